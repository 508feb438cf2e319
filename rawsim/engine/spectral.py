"""A spectral scene's raw camera RGB as a compiled kernel: the twin of
:func:`rawsim.spectral.render.integrate` (the torch reference).

:func:`integral_kernel` reads the scene (H, W, N) where it lies (a memory map of the
file, a crop; any strides), sums each pixel's N bands times the (N, 3) band weights
(:func:`rawsim.spectral.render.band_weights`) in float64, band by band in order, and
writes (H, W, 3) float32: parallel over rows, no copy of the scene. The camera RGB is
then unprocessed as any other (:func:`rawsim.engine.unprocess.unprocess_kernel`,
``camera_rgb``). The reference sums in another order (a float64 einsum), so the two
agree to float64 rounding, the same float32 almost always.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from rawsim.engine import configure
from rawsim.errors import ParameterError

configure()

#: Compiled once, cached; the numpy error model (see :mod:`rawsim.engine.unprocess`);
#: without the GIL, so that a batch reads its next scene alongside.
_JIT = {"cache": True, "error_model": "numpy", "nogil": True}


#: Pixels summed side by side: each block's bands are first laid band-major (a
#: transpose in a small buffer), so that the sums over the bands run one pixel to a
#: vector lane, in the same order as one pixel alone (the same bits).
BLOCK = 64


@njit(parallel=True, **_JIT)
def integral_kernel(scene, weights, out):
    """Raw camera RGB of ``scene`` (H, W, N) float32, any strides, into ``out``
    (H, W, 3) float32: ``Σ_k scene[y, x, k] · weights[k, c]`` in float64, k from 0 up,
    ``weights`` (N, 3) float64."""
    h, w, n = scene.shape
    for y in prange(h):
        row = scene[y]
        bands = np.zeros((n, BLOCK))  # a last, partial block sums zeros beyond its end
        acc = np.empty((3, BLOCK))
        for x0 in range(0, w, BLOCK):
            m = min(BLOCK, w - x0)
            for j in range(m):
                for k in range(n):
                    bands[k, j] = row[x0 + j, k]
            acc[:] = 0.0
            for k in range(n):
                w0, w1, w2 = weights[k, 0], weights[k, 1], weights[k, 2]
                for j in range(BLOCK):  # the whole block: a fixed count vectorises
                    v = bands[k, j]
                    acc[0, j] += v * w0
                    acc[1, j] += v * w1
                    acc[2, j] += v * w2
            for j in range(m):
                out[y, x0 + j, 0], out[y, x0 + j, 1], out[y, x0 + j, 2] = (
                    acc[0, j],
                    acc[1, j],
                    acc[2, j],
                )


def camera_rgb(scene: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 raw camera RGB of ``scene`` (H, W, N) float32 (any strides)
    through the (N, 3) band ``weights``, by :func:`integral_kernel` (on a read-only
    view: the kernel ``rawsim compile`` builds, whether the caller's array is
    writable or not)."""
    if scene.ndim != 3 or weights.shape != (scene.shape[2], 3):
        raise ParameterError(f"scene {scene.shape} and weights {weights.shape} do not match")
    view = scene.view(np.ndarray)  # read-only, as the reader gives scenes: one signature
    view.flags.writeable = False
    out = np.empty((*scene.shape[:2], 3), np.float32)
    integral_kernel(view, np.ascontiguousarray(weights, np.float64), out)
    return out
