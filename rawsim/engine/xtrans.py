"""X-Trans (any periodic CFA) demosaics as compiled kernels: the twin of
:mod:`rawsim.isp.xtrans` (read its module doc for the methods).

The mosaic is extended once by the same phase-preserving reflection
(:func:`rawsim.cfa.phase_reflect_index`); each stage is then a row-parallel
(``prange``) pass over the extended image, computed where its consumers need it
(the valid region shrinks by each stage's reach). Arithmetic is float32 in the
reference's order of operations, so the two agree to rounding. No torch here.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from rawsim.cfa import CFA, phase_reflect_index
from rawsim.engine import configure
from rawsim.errors import ParameterError, check_choice
from rawsim.isp.xtrans_stencils import (
    EDGE_WEIGHTS_3,
    GRAD_EPS,
    ICD_ITERATIONS,
    INV_DIST_5,
    NEIGHBOURS_3,
    NEIGHBOURS_5,
    XTRANS_DEMOSAIC_METHODS,
    padding,
)

configure()

_JIT = {"cache": True, "error_model": "numpy"}

#: The stencils of :mod:`rawsim.isp.xtrans_stencils` as the kernels index them.
_N3 = np.array(NEIGHBOURS_3)
_K3 = np.array(EDGE_WEIGHTS_3, np.float32)
_N5 = np.array(NEIGHBOURS_5)
_K5 = np.array(INV_DIST_5).astype(np.float32)
_EPS = np.float32(GRAD_EPS)
_HALF = np.float32(0.5)
_ONE = np.float32(1.0)


@njit(parallel=True, **_JIT)
def _extend(mosaic, rows, cols, out):
    for i in prange(rows.size):
        src = mosaic[rows[i]]
        dst = out[i]
        for j in range(cols.size):
            dst[j] = src[cols[j]]


def _neighbour_lists(cmap: np.ndarray, offsets: np.ndarray, colors) -> tuple:
    """For each site phase (r, c) and each colour in ``colors``: the indices into
    ``offsets`` of the neighbours of that colour, ascending (the reference's
    summation order), padded with −1; and their counts."""
    ph, pw = cmap.shape
    lists = np.full((ph, pw, len(colors), len(offsets)), -1, np.int64)
    counts = np.zeros((ph, pw, len(colors)), np.int64)
    for r in range(ph):
        for c in range(pw):
            for n, color in enumerate(colors):
                ks = [
                    k
                    for k, (dy, dx) in enumerate(offsets)
                    if cmap[(r + dy) % ph, (c + dx) % pw] == color
                ]
                lists[r, c, n, : len(ks)] = ks
                counts[r, c, n] = len(ks)
    return lists, counts


@njit(parallel=True, **_JIT)
def _bilinear(m, cmap, lists, counts, est, q):
    """3×3 same-colour means into ``est`` (3, H, W) over rows/cols [q, H − q)."""
    h, w = m.shape
    ph, pw = cmap.shape
    for i in prange(q, h - q):
        pr = i % ph
        pc = q % pw
        for j in range(q, w - q):
            own = cmap[pr, pc]
            for c in range(3):
                if c == own:
                    est[c, i, j] = m[i, j]
                    continue
                num = np.float32(0.0)
                den = np.float32(0.0)
                for s in range(counts[pr, pc, c]):
                    k = lists[pr, pc, c, s]
                    num = num + _K3[k] * m[i + _N3[k, 0], j + _N3[k, 1]]
                    den = den + _K3[k]
                est[c, i, j] = num / den
            pc += 1
            if pc == pw:
                pc = 0


@njit(inline="always", **_JIT)
def _l1(est, y, x, i, j):
    return (abs(est[0, y, x] - est[0, i, j]) + abs(est[1, y, x] - est[1, i, j])) + abs(
        est[2, y, x] - est[2, i, j]
    )


@njit(inline="always", **_JIT)
def _inv_sq(g):
    t = g + _EPS
    return _ONE / (t * t)


@njit(parallel=True, **_JIT)
def _green(m, cmap, est, out, q):
    """Step 1 of an ``icd`` round: green into ``out[1]`` over [q, H − q).

    _N3 is symmetric (neighbour 7 − k is opposite k), so each of the 8 RGB
    differences is taken once and used twice.
    """
    h, w = m.shape
    ph, pw = cmap.shape
    for i in prange(q, h - q):
        l1 = np.empty(8, np.float32)
        pr = i % ph
        pc = q % pw
        for j in range(q, w - q):
            own = cmap[pr, pc]
            pc += 1
            if pc == pw:
                pc = 0
            if own == 1:
                out[1, i, j] = m[i, j]
                continue
            for k in range(8):
                l1[k] = _l1(est, i + _N3[k, 0], j + _N3[k, 1], i, j)
            num = np.float32(0.0)
            den = np.float32(0.0)
            for k in range(8):
                g = l1[k] + _HALF * l1[7 - k]
                weight = _K3[k] * _inv_sq(g)
                y = i + _N3[k, 0]
                x = j + _N3[k, 1]
                d = est[own, y, x] - est[1, y, x]
                num = num + weight * d
                den = den + weight
            out[1, i, j] = m[i, j] - num / den


@njit(parallel=True, **_JIT)
def _red_blue(m, cmap, lists, counts, out, q):
    """Step 2 of an ``icd`` round: red and blue into ``out[0]``, ``out[2]`` over [q, H − q)."""
    h, w = m.shape
    ph, pw = cmap.shape
    green = out[1]
    for i in prange(q, h - q):
        pr = i % ph
        pc = q % pw
        for j in range(q, w - q):
            own = cmap[pr, pc]
            g0 = green[i, j]
            for n in range(2):
                c = 2 * n
                if c == own:
                    out[c, i, j] = m[i, j]
                    continue
                num = np.float32(0.0)
                den = np.float32(0.0)
                for s in range(counts[pr, pc, n]):
                    k = lists[pr, pc, n, s]
                    dy = _N5[k, 0]
                    dx = _N5[k, 1]
                    gn = green[i + dy, j + dx]
                    g = abs(gn - g0) + _HALF * abs(green[i - dy, j - dx] - g0)
                    weight = _K5[k] * _inv_sq(g)
                    num = num + weight * (m[i + dy, j + dx] - gn)
                    den = den + weight
                out[c, i, j] = g0 + num / den
            pc += 1
            if pc == pw:
                pc = 0


def demosaic_xtrans(
    mosaic: np.ndarray, cfa: CFA, method: str = "icd", iterations: int = ICD_ITERATIONS
) -> np.ndarray:
    """Demosaic a (H, W) mosaic (linear, float32) on ``cfa`` → (3, H, W) float32.

    The same results as :func:`rawsim.isp.xtrans.demosaic_xtrans` to float32
    rounding; runs on numba's threads (:func:`rawsim.engine.set_threads`).
    """
    check_choice("X-Trans demosaic method", method, XTRANS_DEMOSAIC_METHODS)
    mosaic = np.ascontiguousarray(mosaic, dtype=np.float32)
    if mosaic.ndim != 2:
        raise ParameterError(f"mosaic must be (H, W), got shape {mosaic.shape}")
    if iterations < 1:
        raise ParameterError(f"iterations must be at least 1, got {iterations}")
    pad = padding(cfa, method, iterations)
    h, w = mosaic.shape
    need = pad + max(cfa.period)
    if h < need or w < need:
        raise ParameterError(
            f"a {cfa.name} mosaic needs at least {need}×{need} pixels for {method!r}, got {h}×{w}"
        )
    if not np.isfinite(mosaic).all():
        raise ParameterError("mosaic contains NaN or infinite values")
    ph, pw = cfa.period
    cmap = np.array(cfa.colors, np.int64).reshape(ph, pw)
    rows = phase_reflect_index(h, pad, ph)
    cols = phase_reflect_index(w, pad, pw)
    m = np.empty((rows.size, cols.size), np.float32)
    _extend(mosaic, rows, cols, m)
    est = np.empty((3, *m.shape), np.float32)
    lists3, counts3 = _neighbour_lists(cmap, _N3, (0, 1, 2))
    _bilinear(m, cmap, lists3, counts3, est, 1)
    if method == "icd":
        lists5, counts5 = _neighbour_lists(cmap, _N5, (0, 2))
        out = np.empty_like(est)
        q = 1
        for _ in range(iterations):
            _green(m, cmap, est, out, q + 1)
            _red_blue(m, cmap, lists5, counts5, out, q + 3)
            est, out = out, est
            q += 3
    return np.ascontiguousarray(est[:, pad : pad + h, pad : pad + w])
