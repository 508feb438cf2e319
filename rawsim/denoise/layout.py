"""How the profiled denoiser reads a mosaic, torch-free (shared by the torch reference,
:mod:`rawsim.denoise.profiled`, and the compiled engine, :mod:`rawsim.engine.denoise`):
its planes, their colour mix, and the patch geometry."""

from __future__ import annotations

import math

import numpy as np

from rawsim.cfa import CFA

#: Patch side and step (plane pixels), a pass's reach, plane rows per chunk.
PATCH = 8
STEP = 2
REACH = PATCH - 1
CHUNK = 64
#: The first pass's hard threshold, in σ (chosen on photos outside the Kodak set:
#: benchmarks/bench_denoise.py --tune).
THRESHOLD = 2.5
_R2 = 1 / math.sqrt(2.0)
#: Bayer planes (R, G, G, B) → their mean, (R + B) − (G + G), R − B, G − G; orthonormal.
BAYER_MIX = (
    (0.5, 0.5, 0.5, 0.5),
    (0.5, -0.5, -0.5, 0.5),
    (_R2, 0.0, 0.0, -_R2),
    (0.0, _R2, -_R2, 0.0),
)


def plane_layout(cfa: CFA) -> tuple[np.ndarray, int, np.ndarray]:
    """The planes a mosaic of ``cfa`` is read as: (offsets (C, 2) of each plane's first
    site, the step between a plane's sites, the (C, C) orthonormal mix of the planes).
    Bayer: its R, G, G, B planes; any other pattern: the mosaic as one plane."""
    if cfa.is_bayer:
        return np.array(cfa.packed_sites, np.int64), 2, np.array(BAYER_MIX, np.float32)
    return np.zeros((1, 2), np.int64), 1, np.ones((1, 1), np.float32)


def plane_shape(shape: tuple[int, int], cfa: CFA) -> tuple[int, int]:
    """(rows, columns) of every plane of a mosaic of ``shape``: the smallest plane's."""
    offsets, step, _ = plane_layout(cfa)
    return tuple(  # type: ignore[return-value]
        (n - int(offsets[:, k].max()) + step - 1) // step for k, n in enumerate(shape)
    )


def large_enough(shape: tuple[int, int], cfa: CFA) -> bool:
    """Whether a mosaic of ``shape`` has planes of at least :data:`PATCH` a side."""
    return min(plane_shape(shape, cfa)) >= PATCH


def modulation_pads(cfa: CFA) -> tuple[int, int, int, int]:
    """(top, bottom, left, right): the mirror padding that makes the box of
    :func:`colour_modulation` one CFA period around each site (rows i − ph // 2 to
    i − ph // 2 + ph − 1, likewise columns)."""
    ph, pw = cfa.period
    return ph // 2, ph - 1 - ph // 2, pw // 2, pw - 1 - pw // 2


def colour_modulation(y: np.ndarray, cfa: CFA) -> np.ndarray:
    """The CFA's colour pattern in the transformed mosaic ``y`` (H, W) of a one-plane
    layout (X-Trans …): at each site, the mean of ``y`` over the sites of its colour
    in the period-sized box around it, less the mean of every site in that box
    (:func:`modulation_pads`; the mosaic mirrored at its edges, sums in float64);
    (H, W) float32. ``profiled`` takes it out before its patches, which would keep the
    pattern as detail and the noise with it, and puts it back after (its own noise,
    a mean of 8 or more sites, stays). The torch reference forms the same
    (:func:`rawsim.denoise.profiled.colour_modulation`)."""
    top, bottom, left, right = modulation_pads(cfa)
    ph, pw = cfa.period
    h, w = y.shape
    colours = np.tile(np.array(cfa.colors).reshape(ph, pw), (-(-h // ph), -(-w // pw)))[:h, :w]

    def box(a: np.ndarray) -> np.ndarray:
        a = np.pad(a, ((top, bottom), (left, right)), mode="reflect")
        c = np.zeros((a.shape[0] + 1, a.shape[1] + 1))
        c[1:, 1:] = np.cumsum(np.cumsum(a, 0), 1)
        return c[ph:, pw:] - c[:-ph, pw:] - c[ph:, :-pw] + c[:-ph, :-pw]

    values = y.astype(np.float64)
    out = -box(values) / (ph * pw)
    for c in np.unique(colours):
        mask = (colours == c).astype(np.float64)
        # a site's own colour is in its box: its count is never 0 where it is read
        out[colours == c] += (box(values * mask) / np.maximum(box(mask), 0.5))[colours == c]
    return out.astype(np.float32)
