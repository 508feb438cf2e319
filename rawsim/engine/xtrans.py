"""X-Trans (any periodic CFA) demosaics as compiled kernels: the twin of
:mod:`rawsim.isp.xtrans` (read its module doc for the methods).

The image is cut into tiles of whole CFA periods, parallel over tiles, and each
tile is demosaicked in **phase planes**: for a period of ph × pw sites, a tile
buffer is held as ph·pw planes, plane (pr, pc) holding the sites (ph·Y + pr,
pw·X + pc). Every site of a plane has the same colour and the same neighbours
(each neighbour in a fixed plane at an offset of at most one plane row or
column), so each step is a branch-free loop over a plane row with unit
strides, which LLVM vectorises; in the image's own layout the colour and
the neighbour lists change from pixel to pixel.

Borders: the tile buffer is filled through :func:`tile_index` (the image's
sites, then the phase-preserving reflection of :func:`rawsim.cfa.phase_reflect_index`
that the reference extends the mosaic with), so edge tiles agree with the
reference. The outermost plane row and column of a buffer are read but never
computed; a halo of :func:`halo` sites covers that margin and the reach of the
steps.

Arithmetic is float32 in the reference's order of operations (each sum in the
order of its neighbour list), so the two agree to rounding. No torch here.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from rawsim.cfa import CFA, phase_reflect_index
from rawsim.engine import configure
from rawsim.engine.tiles import next_tile
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

_K3 = np.array(EDGE_WEIGHTS_3, np.float32)
_K5 = np.array(INV_DIST_5).astype(np.float32)
_EPS = np.float32(GRAD_EPS)
_HALF = np.float32(0.5)
_ONE = np.float32(1.0)

#: Output rows and columns of a tile in whole periods (6×6: 96 × 504 sites).
TILE_PERIODS = (16, 84)
METHOD_CODES = {"bilinear": 0, "icd": 1}


# ------------------------------------------------------------- the geometry
class Planes:
    """The phase-plane geometry of one CFA for one demosaic: neighbour tables,
    same-colour lists and the halo, as the kernels take them (see :meth:`args`)."""

    def __init__(
        self,
        cfa: CFA,
        method: str = "icd",
        iterations: int = ICD_ITERATIONS,
    ) -> None:
        check_choice("X-Trans demosaic method", method, XTRANS_DEMOSAIC_METHODS)
        if iterations < 1:
            raise ParameterError(f"iterations must be at least 1, got {iterations}")
        self.cfa, self.method, self.iterations = cfa, method, iterations
        ph, pw = cfa.period
        self.cmap = np.array(cfa.colors, np.int64).reshape(ph, pw)
        self.nb3 = _plane_offsets(ph, pw, NEIGHBOURS_3)
        self.nb5 = _plane_offsets(ph, pw, NEIGHBOURS_5)
        self.lists3, self.counts3 = _same_colour(self.cmap, NEIGHBOURS_3, (0, 1, 2))
        self.lists5, self.counts5 = _same_colour(self.cmap, NEIGHBOURS_5, (0, 2))
        self.den3 = _weight_sums(self.lists3, self.counts3, _K3)
        # The margin of planes read but not computed, per axis, and the halo (sites):
        # the margin plus the reach of the steps after the bilinear start, in periods.
        self.margin = tuple(int(np.abs(self.nb5[..., 2 + a]).max()) for a in (0, 1))
        after = 0 if method == "bilinear" else 3 * iterations + 1  # rounds, refinement
        self.halo = tuple(
            -(-(m * p + after) // p) * p for m, p in zip(self.margin, cfa.period, strict=True)
        )
        # Sites beyond the image are its phase-preserving reflection within the
        # reference's padding; further out (never reaching an output) the same phase
        # moved back inside it.
        self.pad = padding(cfa, method, iterations)

    def args(self) -> tuple:
        """The kernels' geometry arguments, in their order."""
        return (
            self.cmap,
            self.nb3,
            self.nb5,
            self.lists3,
            self.counts3,
            self.lists5,
            self.counts5,
            self.den3,
            np.array(self.margin, np.int64),
            METHOD_CODES[self.method],
            self.iterations,
        )

    def tile_shape(self, periods: tuple[int, int] = TILE_PERIODS) -> tuple[int, int]:
        """(rows, cols) of the output of one tile."""
        return tuple(n * p for n, p in zip(periods, self.cfa.period, strict=True))

    def buffer_planes(self, tile: tuple[int, int]) -> tuple[int, int]:
        """(NY, NX): plane rows and columns of a tile buffer (tile plus halo each side)."""
        return tuple(
            (t + 2 * h) // p for t, h, p in zip(tile, self.halo, self.cfa.period, strict=True)
        )

    def index(self, n: int, axis: int, tile: int) -> np.ndarray:
        """:func:`tile_index` of this geometry along ``axis`` (0 rows, 1 columns)."""
        return tile_index(n, self.pad, self.halo[axis], self.cfa.period[axis], tile)


