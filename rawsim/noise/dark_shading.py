"""Dark shading and black-level error: the dark signal's fixed pattern and its drift.

After Feng et al., "Learnability enhancement for low-light raw denoising: a data
perspective" (PMN, ACM MM 2022; TPAMI 2023), which measures on real sensors two
terms that ELD's model (Wei et al., CVPR 2020) leaves out:

* **dark shading**: the dark level of each pixel, beyond the black level and its
  channel's bias, ``D(x, y) = k(x, y) · ISO + b(x, y)`` DN, with k and b fitted
  separately for each of the sensor's gain ranges (a dual conversion gain switches
  range at one ISO);
* **black-level error**: one offset per shot, normal with σ (DN) depending on the ISO.

A profile carries them under ``noise.dark_shading`` (the map file and its gain
ranges) and ``noise.black_level_error`` (σ per ISO). The maps live in a file beside
the profile JSON (:func:`write_maps`, :data:`FORMAT`), read on first use and
cached (:meth:`DarkShading.maps`). Torch-free. :mod:`rawsim.cameras.dark_calibration`
measures them from dark frames.

Map file (``.npz``, :data:`FORMAT`): ``iso_ranges`` float64 (n, 2), each gain
range's lowest and highest ISO; ``k_codes`` and ``b_codes`` uint16 (n, H, W),
the maps as 16-bit codes, value = ``offset + scale · code`` with ``k_offset``,
``k_scale``, ``b_offset``, ``b_scale`` float64 (n,) (one step is 1/65535 of the
map's range: 0.3 mDN for a map spanning 20 DN, far below any read noise);
``cfa_pattern`` the layout the map was measured on; ``format`` the format name.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rawsim.errors import ParameterError, ProfileError

FORMAT = "rawsim-dark-shading/1"
_CODES = 65535


@dataclass(frozen=True)
class BlackLevelError:
    """σ (DN) of the per-shot black-level offset versus ISO: piecewise linear through
    (``iso``, ``sigma``), held flat outside the points."""

    iso: tuple[float, ...]
    sigma: tuple[float, ...]

    def __call__(self, iso: float) -> float:
        return float(np.interp(iso, self.iso, self.sigma))


@dataclass(frozen=True)
class DarkShading:
    """A profile's dark-shading maps: the file ``path`` (an ``.npz`` of :data:`FORMAT`),
    the ``iso_ranges`` ((lo, hi) per gain range) and the map ``size`` (H, W) pixels.
    Only the file name and these figures live in the profile; the maps are read on
    first use (:meth:`maps`)."""

    path: str
    iso_ranges: tuple[tuple[float, float], ...]
    size: tuple[int, int]

    def range_index(self, iso: float) -> int:
        """The gain range of ``iso``: the one containing it, else the nearest (its
        line k·ISO + b is extrapolated)."""
        gaps = [max(lo - iso, iso - hi, 0.0) for lo, hi in self.iso_ranges]
        return int(np.argmin(gaps))

    def maps(self, iso: float) -> tuple[np.ndarray, np.ndarray]:
        """(k, b) float32 (H, W) of ``iso``'s gain range, decoded once and cached (do
        not modify them)."""
        return _read_maps(self.path, _mtime(self.path), self.range_index(iso), self.size)

    def to_dict(self) -> dict:
        return {
            "file": os.path.basename(self.path),
            "iso_ranges": [list(r) for r in self.iso_ranges],
            "size": list(self.size),
        }


def _mtime(path: str) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        raise ProfileError(f"{path}: dark-shading map file not found") from None


@functools.lru_cache(maxsize=4)
def _read_maps(path: str, mtime: int, index: int, size: tuple[int, int]):
    """Decode gain range ``index`` of a map file (cached by path and modification time)."""
    try:
        with np.load(path, allow_pickle=False) as f:
            if str(f["format"]) != FORMAT:
                raise ProfileError(f"{path}: not a {FORMAT} file (format {str(f['format'])!r})")
            k = f["k_offset"][index] + f["k_scale"][index] * f["k_codes"][index].astype(np.float64)
            b = f["b_offset"][index] + f["b_scale"][index] * f["b_codes"][index].astype(np.float64)
    except (OSError, KeyError, ValueError, IndexError) as err:
        raise ProfileError(f"{path}: cannot read the dark-shading maps ({err})") from None
    if k.shape != tuple(size):
        raise ProfileError(f"{path}: maps are {k.shape[0]}×{k.shape[1]}, the profile says {size}")
    return np.ascontiguousarray(k, np.float32), np.ascontiguousarray(b, np.float32)


def read_spec(value, key: str, origin: str) -> DarkShading:
    """A profile's ``noise.dark_shading`` object → :class:`DarkShading`; the file is
    named relative to the profile JSON (``origin``). Raises :class:`ProfileError`."""

    def fail(why: str):
        raise ProfileError(f"{origin}: key {key!r}: {why}")

    if not isinstance(value, dict) or not isinstance(value.get("file"), str):
        fail("expected an object with 'file', 'iso_ranges' and 'size'")
    ranges = value.get("iso_ranges")
    if not isinstance(ranges, list) or not ranges:
        fail("'iso_ranges' must be a non-empty list of [lowest, highest] ISO")
    out = []
    for r in ranges:
        if (
            not isinstance(r, list)
            or len(r) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in r)
            or not 0 < r[0] <= r[1]
        ):
            fail(f"each gain range must be [lowest, highest] ISO > 0, got {r!r}")
        if out and r[0] <= out[-1][1]:
            fail("gain ranges must be in increasing, non-overlapping order")
        out.append((float(r[0]), float(r[1])))
    size = value.get("size")
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) for v in size)):
        fail(f"'size' must be [height, width] in pixels, got {size!r}")
    base = Path(origin).parent if not origin.startswith("<") else Path.cwd()
    return DarkShading(str(base / value["file"]), tuple(out), (size[0], size[1]))


def read_black_level_error(value, key: str, origin: str) -> BlackLevelError:
    """A profile's ``noise.black_level_error`` (``{"iso": [...], "sigma": [...]}``, σ ≥ 0
    DN) → :class:`BlackLevelError`."""
    iso = value.get("iso") if isinstance(value, dict) else None
    sigma = value.get("sigma") if isinstance(value, dict) else None
    ok = (
        isinstance(iso, list)
        and isinstance(sigma, list)
        and len(iso) == len(sigma) > 0
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in iso + sigma)
        and all(math.isfinite(v) for v in iso + sigma)
        and all(v > 0 for v in iso)
        and all(v >= 0 for v in sigma)
        and all(b > a for a, b in zip(iso, iso[1:], strict=False))
    )
    if not ok:
        raise ProfileError(
            f"{origin}: key {key!r}: expected increasing 'iso' (> 0) and as many "
            f"'sigma' (≥ 0 DN), got {value!r}"
        )
    return BlackLevelError(tuple(float(v) for v in iso), tuple(float(v) for v in sigma))


def write_maps(
    path: str | Path,
    iso_ranges: list[tuple[float, float]],
    k: np.ndarray,
    b: np.ndarray,
    cfa_pattern: str,
) -> None:
    """Write maps k, b ((n, H, W), one per gain range) as a :data:`FORMAT` file."""
    k, b = np.asarray(k, np.float64), np.asarray(b, np.float64)
    if k.shape != b.shape or k.ndim != 3 or k.shape[0] != len(iso_ranges):
        raise ParameterError(f"maps of shape {k.shape} and {b.shape} for {len(iso_ranges)} ranges")
    arrays = {"format": np.array(FORMAT), "cfa_pattern": np.array(cfa_pattern)}
    arrays["iso_ranges"] = np.asarray(iso_ranges, np.float64).reshape(-1, 2)
    for name, m in (("k", k), ("b", b)):
        low = m.min(axis=(1, 2))
        scale = (m.max(axis=(1, 2)) - low) / _CODES
        step = np.where(scale > 0, scale, 1.0)[:, None, None]
        codes = np.rint((m - low[:, None, None]) / step)
        arrays[f"{name}_codes"] = np.clip(codes, 0, _CODES).astype(np.uint16)
        arrays[f"{name}_offset"], arrays[f"{name}_scale"] = low, scale
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def crop_offset(u: float, image: int, size: int, period: int) -> int:
    """The crop's first row (or column) of an ``image``-pixel side in a ``size``-pixel
    map from a uniform ``u`` in (0, 1): a multiple of the CFA ``period``, so each
    site keeps its colour, uniform over the places the image fits."""
    return int(math.floor(u * ((size - image) // period + 1))) * period


def check_fits(shading: DarkShading, height: int, width: int) -> None:
    """Refuse an image larger than the map (the pattern is measured, not invented)."""
    h, w = shading.size
    if height > h or width > w:
        raise ParameterError(
            f"image {height}×{width} is larger than the profile's dark-shading map {h}×{w} "
            f"({os.path.basename(shading.path)}); crop or downscale the image, or use "
            "--noise poisson-gaussian (no dark shading)"
        )
