"""The spectral tables rawsim carries, on one grid (380–780 nm, 5 nm): the CIE 1931 2°
observer, rawtoaces' 190 training reflectances, and the illuminants by name or file.

The figures are in ``tables.json`` (built by ``tools/spectra/build.py``, each table with
its source and licence). Illuminants (:func:`illuminant`), relative power:

- ``D50``, ``D55``, ``D65``, ``D75`` and any daylight by correlated colour temperature
  (:func:`daylight`): the CIE daylight series from its S0, S1, S2 (CIE 15:2004 §3.1,
  M1 and M2 rounded to three decimals as the CIE prescribes), at the CCTs of the CIE's
  tables (6500 K · 1.4388/1.4380 for D65);
- ``A``: Planck's law at 2848 K with c2 = 1.435 × 10⁻² m·K, as CIE 15:2004 (3.1)
  defines it (2856 K with today's c2);
- ``F2``, ``F11``: the CIE's tabulated fluorescents; ``ISO7589``: studio tungsten
  (the Academy's variant, which rawtoaces uses);
- a file: two columns (wavelength in nm, power) as CSV or whitespace-separated text,
  or a rawtoaces-data JSON, interpolated linearly onto the grid. It must cover
  400–700 nm; beyond its ends its end values are held.

Each spectrum is a (81,) float64 array normalised to 100 at 560 nm (the CIE's habit);
only ratios matter to rawsim.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np

from rawsim.color import ILLUMINANT_D65
from rawsim.errors import ParameterError

#: The grid of every spectrum, nm: 380, 385, …, 780 (81 samples).
WAVELENGTHS = np.arange(380, 781, 5, dtype=np.float64)
#: The illuminants known by name (:func:`illuminant`).
ILLUMINANTS = ("D50", "D55", "D65", "D75", "A", "F2", "F11", "ISO7589")
#: Their EXIF LightSource codes (a DNG's CalibrationIlluminant), where EXIF has one
#: (F11 has none).
LIGHT_SOURCES = {
    "D50": 23, "D55": 20, "D65": ILLUMINANT_D65, "D75": 22, "A": 17, "F2": 14, "ISO7589": 24,
}  # fmt: skip
_DAYLIGHT_CCT = {"D50": 5000, "D55": 5500, "D65": 6500, "D75": 7500}
#: c2 of Planck's law (m·K): the value the CIE's illuminant A is defined with, and the
#: CODATA one that the daylight series' nominal temperatures were rescaled to.
_C2_A, _C2 = 1.435e-2, 1.4388e-2


def rescaled(nominal: float) -> float:
    """A daylight's correlated colour temperature from its nominal one (K), rescaled to
    today's c2 as the CIE's tables are: 6500 → 6504 K for D65."""
    return nominal * 1.4388 / 1.4380


@cache
def _tables() -> dict:
    return json.loads((resources.files("rawsim.spectral") / "tables.json").read_text())


def source(table: str) -> str:
    """Where ``table`` ("cmf_1931", "training_190", "iso7589", "d_series_basis",
    "fluorescent") comes from, with its licence where it has one."""
    t = _tables()[table]
    return t["source"] + (f" ({t['licence']})" if "licence" in t else "")


def cmf() -> np.ndarray:
    """(81, 3) float64: the CIE 1931 2° colour-matching functions x̄, ȳ, z̄."""
    return np.asarray(_tables()["cmf_1931"]["xyz"], dtype=np.float64).T


def training_reflectances() -> np.ndarray:
    """(81, 190) float64: rawtoaces' 190 training patches' reflectance (≥ 0; a few
    fluorescent patches exceed 1)."""
    return np.asarray(_tables()["training_190"]["reflectance"], dtype=np.float64).T


def _at_560(spd: np.ndarray) -> np.ndarray:
    return 100.0 * spd / spd[np.searchsorted(WAVELENGTHS, 560.0)]


def daylight(cct: float) -> np.ndarray:
    """(81,) the CIE daylight illuminant of correlated colour temperature ``cct`` (K,
    4000–25000, and the 25014 K that 25000 K becomes rescaled as the CIE's tables are):
    its chromaticity by CIE 15:2004 (3.3)–(3.4), then S0 + M1·S1 + M2·S2."""
    if not 4000 <= cct <= rescaled(25000):
        raise ParameterError(f"a daylight's CCT must be 4000–25000 K, got {cct:g}")
    t = 1e3 / cct
    if cct <= 7000:
        x = -4.6070 * t**3 + 2.9678 * t**2 + 0.09911 * t + 0.244063
    else:
        x = -2.0064 * t**3 + 1.9018 * t**2 + 0.24748 * t + 0.237040
    y = -3.000 * x * x + 2.870 * x - 0.275
    d = 0.0241 + 0.2562 * x - 0.7341 * y
    m1 = round((-1.3515 - 1.7703 * x + 5.9114 * y) / d, 3)
    m2 = round((0.0300 - 31.4424 * x + 30.0717 * y) / d, 3)
    s0, s1, s2 = np.asarray(_tables()["d_series_basis"]["s"], dtype=np.float64)
    return _at_560(s0 + m1 * s1 + m2 * s2)


def blackbody(kelvin: float, c2: float = _C2) -> np.ndarray:
    """(81,) Planck's law at ``kelvin`` (relative spectral radiance)."""
    if not kelvin > 0:
        raise ParameterError(f"a blackbody's temperature must be > 0 K, got {kelvin:g}")
    lam = WAVELENGTHS * 1e-9
    return _at_560(lam**-5 / np.expm1(c2 / (lam * kelvin)))


def illuminant(name: str | Path) -> np.ndarray:
    """(81,) the illuminant ``name`` (:data:`ILLUMINANTS`, case-insensitive) or read
    from a file (see the module's notes)."""
    key = str(name).upper()
    if key in _DAYLIGHT_CCT:
        return daylight(rescaled(_DAYLIGHT_CCT[key]))
    if key == "A":
        return blackbody(2848.0, _C2_A)
    if key in ("F2", "F11"):
        return _at_560(np.asarray(_tables()["fluorescent"][key], dtype=np.float64))
    if key == "ISO7589":
        return _at_560(np.asarray(_tables()["iso7589"]["power"], dtype=np.float64))
    path = Path(name)
    if not path.is_file():
        raise ParameterError(
            f"unknown illuminant {str(name)!r}: give one of {', '.join(ILLUMINANTS)}, or a "
            "file of two columns (wavelength in nm, power)"
        )
    return _at_560(read_spectrum(path))


def read_spectrum(path: Path) -> np.ndarray:
    """(81,) a one-column spectrum from ``path`` on :data:`WAVELENGTHS`: two columns
    (nm, value) as CSV or text, or a rawtoaces-data JSON with one column."""
    what = f"{path}: not a spectrum"
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise ParameterError(f"{path}: cannot read the spectrum ({err})") from None
    try:
        if path.suffix.lower() == ".json":
            main = json.loads(text)["spectral_data"]["data"]["main"]
            nm = np.array([float(k) for k in main])
            values = np.array([np.ravel(v)[0] for v in main.values()], dtype=np.float64)
        else:
            rows = [
                line.replace(",", " ").split()
                for line in text.splitlines()
                if line.strip() and not line.lstrip().startswith("#")
            ]
            rows = [r for r in rows if _numeric(r[0])]  # a header line is skipped
            nm, values = np.array([[float(r[0]), float(r[1])] for r in rows]).T
    except (ValueError, KeyError, IndexError, TypeError, json.JSONDecodeError):
        raise ParameterError(
            f"{what}: give two columns (wavelength in nm, power) as CSV or text, or a "
            "rawtoaces-data JSON"
        ) from None
    return resample(nm, values, str(path))


def _numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def resample(nm, values, what: str) -> np.ndarray:
    """``values`` (N, …) at wavelengths ``nm`` (N,), increasing, → (81, …) on
    :data:`WAVELENGTHS` by linear interpolation, the end values held beyond the ends.
    Refused where they do not cover 400–700 nm or are not finite and ≥ 0."""
    nm = np.asarray(nm, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if nm.ndim != 1 or len(nm) < 2 or values.shape[0] != len(nm):
        raise ParameterError(f"{what}: needs one value per wavelength, at two or more")
    if not (np.diff(nm) > 0).all():
        raise ParameterError(f"{what}: its wavelengths must increase")
    if nm[0] > 400 or nm[-1] < 700:
        raise ParameterError(
            f"{what}: its wavelengths ({nm[0]:g}–{nm[-1]:g} nm) do not cover 400–700 nm"
        )
    if not np.isfinite(values).all() or (values < 0).any():
        raise ParameterError(f"{what}: its values must be finite and ≥ 0")
    if np.array_equal(nm, WAVELENGTHS):
        return values.copy()
    flat = values.reshape(len(nm), -1)
    out = np.stack([np.interp(WAVELENGTHS, nm, col) for col in flat.T], axis=1)
    return out.reshape((len(WAVELENGTHS), *values.shape[1:]))