def tile_index(n: int, pad: int, halo: int, period: int, tile: int) -> np.ndarray:
    """Source index (int64) of every position −halo … ⌈n / tile⌉·tile + halo − 1 of a
    line of ``n`` CFA sites cut into tiles: the identity inside, the reference's
    :func:`~rawsim.cfa.phase_reflect_index` within ``pad`` outside, and beyond that a
    site of the same phase (a multiple of ``period`` back towards the line)."""
    ext = phase_reflect_index(n, pad, period)  # positions −pad … n + pad − 1
    v = np.arange(-halo, -(-n // tile) * tile + halo)
    inside = np.clip(v, -pad, n + pad - 1)
    inside = inside + np.mod(v - inside, period)  # back to v's phase
    inside = np.where(inside > n + pad - 1, inside - period, inside)
    return ext[inside + pad].astype(np.int64)


def _plane_offsets(ph: int, pw: int, offsets) -> np.ndarray:
    """(ph, pw, K, 4): for each phase and each neighbour offset (dy, dx), the
    neighbour's plane (qr, qc) and plane offset (oy, ox)."""
    table = np.empty((ph, pw, len(offsets), 4), np.int64)
    for r in range(ph):
        for c in range(pw):
            for k, (dy, dx) in enumerate(offsets):
                oy, qr = divmod(r + dy, ph)
                ox, qc = divmod(c + dx, pw)
                table[r, c, k] = (qr, qc, oy, ox)
    return table


def _same_colour(cmap: np.ndarray, offsets, colors) -> tuple[np.ndarray, np.ndarray]:
    """For each phase and each colour in ``colors``: the indices into ``offsets`` of
    that colour's neighbours, ascending (the reference's summation order), padded
    with −1; and their counts."""
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


def _weight_sums(lists, counts, weights) -> np.ndarray:
    """Σ of the listed weights per phase and colour, summed in float32 in list order."""
    out = np.ones(counts.shape, np.float32)
    for idx in np.ndindex(*counts.shape):
        if counts[idx]:
            total = np.float32(0.0)
            for k in lists[idx][: counts[idx]]:
                total = np.float32(total + weights[k])
            out[idx] = total
    return out


# ------------------------------------------------------------------ kernels
@njit(inline="always", **_JIT)
def _row(p, c, qr, qc, y, x0, n):
    """Plane (qr, qc) of channel ``c`` of ``p``, row ``y``, columns [x0, x0 + n)."""
    return p[c, qr, qc, y, x0 : x0 + n]


@njit(**_JIT)
def init_own(m, est, out, cmap):
    """Each site's own colour is its sample, in both estimate buffers (set once a tile)."""
    ph, pw = cmap.shape
    for pr in range(ph):
        for pc in range(pw):
            own = cmap[pr, pc]
            sample = m[0, pr, pc]
            for y in range(sample.shape[0]):  # loops: a slice assignment compiles seconds longer
                for x in range(sample.shape[1]):
                    est[own, pr, pc, y, x] = sample[y, x]
                    out[own, pr, pc, y, x] = sample[y, x]


@njit(**_JIT)
def _bilinear(m, est, cmap, nb3, lists3, counts3, den3, margin):
    """3×3 same-colour means (LibRaw's ``lin_interpolate``, normalised exactly)."""
    _, ph, pw, ny, nx = m.shape
    my, mx = margin[0], margin[1]
    n = nx - 2 * mx
    for pr in range(ph):
        for pc in range(pw):
            own = cmap[pr, pc]
            for c in range(3):
                if c == own:
                    continue
                den = den3[pr, pc, c]
                for y in range(my, ny - my):
                    dst = _row(est, c, pr, pc, y, mx, n)
                    if counts3[pr, pc, c] == 0:  # no such neighbour: the reference's 0
                        dst[:] = np.float32(0.0)
                        continue
                    for s in range(counts3[pr, pc, c]):
                        k = lists3[pr, pc, c, s]
                        wk = _K3[k]
                        src = _row(
                            m,
                            0,
                            nb3[pr, pc, k, 0],
                            nb3[pr, pc, k, 1],
                            y + nb3[pr, pc, k, 2],
                            mx + nb3[pr, pc, k, 3],
                            n,
                        )
                        if s == 0:
                            for x in range(n):
                                dst[x] = wk * src[x]
                        else:
                            for x in range(n):
                                dst[x] = dst[x] + wk * src[x]
                    for x in range(n):
                        dst[x] = dst[x] / den


@njit(**_JIT)
def _green(m, est, out, cmap, nb3, margin, l1, num, den):
    """Step 1 of an ``icd`` round: green at the red and blue sites into ``out[1]``.

    ``l1`` (8, n), ``num``, ``den`` (n): scratch rows. NEIGHBOURS_3 is symmetric
    (neighbour 7 − k is opposite k), so each of the 8 RGB differences is taken
    once and used twice.
    """
    _, ph, pw, ny, nx = m.shape
    my, mx = margin[0], margin[1]
    n = nx - 2 * mx
    for pr in range(ph):
        for pc in range(pw):
            own = cmap[pr, pc]
            if own == 1:
                continue
            for y in range(my, ny - my):
                cr = _row(est, 0, pr, pc, y, mx, n)
                cg = _row(est, 1, pr, pc, y, mx, n)
                cb = _row(est, 2, pr, pc, y, mx, n)
                for k in range(8):
                    qr, qc = nb3[pr, pc, k, 0], nb3[pr, pc, k, 1]
                    yy, xx = y + nb3[pr, pc, k, 2], mx + nb3[pr, pc, k, 3]
                    er = _row(est, 0, qr, qc, yy, xx, n)
                    eg = _row(est, 1, qr, qc, yy, xx, n)
                    eb = _row(est, 2, qr, qc, yy, xx, n)
                    dst = l1[k]
                    for x in range(n):
                        dst[x] = (abs(er[x] - cr[x]) + abs(eg[x] - cg[x])) + abs(eb[x] - cb[x])
                for x in range(n):
                    num[x] = np.float32(0.0)
                    den[x] = np.float32(0.0)
                for k in range(8):
                    qr, qc = nb3[pr, pc, k, 0], nb3[pr, pc, k, 1]
                    yy, xx = y + nb3[pr, pc, k, 2], mx + nb3[pr, pc, k, 3]
                    eo = _row(est, own, qr, qc, yy, xx, n)
                    eg = _row(est, 1, qr, qc, yy, xx, n)
                    a, b = l1[k], l1[7 - k]
                    wk = _K3[k]
                    for x in range(n):
                        t = (a[x] + _HALF * b[x]) + _EPS
                        weight = wk * (_ONE / (t * t))
                        num[x] = num[x] + weight * (eo[x] - eg[x])
                        den[x] = den[x] + weight
                sample = _row(m, 0, pr, pc, y, mx, n)
                dst = _row(out, 1, pr, pc, y, mx, n)
                for x in range(n):
                    dst[x] = sample[x] - num[x] / den[x]


@njit(**_JIT)
def _red_blue(m, out, cmap, nb5, lists5, counts5, margin, num, den):
    """Step 2 of an ``icd`` round: red and blue wherever missing, into ``out[0]``, ``out[2]``.

    NEIGHBOURS_5 is symmetric too (23 − k is opposite k).
    """
    _, ph, pw, ny, nx = m.shape
    my, mx = margin[0], margin[1]
    n = nx - 2 * mx
    for pr in range(ph):
        for pc in range(pw):
            own = cmap[pr, pc]
            for i in range(2):
                c = 2 * i
                if c == own:
                    continue
                for y in range(my, ny - my):
                    g0 = _row(out, 1, pr, pc, y, mx, n)
                    for x in range(n):
                        num[x] = np.float32(0.0)
                        den[x] = np.float32(0.0)
                    for s in range(counts5[pr, pc, i]):
                        k = lists5[pr, pc, i, s]
                        qr, qc = nb5[pr, pc, k, 0], nb5[pr, pc, k, 1]
                        yy, xx = y + nb5[pr, pc, k, 2], mx + nb5[pr, pc, k, 3]
                        gn = _row(out, 1, qr, qc, yy, xx, n)
                        mn = _row(m, 0, qr, qc, yy, xx, n)
                        k2 = 23 - k
                        go = _row(
                            out,
                            1,
                            nb5[pr, pc, k2, 0],
                            nb5[pr, pc, k2, 1],
                            y + nb5[pr, pc, k2, 2],
                            mx + nb5[pr, pc, k2, 3],
                            n,
                        )
                        wk = _K5[k]
                        for x in range(n):
                            t = (abs(gn[x] - g0[x]) + _HALF * abs(go[x] - g0[x])) + _EPS
                            weight = wk * (_ONE / (t * t))
                            num[x] = num[x] + weight * (mn[x] - gn[x])
                            den[x] = den[x] + weight
                    dst = _row(out, c, pr, pc, y, mx, n)
                    for x in range(n):
                        dst[x] = g0[x] + num[x] / den[x]


#: A median-of-9 network (Paeth; Devillard's ``opt_med9``): 19 compare-exchanges of
#: the values' slots, after which slot 4 holds the median.
_MEDIAN9 = np.array(
    [
        (1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 3),
        (5, 8), (4, 7), (3, 6), (1, 4), (2, 5), (4, 7), (4, 2), (6, 4), (4, 2),
    ],
    np.int64,
)  # fmt: skip


@njit(**_JIT)
def _median_rows(v, n):
    """Row 4 of ``v`` (9, ≥ n) becomes the median of the 9 rows, column by column; the
    other rows are left permuted. Branch-free (min/max), so LLVM vectorises it."""
    for e in range(_MEDIAN9.shape[0]):
        a, b = v[_MEDIAN9[e, 0]], v[_MEDIAN9[e, 1]]
        for x in range(n):
            lo, hi = min(a[x], b[x]), max(a[x], b[x])
            a[x], b[x] = lo, hi


@njit(**_JIT)
def _refine(m, est, out, cmap, nb3, margin, rows):
    """The ``icd`` median refinement (:func:`rawsim.isp.xtrans._refine`) of ``est``
    into ``out``: R − G and B − G take their medians over the site and its 8
    neighbours (NEIGHBOURS_3), each site keeping its sample. ``rows``: (18, ≥ n)
    scratch (the 9 differences of each kind)."""
    _, ph, pw, ny, nx = m.shape
    my, mx = margin[0], margin[1]
    n = nx - 2 * mx
    vr, vb = rows[:9], rows[9:18]
    for pr in range(ph):
        for pc in range(pw):
            own = cmap[pr, pc]
            for y in range(my, ny - my):
                for k in range(9):  # slot 0 the site, then its neighbours in order
                    if k == 0:
                        qr, qc, yy, xx = pr, pc, y, mx
                    else:
                        qr, qc = nb3[pr, pc, k - 1, 0], nb3[pr, pc, k - 1, 1]
                        yy, xx = y + nb3[pr, pc, k - 1, 2], mx + nb3[pr, pc, k - 1, 3]
                    er = _row(est, 0, qr, qc, yy, xx, n)
                    eg = _row(est, 1, qr, qc, yy, xx, n)
                    eb = _row(est, 2, qr, qc, yy, xx, n)
                    dr, db = vr[k], vb[k]
                    for x in range(n):
                        dr[x] = er[x] - eg[x]
                        db[x] = eb[x] - eg[x]
                _median_rows(vr, n)
                _median_rows(vb, n)
                dr, db = vr[4], vb[4]
                sample = _row(m, 0, pr, pc, y, mx, n)
                red = _row(out, 0, pr, pc, y, mx, n)
                green = _row(out, 1, pr, pc, y, mx, n)
                blue = _row(out, 2, pr, pc, y, mx, n)
                if own == 1:
                    for x in range(n):
                        green[x] = sample[x]
                        red[x] = sample[x] + dr[x]
                        blue[x] = sample[x] + db[x]
                elif own == 0:
                    for x in range(n):
                        red[x] = sample[x]
                        green[x] = sample[x] - dr[x]
                        blue[x] = green[x] + db[x]
                else:
                    for x in range(n):
                        blue[x] = sample[x]
                        green[x] = sample[x] - db[x]
                        red[x] = green[x] + dr[x]


@njit(**_JIT)
def demosaic_planes(m, est, out, scratch, geometry):
    """Demosaic the tile in ``m`` (1, ph, pw, NY, NX); returns the buffer holding the
    result (``est`` or ``out``, each (3, ph, pw, NY, NX)). ``scratch``: (28, NX) rows."""
    cmap, nb3, nb5, lists3, counts3, lists5, counts5, den3, margin, method, rounds = geometry
    init_own(m, est, out, cmap)
    _bilinear(m, est, cmap, nb3, lists3, counts3, den3, margin)
    if method == 0:
        return est
    l1, num, den = scratch[:8], scratch[8], scratch[9]
    for _ in range(rounds):
        _green(m, est, out, cmap, nb3, margin, l1, num, den)
        _red_blue(m, out, cmap, nb5, lists5, counts5, margin, num, den)
        est, out = out, est
    _refine(m, est, out, cmap, nb3, margin, scratch[10:28])
    return out


@njit(**_JIT)
def new_buffers(ph, pw, ny, nx):
    """A thread's tile buffers: mosaic planes, two estimates, scratch rows (zeroed
    once: the margin planes are read before any tile writes them)."""
    return (
        np.zeros((1, ph, pw, ny, nx), np.float32),
        np.zeros((3, ph, pw, ny, nx), np.float32),
        np.zeros((3, ph, pw, ny, nx), np.float32),
        np.zeros((28, nx), np.float32),
    )


@njit(**_JIT)
def planes_to_image(p, hy, hx, n_rows, n_cols, dst, d0, d1):
    """Copy the tile's output sites of the estimate planes ``p`` (3, ph, pw, NY, NX),
    buffer rows [hy, hy + n_rows) and columns [hx, hx + n_cols) (``hy``, ``hx``
    whole periods), into ``dst[c]`` (three (H', W') images) at (d0 + row, d1 + col)."""
    _, ph, pw, _, _ = p.shape
    x0 = hx // pw
    for c in range(3):
        image = dst[c]
        for i in range(n_rows):
            b = hy + i
            row = image[d0 + i, d1 : d1 + n_cols]
            for pc in range(pw):
                src = p[c, b % ph, pc, b // ph, x0:]
                for t in range((n_cols - pc + pw - 1) // pw):
                    row[pc + pw * t] = src[t]


@njit(**_JIT)
def _load_float(mosaic, m, rows, cols, r0, c0):
    """Fill the planes ``m`` of the tile whose first output site is (r0, c0) from a
    float32 mosaic, through the index maps ``rows``/``cols`` (:func:`tile_index`)."""
    _, ph, pw, ny, nx = m.shape
    for pr in range(ph):
        for y in range(ny):
            src = mosaic[rows[r0 + y * ph + pr]]
            for pc in range(pw):
                dst = m[0, pr, pc, y]
                for x in range(nx):
                    dst[x] = src[cols[c0 + x * pw + pc]]


@njit(parallel=True, **_JIT)
def _demosaic_image(
    mosaic, rows, cols, geometry, tile_rows, tile_cols, hy, hx, ny, nx, out, threads
):
    h, w = mosaic.shape
    ph, pw = geometry[0].shape
    n_r, n_c = (h + tile_rows - 1) // tile_rows, (w + tile_cols - 1) // tile_cols
    tiles = n_r * n_c
    threads = max(1, min(tiles, threads))
    counter = np.zeros(1, np.int64)  # the next tile (see rawsim.engine.tiles)
    for _ in prange(threads):  # each thread: its buffers, then tiles while any are left
        m, est, buf, scratch = new_buffers(ph, pw, ny, nx)
        while True:
            tile = next_tile(counter)
            if tile >= tiles:
                break
            r0, c0 = (tile // n_c) * tile_rows, (tile % n_c) * tile_cols
            _load_float(mosaic, m, rows, cols, r0, c0)
            result = demosaic_planes(m, est, buf, scratch, geometry)
            planes_to_image(
                result, hy, hx, min(tile_rows, h - r0), min(tile_cols, w - c0), out, r0, c0
            )


def demosaic_xtrans(
    mosaic: np.ndarray,
    cfa: CFA,
    method: str = "icd",
    iterations: int = ICD_ITERATIONS,
) -> np.ndarray:
    """Demosaic a (H, W) float32 mosaic on ``cfa`` → (3, H, W) float32.

    The same results as :func:`rawsim.isp.xtrans.demosaic_xtrans` (same arguments)
    to float32 rounding; runs on numba's threads (:func:`rawsim.engine.set_threads`).
    """
    import numba

    geo = Planes(cfa, method, iterations)
    mosaic = np.ascontiguousarray(mosaic, dtype=np.float32)
    if mosaic.ndim != 2:
        raise ParameterError(f"mosaic must be (H, W), got shape {mosaic.shape}")
    h, w = mosaic.shape
    need = geo.pad + max(cfa.period)
    if h < need or w < need:
        raise ParameterError(
            f"a {cfa.name} mosaic needs at least {need}×{need} pixels for {method!r}, got {h}×{w}"
        )
    if not np.isfinite(mosaic).all():
        raise ParameterError("mosaic contains NaN or infinite values")
    tile = geo.tile_shape()
    ny, nx = geo.buffer_planes(tile)
    out = np.empty((3, h, w), np.float32)
    _demosaic_image(
        mosaic,
        geo.index(h, 0, tile[0]),
        geo.index(w, 1, tile[1]),
        geo.args(),
        *tile,
        *geo.halo,
        ny,
        nx,
        out,
        numba.get_num_threads(),
    )
    return out
