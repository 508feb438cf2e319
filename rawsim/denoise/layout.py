"""How the denoisers read a mosaic, torch-free: the profiled one's planes, their colour
mix and the patch geometry (shared by the torch reference, :mod:`rawsim.denoise.profiled`,
and the compiled engine, :mod:`rawsim.engine.denoise`), and the learned one's packing and
which weights serve a CFA (:mod:`rawsim.denoise.learned`)."""

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
#: The sites of a 2 × 2 block, in the order of a non-Bayer mosaic's packed planes.
BLOCK_SITES = ((0, 0), (0, 1), (1, 0), (1, 1))
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
    """(top, bottom, left, right): the mirror padding that makes the box of the colour
    pattern ``profiled`` takes out of a one-plane mosaic
    (:func:`rawsim.denoise.profiled.colour_modulation`,
    :func:`rawsim.engine.denoise.colour_pattern`) one CFA period around each site
    (rows i − ph // 2 to i − ph // 2 + ph − 1, likewise columns)."""
    ph, pw = cfa.period
    return ph // 2, ph - 1 - ph // 2, pw // 2, pw - 1 - pw // 2


def weights_kind(cfa: CFA) -> str | None:
    """The key of :data:`rawsim.denoise.learned.WEIGHTS` that serves mosaics of ``cfa``:
    ``bayer``, ``xtrans`` (any 6 × 6 pattern, X-Trans at any phase), or None (none do)."""
    if cfa.is_bayer:
        return "bayer"
    return "xtrans" if cfa.period == (6, 6) else None


def packing(cfa: CFA) -> tuple[tuple[int, int], ...]:
    """(row, col) in its 2 × 2 block of each packed plane's site: a Bayer mosaic's R, Gr,
    Gb and B (:attr:`CFA.packed_sites`), else :data:`BLOCK_SITES`."""
    return cfa.packed_sites if cfa.is_bayer else BLOCK_SITES


def pack(mosaic: np.ndarray, cfa: CFA) -> np.ndarray:
    """A (H, W) mosaic's packed planes (4, H // 2, W // 2) (:func:`packing`); an odd
    last row or column is left out."""
    h, w = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    return np.stack([mosaic[r::2, c::2][:h, :w] for r, c in packing(cfa)])
