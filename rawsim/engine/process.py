"""The fused process kernel: a Bayer mosaic in DN → an RGB image, tile by tile.

The image is cut into tiles of :data:`TILE_ROWS` × :data:`TILE_COLS` pixels,
parallel over tiles (``prange`` over the threads, each with its own buffers, each
taking the next tile while any are left: :mod:`rawsim.engine.tiles`).
For each tile every stage runs while the data is in cache: the mosaic stages
(black level, lens shading, white balance, highlight clip, in the config's
order) on the tile and a :data:`HALO` of context, the demosaic
(:mod:`rawsim.isp.demosaic`: ``bilinear``, ``malvar``, ``menon``, ``wcd``), where
``reconstruct`` rebuilt the mosaic its magenta guard (:func:`_guard`), then
per pixel the RGB stages (white balance, highlights, lens shading after
demosaic; colour matrix; exposure; tone and transfer) and the quantisation,
written straight to the oriented output.

Arithmetic is float32 in the reference's order of operations, so results agree
with the torch reference to rounding. Each intermediate of the demosaic lives in
a tile buffer that covers the tile plus the reach its consumers need; where the
reach crosses the image's edge, the buffer is filled by mirroring (the
reference's ``reflect`` padding, applied to that intermediate as the reference
applies it), so borders agree too.

Tone and transfer run through a lookup table of their composition on [0, 1]
with linear interpolation (error < 1e-7, far below a 16-bit code): they are
monotone with f(0) = 0 and f(1) ≥ 1, so clipping before them is clipping after
(a filmic curve's exposure, at most 4 stops, leaves 4096 entries below display white).
A power-law transfer, whose slope is unbounded at 0, is evaluated exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rawsim.engine import configure
from rawsim.engine import xtrans as xt
from rawsim.engine.magenta_guard import green_raise
from rawsim.engine.tiles import next_tile
from rawsim.isp.config import DEMOSAIC_ROOT_EPS

configure()

#: Compile options of every function here: cached on disk; float division by zero
#: gives inf/nan as in torch (numba's default "python" model checks every
#: division and raises, which also keeps loops from vectorising).
_JIT = {"cache": True, "error_model": "numpy"}

#: Tile size (even: tiles keep the CFA phase). Measured on a 24 MP wcd render:
#: 64 × 512 took 0.239 s on one thread and 0.126 s on two, 96 × 768 0.210 / 0.113 s
#: (less halo recomputed; larger tiles were slower on two threads, whose buffers
#: then share less cache).
TILE_ROWS = 96
TILE_COLS = 768
#: Context around a tile: the largest reach of any demosaic's chain (``learned``'s is
#: 13: ``wcd``'s 11 and its correction's 2), rounded up to keep the CFA phase.
HALO = 14

#: Demosaic codes.
DEMOSAIC_CODES = {"bilinear": 0, "malvar": 1, "menon": 2, "wcd": 3, "learned": 4}
#: Pointwise op codes (mosaic and RGB stages).
#: OP_ROOT/OP_SQUARE: into and out of the demosaic's root domain (the reference's
#: ``rawsim.isp.demosaic.to_root``/``from_root``), the last mosaic op and the first RGB op.
#: OP_CLIP clips at its number. (``unclip`` and ``reconstruct`` are pre-passes on the
#: mosaic: :mod:`rawsim.engine.highlights`.)
(
    OP_LEVELS,
    OP_SHADING,
    OP_WB,
    OP_CLIP,
    OP_BLEND,
    OP_MATRIX,
    OP_EXPOSURE,
    OP_ROOT,
    OP_SQUARE,
) = range(9)
#: Numbers an op takes at most (the columns of the ops' number arrays).
OP_NUMBERS = 20
#: Transfer codes of the output: table (tone ∘ transfer on [0, 1]), power law, none.
OUT_TABLE, OUT_GAMMA, OUT_FLOAT = range(3)
LUT_SIZE = 65536

_EPS = np.float32(1e-10)
_ROOT_EPS = np.float32(DEMOSAIC_ROOT_EPS)  # as rawsim.isp.demosaic.ROOT_EPS
_ROOT_SQRT_EPS = np.sqrt(_ROOT_EPS)
_ROOT_TWICE_SQRT_EPS = np.float32(2 * _ROOT_SQRT_EPS)
_HALF = np.float32(0.5)
_QUARTER = np.float32(-0.25)
_THIRD = np.float32(1 / 3)


# --------------------------------------------------------------------- tiles
@njit(inline="always", **_JIT)
def _span(q, r0, r1, c0, c1, h, w):
    """Buffer index ranges (rows, cols) of the in-image part of reach ``q``."""
    return (
        max(0, r0 - q) - r0 + HALO,
        min(h, r1 + q) - r0 + HALO,
        max(0, c0 - q) - c0 + HALO,
        min(w, c1 + q) - c0 + HALO,
    )


@njit(**_JIT)
def _mirror(b, q, r0, r1, c0, c1, h, w):
    """Fill the out-of-image positions within reach ``q`` by reflection (no edge repeat).

    Callers pass ``q`` as ``np.int64``: numba compiles a function called with a literal
    integer once for each literal (nine copies of this one, two of :func:`_wcd`).
    """
    ia, ib, ja, jb = _span(q, r0, r1, c0, c1, h, w)
    jlo, jhi = HALO - q, c1 - c0 + HALO + q
    for i in range(ia, ib):
        for j in range(jlo, ja):  # virtual column vc < 0 mirrors −vc
            b[i, j] = b[i, 2 * (HALO - c0) - j]
        for j in range(jb, jhi):  # vc ≥ w mirrors 2(w − 1) − vc
            b[i, j] = b[i, 2 * (w - 1 - c0 + HALO) - j]
    for i in range(HALO - q, ia):
        _copy_row(b, i, 2 * (HALO - r0) - i, jlo, jhi)
    for i in range(ib, r1 - r0 + HALO + q):
        _copy_row(b, i, 2 * (h - 1 - r0 + HALO) - i, jlo, jhi)


@njit(inline="always", **_JIT)
def _copy_row(b, i, src, jlo, jhi):
    """Row ``src`` of ``b`` into row ``i``, columns [jlo, jhi). A loop, not a slice
    assignment: numba compiles a slice assignment's shape check with its error
    message, 1.5–2.7 s of each kernel's first compile."""
    for j in range(jlo, jhi):
        b[i, j] = b[src, j]


# ------------------------------------------------------------ mosaic stages
@njit(inline="always", **_JIT)
def _mosaic_value(v, site, color, y, x, cy, cx, ops, opf):
    """The mosaic stages at one site: DN ``v`` (float32) → linear value, white = 1.

    ``ops`` lists the stages in order; ``opf[k]`` holds op ``k``'s numbers: levels
    (black per site ×4, then white − black per site ×4), white balance (R, G, B
    gains), shading (k1, k2, k3, strength), clip (its level).
    """
    for k in range(ops.size):
        op = ops[k]
        if op == OP_LEVELS:
            v = (v - np.float32(opf[k, site])) / np.float32(opf[k, 4 + site])
        elif op == OP_WB:
            v = v * np.float32(opf[k, color])
        elif op == OP_CLIP:
            v = min(v, np.float32(opf[k, 0]))
        elif op == OP_SHADING:
            v = v * _shading_gain(y, x, cy, cx, opf[k])
        elif op == OP_ROOT:
            v = _to_root(v)
    return v


@njit(inline="always", **_JIT)
def _to_root(v):
    """sign(v)·(√(|v| + ε) − √ε) as v / (√(|v| + ε) + √ε), float32
    (``rawsim.isp.demosaic.to_root``)."""
    return np.float32(v / (np.sqrt(abs(v) + _ROOT_EPS) + _ROOT_SQRT_EPS))


@njit(inline="always", **_JIT)
def _from_root(y):
    """sign(y)·((|y| + √ε)² − ε) as y·(|y| + 2√ε), float32
    (``rawsim.isp.demosaic.from_root``)."""
    return np.float32(y * (abs(y) + _ROOT_TWICE_SQRT_EPS))


@njit(**_JIT)
def mosaic_table(colors, ops, opf):
    """(4, 65536) float32: the mosaic stages for every code at each tile site.

    Valid when the stages do not depend on position (no lens shading).
    """
    table = np.empty((4, 65536), np.float32)
    for site in range(4):
        for code in range(65536):
            table[site, code] = _mosaic_value(
                np.float32(code), site, colors[site], 0, 0, 0.0, 0.0, ops, opf
            )
    return table


def load() -> None:
    """Initialise numba's CPU target and load a cached kernel (no work): what the
    first call would otherwise pay, done ahead (e.g. while a raw file is read)."""
    mosaic_table(np.zeros(4, np.int64), np.zeros(0, np.int64), np.zeros((1, OP_NUMBERS)))


@njit(**_JIT)
def _load_mosaic(raw, m, table, colors, ops, opf, r0, r1, c0, c1, h, w):
    """Mosaic stages on the tile's reach: raw DN (uint16) → ``m`` (float32, white = 1).

    Through ``table`` (see :func:`mosaic_table`) when it has rows, else site by site.
    """
    ia, ib, ja, jb = _span(HALO, r0, r1, c0, c1, h, w)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    for i in range(ia, ib):
        y = r0 - HALO + i
        x0 = c0 - HALO
        if table.shape[0]:
            even, odd = table[(y & 1) * 2], table[(y & 1) * 2 + 1]
            for j in range(ja, jb):
                code = raw[y, x0 + j]
                m[i, j] = even[code] if (x0 + j) & 1 == 0 else odd[code]
            continue
        for j in range(ja, jb):
            x = x0 + j
            site = (y & 1) * 2 + (x & 1)
            v = np.float32(raw[y, x])
            m[i, j] = _mosaic_value(v, site, colors[site], y, x, cy, cx, ops, opf)
    _mirror(m, np.int64(HALO), r0, r1, c0, c1, h, w)


@njit(inline="always", **_JIT)
def _shading_gain(y, x, cy, cx, p):
    """``rawsim.isp.lens_shading.radial_gain`` at (y, x), float64 → float32."""
    r2 = ((y - cy) ** 2 + (x - cx) ** 2) / (cy * cy + cx * cx)
    v = 1 + p[0] * r2 + p[1] * r2**2 + p[2] * r2**3
    return np.float32(1 + p[3] * (v - 1))


# --------------------------------------------------------------- demosaics
# Each demosaic reads the mosaic ``m`` (valid within HALO) and writes ``rgb``
# (3 buffers) on the tile. Sums follow the reference's tap order
# (:func:`rawsim.isp.planes.correlate`: row-major over the kernel's non-zeros).


@njit(inline="always", **_JIT)
def _pair(a, b):
    """_h/_v(x, _PAIR) of the two neighbours ``a`` and ``b`` (west/east or
    north/south): their mean, in the reference's order."""
    return a * _HALF + _HALF * b


@njit(**_JIT)
def _bilinear(m, rgb, cmap, r0, r1, c0, c1, h, w):
    """Bilinear demosaic (:func:`rawsim.isp.demosaic.demosaic_bilinear`), row by row
    over unit-stride views (every site's candidates computed, the site's kept)."""
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    q = np.float32(0.25)
    for i in range(ia, ib):
        cm, x = cmap[i & 1, ja:jb], _at(m, i, ja, jb, 0)
        red_row = _holds_red(cmap, i)
        e, wst, s_, n = _cross(m, i, ja, jb)
        nw, ne, sw, se = _diagonals(m, i, ja, jb, 1)
        o_r, o_g, o_b = _rows(rgb, i, ja, jb)
        for k in range(jb - ja):
            c, v = cm[k], x[k]
            cross = ((n[k] * q + q * wst[k]) + q * e[k]) + q * s_[k]
            diag = ((nw[k] * q + q * ne[k]) + q * sw[k]) + q * se[k]
            along_row = _pair(wst[k], e[k])
            along_col = _pair(n[k], s_[k])
            red_at_green = along_row if red_row else along_col
            blue_at_green = along_col if red_row else along_row
            o_g[k] = v if c == 1 else cross
            o_r[k] = v if c == 0 else (diag if c == 2 else red_at_green)
            o_b[k] = v if c == 2 else (diag if c == 0 else blue_at_green)


@njit(**_JIT)
def _malvar(m, rgb, cmap, r0, r1, c0, c1, h, w):
    """Malvar–He–Cutler demosaic (:func:`rawsim.isp.demosaic.demosaic_malvar`), row by
    row over unit-stride views (every site's candidates computed, the site's kept)."""
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    e = np.float32(0.125)
    two, four, six = np.float32(2), np.float32(4), np.float32(6)
    for i in range(ia, ib):
        cm = cmap[i & 1, ja:jb]
        red_row = _holds_red(cmap, i)
        w2, w1, x, e1, e2 = _line_h(m, i, ja, jb)
        n2, n1, _, s1, s2 = _line_v(m, i, ja, jb)
        nw, ne, sw, se = _diagonals(m, i, ja, jb, 1)
        o_r, o_g, o_b = _rows(rgb, i, ja, jb)
        for k in range(jb - ja):
            c, v = cm[k], x[k]
            diagonals = (nw[k] + ne[k]) + (sw[k] + se[k])
            ns2, we2 = n2[k] + s2[k], w2[k] + e2[k]
            ns1, we1 = n1[k] + s1[k], w1[k] + e1[k]
            row = _malvar_line(ns2, we2, we1, diagonals, v) * e
            col = _malvar_line(we2, ns2, ns1, diagonals, v) * e
            far = ns2 + we2
            near = ns1 + we1
            green = (two * near - far + four * v) * e
            other = (two * diagonals - np.float32(1.5) * far + six * v) * e
            o_g[k] = v if c == 1 else green
            o_r[k] = v if c == 0 else (other if c == 2 else (row if red_row else col))
            o_b[k] = v if c == 2 else (other if c == 0 else (col if red_row else row))


@njit(inline="always", **_JIT)
def _malvar_line(across2, along2, along1, diagonals, v):
    """Malvar's red or blue at a green site, from the line its colour lies along
    (``along1``, ``along2``: the sums of the neighbours 1 and 2 away on that line;
    ``across2``: 2 away across it), before the 1/8 scale."""
    return _HALF * across2 - diagonals - along2 + np.float32(4) * along1 + np.float32(5) * v


@njit(inline="always", **_JIT)
def _ha(w1, e1, w2, c, e2):
    """Hamilton–Adams green estimate from a line of five (−2 … +2): _h(m, _H0), _h(m, _H1)."""
    a = _pair(w1, e1)
    b = (w2 * _QUARTER + _HALF * c) + _QUARTER * e2
    return a, b


@njit(inline="always", **_JIT)
def _inv_sq(x):
    """(x + ε)⁻², the reference's ``(x + _EPS) ** -2``."""
    y = x + _EPS
    return np.float32(1.0) / (y * y)


@njit(inline="always", **_JIT)
def _wcd_weights(s_e, s_w, s_s, s_n):
    """The four directions' weights 1 / (gradient sum)² and their total, as the
    reference (computed where green is estimated and again where red and blue are,
    cheaper than storing five tiles of them)."""
    w_e, w_w, w_s, w_n = _inv_sq(s_e), _inv_sq(s_w), _inv_sq(s_s), _inv_sq(s_n)
    return w_e, w_w, w_s, w_n, ((w_e + w_w) + w_s) + w_n


@njit(inline="always", **_JIT)
def _diagonal_weight(near, far, g_near, g, m_far, v):
    """1 / (local gradient towards a diagonal neighbour)², as the reference.

    ``near``/``far``: the mosaic at the neighbour and opposite it; ``g_near``/``g``:
    green at the neighbour and the centre; ``m_far``/``v``: the mosaic two steps
    out and at the centre.
    """
    grad = abs(near - far) + abs(g_near - g)
    return _inv_sq(grad + abs(m_far - v))


@njit(inline="always", **_JIT)
def _at(b, i, ja, jb, dj):
    """Row ``i`` of ``b`` over columns [ja + dj, jb + dj): a unit-stride view.

    The row loops index these views from 0, so that LLVM sees plain streams and
    vectorises them (indexing ``b[i, j - 1]`` with a signed ``j`` does not).
    """
    return b[i, ja + dj : jb + dj]


@njit(inline="always", **_JIT)
def _rows(rgb, i, ja, jb):
    """Row ``i`` of each of the three buffers ``rgb`` (:func:`_at`)."""
    return _at(rgb[0], i, ja, jb, 0), _at(rgb[1], i, ja, jb, 0), _at(rgb[2], i, ja, jb, 0)


@njit(inline="always", **_JIT)
def _holds_red(cmap, i):
    """Whether row ``i`` of a Bayer tile holds red: its green sites' row neighbours
    are red (else blue)."""
    return cmap[i & 1, 0] == 0 or cmap[i & 1, 1] == 0


@njit(inline="always", **_JIT)
def _line_h(b, i, ja, jb):
    """Views of row ``i`` shifted by −2, −1, 0, 1, 2 columns."""
    return (
        _at(b, i, ja, jb, -2),
        _at(b, i, ja, jb, -1),
        _at(b, i, ja, jb, 0),
        _at(b, i, ja, jb, 1),
        _at(b, i, ja, jb, 2),
    )


@njit(inline="always", **_JIT)
def _line_v(b, i, ja, jb):
    """Views of rows i − 2 … i + 2."""
    return (
        _at(b, i - 2, ja, jb, 0),
        _at(b, i - 1, ja, jb, 0),
        _at(b, i, ja, jb, 0),
        _at(b, i + 1, ja, jb, 0),
        _at(b, i + 2, ja, jb, 0),
    )


@njit(inline="always", **_JIT)
def _cross(b, i, ja, jb):
    """Views of the east, west, south and north neighbours of row ``i``."""
    return (
        _at(b, i, ja, jb, 1),
        _at(b, i, ja, jb, -1),
        _at(b, i + 1, ja, jb, 0),
        _at(b, i - 1, ja, jb, 0),
    )


@njit(inline="always", **_JIT)
def _diagonals(b, i, ja, jb, s):
    """Views ``s`` steps towards the north-west, north-east, south-west, south-east."""
    return (
        _at(b, i - s, ja, jb, -s),
        _at(b, i - s, ja, jb, s),
        _at(b, i + s, ja, jb, -s),
        _at(b, i + s, ja, jb, s),
    )


@njit(inline="always", **_JIT)
def _sum5(lines, out):
    """``out`` = the five row views ``lines`` summed, in the reference's order."""
    a0, a1, a2, a3, a4 = lines
    for k in range(out.size):
        out[k] = (((a0[k] + a1[k]) + a2[k]) + a3[k]) + a4[k]


@njit(**_JIT)
def _wcd(m, b, rgb, cmap, r0, r1, c0, c1, h, w, q):
    """Weighted colour-difference demosaic (:func:`rawsim.isp.demosaic.demosaic_wcd`),
    written ``q`` sites beyond the tile (what :func:`_correct` reads around it)."""
    dh, dv, gh, gv, bh, bv, sh, sv = b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]
    grn, red1, blue1, yr, yb = b[8], b[9], b[10], b[11], b[12]
    one, zero = np.float32(1.0), np.float32(0.0)
    # Colour differences G − C along rows and columns (reach 9 + q).
    ia, ib, ja, jb = _span(9 + q, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm = cmap[i & 1, ja:jb]
        w2, w1, x, e1, e2 = _line_h(m, i, ja, jb)
        n2, n1, _, s1, s2 = _line_v(m, i, ja, jb)
        oh, ov = _at(dh, i, ja, jb, 0), _at(dv, i, ja, jb, 0)
        for k in range(jb - ja):
            sign = one if cm[k] == 1 else -one
            a, c = _ha(w1[k], e1[k], w2[k], x[k], e2[k])
            oh[k] = sign * (x[k] - a - c)
            a, c = _ha(n1[k], s1[k], n2[k], x[k], s2[k])
            ov[k] = sign * (x[k] - a - c)
    for buf in (dh, dv):
        _mirror(buf, 9 + q, r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(8 + q, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        he, hw, _, _ = _cross(dh, i, ja, jb)
        _, _, vs, vn = _cross(dv, i, ja, jb)
        oh, ov = _at(gh, i, ja, jb, 0), _at(gv, i, ja, jb, 0)
        for k in range(jb - ja):
            oh[k] = abs(hw[k] - he[k])
            ov[k] = abs(vn[k] - vs[k])
    for buf in (gh, gv):
        _mirror(buf, 8 + q, r0, r1, c0, c1, h, w)
    # 5 × 5 box sums: along rows, then along columns.
    ia, ib, ja, jb = _span(6 + q, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for src, dst in ((gh, bh), (gv, bv)):
            _sum5(_line_h(src, i, ja, jb), _at(dst, i, ja, jb, 0))
    for buf in (bh, bv):
        _mirror(buf, 6 + q, r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(4 + q, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for src, dst in ((bh, sh), (bv, sv)):
            _sum5(_line_v(src, i, ja, jb), _at(dst, i, ja, jb, 0))
    for buf in (sh, sv):
        _mirror(buf, 4 + q, r0, r1, c0, c1, h, w)
    # Green: the four one-sided estimates, weighted by 1 / (gradient sum)².
    ia, ib, ja, jb = _span(2 + q, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, x = cmap[i & 1, ja:jb], _at(m, i, ja, jb, 0)
        hw2, hw1, h0, he1, he2 = _line_h(dh, i, ja, jb)
        vn2, vn1, v0, vs1, vs2 = _line_v(dv, i, ja, jb)
        s_w, _, _, _, s_e = _line_h(sh, i, ja, jb)
        s_n, _, _, _, s_s = _line_v(sv, i, ja, jb)
        o_g = _at(grn, i, ja, jb, 0)
        for k in range(jb - ja):
            e_e = (h0[k] * _THIRD + _THIRD * he1[k]) + _THIRD * he2[k]
            e_w = (hw2[k] * _THIRD + _THIRD * hw1[k]) + _THIRD * h0[k]
            e_s = (v0[k] * _THIRD + _THIRD * vs1[k]) + _THIRD * vs2[k]
            e_n = (vn2[k] * _THIRD + _THIRD * vn1[k]) + _THIRD * v0[k]
            w_e, w_w, w_s, w_n, total = _wcd_weights(s_e[k], s_w[k], s_s[k], s_n[k])
            delta = (((w_e * e_e + w_w * e_w) + w_s * e_s) + w_n * e_n) / total
            c, v = cm[k], x[k]
            g = v if c == 1 else v + delta
            o_g[k] = g
    _mirror(grn, 2 + q, r0, r1, c0, c1, h, w)
    # Red at blue sites and blue at red sites: diagonal colour differences (the
    # diagonal neighbours of a red site are blue and of a blue one red: their
    # green − mosaic is the difference of the colour missing here).
    ia, ib, ja, jb = _span(1 + q, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, x, g0 = cmap[i & 1, ja:jb], _at(m, i, ja, jb, 0), _at(grn, i, ja, jb, 0)
        mnw, mne, msw, mse = _diagonals(m, i, ja, jb, 1)
        fnw, fne, fsw, fse = _diagonals(m, i, ja, jb, 2)
        gnw, gne, gsw, gse = _diagonals(grn, i, ja, jb, 1)
        o_r, o_b = _at(red1, i, ja, jb, 0), _at(blue1, i, ja, jb, 0)
        o_yr, o_yb = _at(yr, i, ja, jb, 0), _at(yb, i, ja, jb, 0)
        for k in range(jb - ja):
            c, v, g = cm[k], x[k], g0[k]
            w0 = _diagonal_weight(mnw[k], mse[k], gnw[k], g, fnw[k], v)
            w1 = _diagonal_weight(mne[k], msw[k], gne[k], g, fne[k], v)
            w2 = _diagonal_weight(msw[k], mne[k], gsw[k], g, fsw[k], v)
            w3 = _diagonal_weight(mse[k], mnw[k], gse[k], g, fse[k], v)
            total = ((w0 + w1) + w2) + w3
            d0, d1 = gnw[k] - mnw[k], gne[k] - mne[k]
            d2, d3 = gsw[k] - msw[k], gse[k] - mse[k]
            md = ((w0 * d0 + w1 * d1) + w2 * d2) + w3 * d3
            r = v if c == 0 else (g - md / total if c == 2 else zero)
            bl = v if c == 2 else (g - md / total if c == 0 else zero)
            o_r[k], o_b[k] = r, bl
            o_yr[k] = g - r if c != 1 else zero
            o_yb[k] = g - bl if c != 1 else zero
    for buf in (yr, yb):
        _mirror(buf, 1 + q, r0, r1, c0, c1, h, w)
    # Red and blue at green sites: the four neighbours' differences, weighted as green.
    ia, ib, ja, jb = _span(q, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, g0 = cmap[i & 1, ja:jb], _at(grn, i, ja, jb, 0)
        s_w, _, _, _, s_e = _line_h(sh, i, ja, jb)
        s_n, _, _, _, s_s = _line_v(sv, i, ja, jb)
        re, rw, rs, rn = _cross(yr, i, ja, jb)
        be, bw, bs, bn = _cross(yb, i, ja, jb)
        r1_, b1_ = _at(red1, i, ja, jb, 0), _at(blue1, i, ja, jb, 0)
        o_r, o_g, o_b = _rows(rgb, i, ja, jb)
        for k in range(jb - ja):
            g = g0[k]
            w_e, w_w, w_s, w_n, t = _wcd_weights(s_e[k], s_w[k], s_s[k], s_n[k])
            cr = ((w_e * re[k] + w_w * rw[k]) + w_s * rs[k]) + w_n * rn[k]
            cb = ((w_e * be[k] + w_w * bw[k]) + w_s * bs[k]) + w_n * bn[k]
            green = cm[k] == 1
            o_g[k] = g
            o_r[k] = g - cr / t if green else r1_[k]
            o_b[k] = g - cb / t if green else b1_[k]


@njit(**_JIT)
def _correct(src, b, rgb, cmap, wt, r0, r1, c0, c1, h, w):
    """The ``learned`` demosaic's correction after :func:`_wcd`
    (:func:`rawsim.learned_demosaic.correction.correct`): ``src``, ``wcd``'s three
    buffers mirrored within reach 2, into ``rgb`` on the tile.

    The filters are symmetric in rows and in columns, so each input colour's 5 × 5
    window reduces to 9 sums over the sites (±|dy|, ±|dx|) away: ``b[0:6]`` first
    holds each row's v[x − 1] + v[x + 1] and v[x − 2] + v[x + 2]. A row of a Bayer
    mosaic measures one colour at even columns and another at odd ones, and lacks
    the third: two sums per site suffice, ``b[6]`` for the colour the other
    column measures and ``b[7]`` for the third. One pass per input colour adds its
    share to both, the weights alternating with the column's parity, in loops
    that LLVM vectorises. ``wt`` (2, 2, 2, 3, 3, 3): the weights by row and column
    parity, sum, input colour, |dy|, |dx|
    (:func:`rawsim.learned_demosaic.filters.site_filters`).
    """
    _, _, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    for ch in range(3):
        for i in range(HALO - 2, r1 - r0 + HALO + 2):  # the tile's rows and 2 each side
            w2, w1, _, e1, e2 = _line_h(src[ch], i, ja, jb)
            o1, o2 = _at(b[2 * ch], i, ja, jb, 0), _at(b[2 * ch + 1], i, ja, jb, 0)
            for k in range(jb - ja):
                o1[k] = w1[k] + e1[k]
                o2[k] = w2[k] + e2[k]
    zero = np.float32(0.0)
    ia, ib, _, _ = _span(0, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        other, third = _at(b[6], i, ja, jb, 0), _at(b[7], i, ja, jb, 0)
        for k in range(jb - ja):
            other[k], third[k] = zero, zero
        for ch in range(3):
            _accumulate(
                src[ch],
                b[2 * ch],
                b[2 * ch + 1],
                wt[i & 1, 0, :, ch],
                wt[i & 1, 1, :, ch],
                i,
                ja,
                jb,
                other,
                third,
            )
        even, odd = cmap[i & 1, ja], cmap[i & 1, ja + 1]  # ja is even: the tile keeps the CFA phase
        for c in range(3):
            x, out = _at(src[c], i, ja, jb, 0), _at(rgb[c], i, ja, jb, 0)
            if c != even and c != odd:
                for k in range(jb - ja):
                    out[k] = x[k] + third[k]
            else:
                for k in range(jb - ja):
                    lacks = (k & 1 == 0) == (c == odd)  # the site lacks c
                    out[k] = x[k] + (other[k] if lacks else zero)


@njit(inline="always", **_JIT)
def _accumulate(v, h1, h2, e, o, i, ja, jb, other, third):
    """Add one input colour's share to :func:`_correct`'s two sums on row ``i``: its
    values ``v`` and row sums ``h1``, ``h2``; ``e``/``o`` (2, 3, 3): the weights at
    even and odd columns (sum, |dy|, |dx|)."""
    n2, n1, v0, s1, s2 = _line_v(v, i, ja, jb)
    a2, a1, a0, b1, b2 = _line_v(h1, i, ja, jb)
    c2, c1, c0, d1, d2 = _line_v(h2, i, ja, jb)
    other_e, other_o, third_e, third_o = _nine(e[0]), _nine(o[0]), _nine(e[1]), _nine(o[1])
    for k in range(jb - ja):
        even = k & 1 == 0
        g = (
            v0[k],
            a0[k],
            c0[k],
            n1[k] + s1[k],
            a1[k] + b1[k],
            c1[k] + d1[k],
            n2[k] + s2[k],
            a2[k] + b2[k],
            c2[k] + d2[k],
        )
        other[k] += _weigh(other_e, other_o, even, g)
        third[k] += _weigh(third_e, third_o, even, g)


@njit(inline="always", **_JIT)
def _nine(w):
    """The weights ``w`` (3, 3) as 9 scalars, |dy| then |dx|: loads from the array in a
    loop could alias the sums the loop writes, and keep it from vectorising."""
    return (w[0, 0], w[0, 1], w[0, 2], w[1, 0], w[1, 1], w[1, 2], w[2, 0], w[2, 1], w[2, 2])


@njit(inline="always", **_JIT)
def _weigh(e, o, even, g):
    """The 9 group sums ``g`` weighted by ``e`` at an even column, else ``o``."""
    t = (e[0] if even else o[0]) * g[0]
    t += (e[1] if even else o[1]) * g[1]
    t += (e[2] if even else o[2]) * g[2]
    t += (e[3] if even else o[3]) * g[3]
    t += (e[4] if even else o[4]) * g[4]
    t += (e[5] if even else o[5]) * g[5]
    t += (e[6] if even else o[6]) * g[6]
    t += (e[7] if even else o[7]) * g[7]
    return t + (e[8] if even else o[8]) * g[8]


@njit(**_JIT)
def _menon(m, b, rgb, cmap, r0, r1, c0, c1, h, w):
    """Menon et al. 2007 with refining (:func:`rawsim.isp.demosaic.demosaic_menon`), row
    by row over unit-stride views: every site's candidates computed and the site's
    (or the decided direction's) kept, so that LLVM vectorises the loops."""
    g_h, g_v, c_h, c_v, d_h, d_v, hz, grn = b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]
    red0, blue0, red1, blue1, grn2, red2, blue2 = b[8], b[9], b[10], b[11], b[12], b[13], b[14]
    dif_r, dif_b, rb = b[15], b[16], b[17]
    zero, three = np.float32(0.0), 3.0
    # 1. Directional green estimates and colour differences at R/B sites (reach 9).
    ia, ib, ja, jb = _span(9, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm = cmap[i & 1, ja:jb]
        w2, w1, x, e1, e2 = _line_h(m, i, ja, jb)
        n2, n1, _, s1, s2 = _line_v(m, i, ja, jb)
        o_gh, o_gv = _at(g_h, i, ja, jb, 0), _at(g_v, i, ja, jb, 0)
        o_ch, o_cv = _at(c_h, i, ja, jb, 0), _at(c_v, i, ja, jb, 0)
        for k in range(jb - ja):
            v, green = x[k], cm[k] == 1
            a, c = _ha(w1[k], e1[k], w2[k], v, e2[k])
            o_gh[k] = v if green else a + c
            o_ch[k] = zero if green else v - (a + c)
            a, c = _ha(n1[k], s1[k], n2[k], v, s2[k])
            o_gv[k] = v if green else a + c
            o_cv[k] = zero if green else v - (a + c)
    for q in (g_h, g_v, c_h, c_v):
        _mirror(q, np.int64(9), r0, r1, c0, c1, h, w)
    # 2. The decision: colour differences vary less along the edge.
    ia, ib, ja, jb = _span(7, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        ch0, ch2 = _at(c_h, i, ja, jb, 0), _at(c_h, i, ja, jb, 2)
        cv0, cv2 = _at(c_v, i, ja, jb, 0), _at(c_v, i + 2, ja, jb, 0)
        o_dh, o_dv = _at(d_h, i, ja, jb, 0), _at(d_v, i, ja, jb, 0)
        for k in range(jb - ja):
            o_dh[k] = abs(ch0[k] - ch2[k])
            o_dv[k] = abs(cv0[k] - cv2[k])
    for q in (d_h, d_v):
        _mirror(q, np.int64(7), r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(5, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        h00, h02, h11 = (
            _at(d_h, i - 2, ja, jb, 0),
            _at(d_h, i - 2, ja, jb, 2),
            _at(d_h, i - 1, ja, jb, 1),
        )
        h20, h22, h31 = _at(d_h, i, ja, jb, 0), _at(d_h, i, ja, jb, 2), _at(d_h, i + 1, ja, jb, 1)
        h40, h42 = _at(d_h, i + 2, ja, jb, 0), _at(d_h, i + 2, ja, jb, 2)
        v0m, v00, v0p = _at(d_v, i, ja, jb, -2), _at(d_v, i, ja, jb, 0), _at(d_v, i, ja, jb, 2)
        v1m, v1p = _at(d_v, i + 1, ja, jb, -1), _at(d_v, i + 1, ja, jb, 1)
        v2m, v20, v2p = (
            _at(d_v, i + 2, ja, jb, -2),
            _at(d_v, i + 2, ja, jb, 0),
            _at(d_v, i + 2, ja, jb, 2),
        )
        gh, gv = _at(g_h, i, ja, jb, 0), _at(g_v, i, ja, jb, 0)
        o_hz, o_g = _at(hz, i, ja, jb, 0), _at(grn, i, ja, jb, 0)
        for k in range(jb - ja):
            # Taps in the reference's order; its weight-3 taps are fused multiply-adds
            # (one rounding), done here in float64, which is exact before the rounding.
            sh = (h00[k] + h02[k]) + h11[k]
            sh = np.float32(np.float64(sh) + three * np.float64(h20[k]))
            sh = np.float32(np.float64(sh) + three * np.float64(h22[k]))
            sh = ((sh + h31[k]) + h40[k]) + h42[k]
            sv = np.float32(np.float64(v0m[k]) + three * np.float64(v00[k]))
            sv = (((sv + v0p[k]) + v1m[k]) + v1p[k]) + v2m[k]
            sv = np.float32(np.float64(sv) + three * np.float64(v20[k]))
            sv = sv + v2p[k]
            horizontal = sv >= sh
            o_hz[k] = np.float32(1.0) if horizontal else zero
            o_g[k] = gh[k] if horizontal else gv[k]
    for q in (hz, grn):
        _mirror(q, np.int64(5), r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(5, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, x, g0 = cmap[i & 1, ja:jb], _at(m, i, ja, jb, 0), _at(grn, i, ja, jb, 0)
        o_dr, o_db = _at(dif_r, i, ja, jb, 0), _at(dif_b, i, ja, jb, 0)
        o_rb, o_r0 = _at(rb, i, ja, jb, 0), _at(red0, i, ja, jb, 0)
        for k in range(jb - ja):
            c = cm[k]
            o_dr[k] = x[k] if c == 0 else zero  # red, sparse
            o_db[k] = x[k] if c == 2 else zero  # blue, sparse
            o_rb[k] = g0[k] if c == 0 else zero  # green * r
            o_r0[k] = g0[k] if c == 2 else zero  # green * b (scratch)
    for q in (dif_r, dif_b, rb, red0):
        _mirror(q, np.int64(5), r0, r1, c0, c1, h, w)
    # 3. Red and blue at green sites from the colour difference along the row/column.
    ia, ib, ja, jb = _span(4, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, x, g0 = cmap[i & 1, ja:jb], _at(m, i, ja, jb, 0), _at(grn, i, ja, jb, 0)
        red_row = _holds_red(cmap, i)
        dr_e, dr_w, dr_s, dr_n = _cross(dif_r, i, ja, jb)
        rb_e, rb_w, rb_s, rb_n = _cross(rb, i, ja, jb)
        db_e, db_w, db_s, db_n = _cross(dif_b, i, ja, jb)
        r0_e, r0_w, r0_s, r0_n = _cross(red0, i, ja, jb)
        o_r, o_b = _at(red1, i, ja, jb, 0), _at(blue1, i, ja, jb, 0)
        for k in range(jb - ja):
            c, g = cm[k], g0[k]
            red_h = (g + _pair(dr_w[k], dr_e[k])) - _pair(rb_w[k], rb_e[k])
            red_v = (g + _pair(dr_n[k], dr_s[k])) - _pair(rb_n[k], rb_s[k])
            blue_h = (g + _pair(db_w[k], db_e[k])) - _pair(r0_w[k], r0_e[k])
            blue_v = (g + _pair(db_n[k], db_s[k])) - _pair(r0_n[k], r0_s[k])
            red_g = red_h if red_row else red_v
            blue_g = blue_v if red_row else blue_h
            o_r[k] = red_g if c == 1 else (x[k] if c == 0 else zero)
            o_b[k] = blue_g if c == 1 else (x[k] if c == 2 else zero)
    for q in (red1, blue1):
        _mirror(q, np.int64(4), r0, r1, c0, c1, h, w)
    # 4. Red at blue sites and blue at red sites, along the decided direction.
    ia, ib, ja, jb = _span(3, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, g0, hz0 = cmap[i & 1, ja:jb], _at(grn, i, ja, jb, 0), _at(hz, i, ja, jb, 0)
        r1_e, r1_w, r1_s, r1_n = _cross(red1, i, ja, jb)
        b1_e, b1_w, b1_s, b1_n = _cross(blue1, i, ja, jb)
        r1_0, b1_0 = _at(red1, i, ja, jb, 0), _at(blue1, i, ja, jb, 0)
        o_r, o_b = _at(red0, i, ja, jb, 0), _at(blue0, i, ja, jb, 0)
        o_dr, o_db = _at(dif_r, i, ja, jb, 0), _at(dif_b, i, ja, jb, 0)
        for k in range(jb - ja):
            c, horizontal = cm[k], hz0[k] != 0
            r, bl = r1_0[k], b1_0[k]
            red_pair = _pair(r1_w[k], r1_e[k]) if horizontal else _pair(r1_n[k], r1_s[k])
            blue_pair = _pair(b1_w[k], b1_e[k]) if horizontal else _pair(b1_n[k], b1_s[k])
            r_at_blue = (bl + red_pair) - blue_pair
            b_at_red = (r + blue_pair) - red_pair
            r = r_at_blue if c == 2 else r
            bl = b_at_red if c == 0 else bl
            o_r[k], o_b[k] = r, bl
            o_dr[k] = r - g0[k]
            o_db[k] = bl - g0[k]
    for q in (red0, blue0, dif_r, dif_b):
        _mirror(q, np.int64(3), r0, r1, c0, c1, h, w)
    # 5. Refining: green at R/B sites from the smoothed differences (reach 2) ...
    ia, ib, ja, jb = _span(2, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, g0, hz0 = cmap[i & 1, ja:jb], _at(grn, i, ja, jb, 0), _at(hz, i, ja, jb, 0)
        r0_0, b0_0 = _at(red0, i, ja, jb, 0), _at(blue0, i, ja, jb, 0)
        dr_e, dr_w, dr_s, dr_n = _cross(dif_r, i, ja, jb)
        db_e, db_w, db_s, db_n = _cross(dif_b, i, ja, jb)
        dr_0, db_0 = _at(dif_r, i, ja, jb, 0), _at(dif_b, i, ja, jb, 0)
        o_g2, o_gh, o_gv = _at(grn2, i, ja, jb, 0), _at(g_h, i, ja, jb, 0), _at(g_v, i, ja, jb, 0)
        for k in range(jb - ja):
            c, horizontal = cm[k], hz0[k] != 0
            mean_r = _three(dr_w[k], dr_0[k], dr_e[k], dr_n[k], dr_s[k], horizontal)
            mean_b = _three(db_w[k], db_0[k], db_e[k], db_n[k], db_s[k], horizontal)
            g2 = r0_0[k] - mean_r if c == 0 else (b0_0[k] - mean_b if c == 2 else g0[k])
            o_g2[k] = g2
            o_gh[k] = r0_0[k] - g2  # red − green (scratch)
            o_gv[k] = b0_0[k] - g2  # blue − green (scratch)
    for q in (grn2, g_h, g_v):
        _mirror(q, np.int64(2), r0, r1, c0, c1, h, w)
    # ... red and blue at green sites from their neighbours' differences (reach 1) ...
    ia, ib, ja, jb = _span(1, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, g0 = cmap[i & 1, ja:jb], _at(grn2, i, ja, jb, 0)
        red_row = _holds_red(cmap, i)
        r0_0, b0_0 = _at(red0, i, ja, jb, 0), _at(blue0, i, ja, jb, 0)
        gh_e, gh_w, gh_s, gh_n = _cross(g_h, i, ja, jb)
        gv_e, gv_w, gv_s, gv_n = _cross(g_v, i, ja, jb)
        o_r, o_b, o_c = _at(red2, i, ja, jb, 0), _at(blue2, i, ja, jb, 0), _at(c_h, i, ja, jb, 0)
        for k in range(jb - ja):
            g = g0[k]
            along_h = _pair(gh_w[k], gh_e[k])
            along_v = _pair(gh_n[k], gh_s[k])
            blue_h = _pair(gv_w[k], gv_e[k])
            blue_v = _pair(gv_n[k], gv_s[k])
            r_g = g + (along_h if red_row else along_v)
            b_g = g + (blue_v if red_row else blue_h)
            green = cm[k] == 1
            r = r_g if green else r0_0[k]
            bl = b_g if green else b0_0[k]
            o_r[k], o_b[k] = r, bl
            o_c[k] = r - bl  # red − blue (scratch)
    for q in (red2, blue2, c_h):
        _mirror(q, np.int64(1), r0, r1, c0, c1, h, w)
    # ... and red at blue sites, blue at red sites from the smoothed R − B difference.
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        cm, hz0 = cmap[i & 1, ja:jb], _at(hz, i, ja, jb, 0)
        ch_e, ch_w, ch_s, ch_n = _cross(c_h, i, ja, jb)
        ch_0, g2 = _at(c_h, i, ja, jb, 0), _at(grn2, i, ja, jb, 0)
        r2_0, b2_0 = _at(red2, i, ja, jb, 0), _at(blue2, i, ja, jb, 0)
        o_r, o_g, o_b = _rows(rgb, i, ja, jb)
        for k in range(jb - ja):
            c = cm[k]
            red_blue = _three(ch_w[k], ch_0[k], ch_e[k], ch_n[k], ch_s[k], hz0[k] != 0)
            r, bl = r2_0[k], b2_0[k]
            o_r[k] = bl + red_blue if c == 2 else r
            o_g[k] = g2[k]
            o_b[k] = r - red_blue if c == 0 else bl


@njit(inline="always", **_JIT)
def _three(west, centre, east, north, south, horizontal):
    """smoothed(x, _MEAN3): the mean of three along the decided direction (the row
    or the column through ``centre``)."""
    if horizontal:
        return (west * _THIRD + _THIRD * centre) + _THIRD * east
    return (north * _THIRD + _THIRD * centre) + _THIRD * south


# --------------------------------------------------------------- RGB stages
@njit(**_JIT)
def _finish(rgb, ops, opf, out_mode, lut, gamma, scale, orient, out, r0, r1, c0, c1, h, w):
    """RGB stages, tone/transfer and quantisation of the tile, written to ``out``.

    ``out`` is (H', W', 3): uint8/uint16 codes (``scale`` = 2^bits − 1) or float32
    (``out_mode`` OUT_FLOAT), already in display orientation: ``orient`` = (transpose,
    flip rows, flip columns). Row by row, each stage over the whole row.
    Overwrites ``rgb``.
    """
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    at = np.empty(jb - ja, np.int32)  # _encode's table positions
    for i in range(ia, ib):
        y, x0 = r0 - HALO + i, c0 - HALO + ja
        r, g, b = _rows(rgb, i, ja, jb)
        for k in range(ops.size):
            _rgb_stage(ops[k], opf[k], r, g, b, y, x0, h, w)
        if out_mode != OUT_FLOAT:
            for v in (r, g, b):
                _encode(v, out_mode, lut, gamma, scale, at)
        _store(r, g, b, out, y, x0, orient)


@njit(**_JIT)
def _guard(rgb, near, near_rows, to_xyz, post_ops, r0, r1, c0, c1, h, w):
    """``reconstruct``'s magenta guard (:mod:`rawsim.engine.magenta_guard`) on the
    tile's pixels that ``near`` (H, W) uint8 marks (in the rows ``near_rows`` (H,)
    marks), in ``rgb`` as the demosaic left it: square roots where the post ops start
    by squaring them. ``to_xyz``: camera → XYZ over the white (3, 3) float64."""
    root = post_ops.size > 0 and post_ops[0] == OP_SQUARE
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    red, green, blue = rgb
    for i in range(ia, ib):
        if not near_rows[r0 - HALO + i]:
            continue
        marks = near[r0 - HALO + i]
        for j in range(ja, jb):
            if not marks[c0 - HALO + j]:
                continue
            r, g, b = red[i, j], green[i, j], blue[i, j]
            if root:
                r, g, b = _from_root(r), _from_root(g), _from_root(b)
            d = green_raise(np.float64(r), np.float64(g), np.float64(b), to_xyz)
            if d > 0.0:
                g = np.float32(g + np.float32(d))
                green[i, j] = _to_root(g) if root else g


@njit(**_JIT)
def _rgb_stage(op, p, r, g, b, y, x0, h, w):
    """One RGB stage on a row: ``r``, ``g``, ``b`` (views) in place; its first pixel is (y, x0)."""
    if op == OP_WB:
        sr, sg, sb = np.float32(p[0]), np.float32(p[1]), np.float32(p[2])
        for q in range(r.size):
            r[q], g[q], b[q] = r[q] * sr, g[q] * sg, b[q] * sb
    elif op == OP_CLIP:
        top = np.float32(p[0])
        for q in range(r.size):
            r[q], g[q], b[q] = min(r[q], top), min(g[q], top), min(b[q], top)
    elif op == OP_MATRIX:
        m = (
            np.float32(p[0]),
            np.float32(p[1]),
            np.float32(p[2]),
            np.float32(p[3]),
            np.float32(p[4]),
            np.float32(p[5]),
            np.float32(p[6]),
            np.float32(p[7]),
            np.float32(p[8]),
        )
        for q in range(r.size):
            r[q], g[q], b[q] = _matrix(m, 0, r[q], g[q], b[q])
    elif op == OP_EXPOSURE:
        s = np.float32(p[0])
        for q in range(r.size):
            r[q], g[q], b[q] = r[q] * s, g[q] * s, b[q] * s
    elif op == OP_SHADING:
        cy, cx = (h - 1) / 2, (w - 1) / 2
        for q in range(r.size):
            s = _shading_gain(y, x0 + q, cy, cx, p)
            r[q], g[q], b[q] = r[q] * s, g[q] * s, b[q] * s
    elif op == OP_BLEND:
        for q in range(r.size):
            r[q], g[q], b[q] = _blend(p, r[q], g[q], b[q])
    elif op == OP_SQUARE:
        for q in range(r.size):
            r[q], g[q], b[q] = _from_root(r[q]), _from_root(g[q]), _from_root(b[q])


@njit(**_JIT)
def _encode(v, out_mode, lut, gamma, scale, at):
    """Tone ∘ transfer and quantisation of a row of one channel, in place (codes as
    floats). Inputs are clipped to [0, 1], where the table is defined.

    In three passes, so that only the table lookups are scalar: the table position
    (into ``at``, int32, ``v.size`` or more) and its fraction (into ``v``), the
    interpolation, then the power law and the codes (vectorised): 1.1 ns per value
    on one core, where one pass took 2.0 ns.
    """
    one, zero = np.float32(1.0), np.float32(0.0)
    for q in range(v.size):
        t = min(max(v[q], zero), one) * np.float32(LUT_SIZE - 1)
        n = min(np.int32(t), np.int32(LUT_SIZE - 2))
        at[q] = n
        v[q] = t - np.float32(n)
    for q in range(v.size):
        n = at[q]
        v[q] = lut[n] + v[q] * (lut[n + 1] - lut[n])
    for q in range(v.size):
        x = v[q]
        if out_mode == OUT_GAMMA:
            x = np.float32(max(x, np.float32(1e-12)) ** gamma) if x > 0 else x
        x = min(max(x, zero), one)
        v[q] = np.rint(x * np.float32(scale))


@njit(**_JIT)
def _store(r, g, b, out, y, x0, orient):
    """Write a row (first pixel at (y, x0)) into the oriented ``out``."""
    transpose, flip_rows, flip_cols = orient[0], orient[1], orient[2]
    out_h, out_w = out.shape[0], out.shape[1]
    if not transpose:
        row = out[out_h - 1 - y if flip_rows else y]
        if not flip_cols:
            dst = row[x0 : x0 + r.size]
            for q in range(r.size):
                dst[q, 0], dst[q, 1], dst[q, 2] = r[q], g[q], b[q]
            return
        for q in range(r.size):
            ox = out_w - 1 - (x0 + q)
            row[ox, 0], row[ox, 1], row[ox, 2] = r[q], g[q], b[q]
        return
    ox = out_w - 1 - y if flip_cols else y
    for q in range(r.size):
        oy = x0 + q
        oy = out_h - 1 - oy if flip_rows else oy
        out[oy, ox, 0], out[oy, ox, 1], out[oy, ox, 2] = r[q], g[q], b[q]


@njit(inline="always", **_JIT)
def _matrix(p, at, r, g, b):
    """(r, g, b) → M (r, g, b) with M row-major in p[at : at + 9], float32."""
    return (
        (np.float32(p[at]) * r + np.float32(p[at + 1]) * g) + np.float32(p[at + 2]) * b,
        (np.float32(p[at + 3]) * r + np.float32(p[at + 4]) * g) + np.float32(p[at + 5]) * b,
        (np.float32(p[at + 6]) * r + np.float32(p[at + 7]) * g) + np.float32(p[at + 8]) * b,
    )


@njit(inline="always", **_JIT)
def _blend(p, r, g, b):
    """dcraw's highlight blend (:func:`rawsim.isp.highlights.handle_highlights`).

    p[0:9] is the lightness/chroma transform, p[9:18] its inverse, p[18] the least
    colour's clip level.
    """
    one = np.float32(p[18])
    if not (r > one or g > one or b > one):
        return r, g, b
    _, c1, c2 = _matrix(p, 0, r, g, b)
    lab0, l1, l2 = _matrix(p, 0, min(r, one), min(g, one), min(b, one))
    chroma_cam = c1 * c1 + c2 * c2
    chroma_lab = l1 * l1 + l2 * l2
    ratio = max(chroma_lab / max(chroma_cam, np.float32(1e-20)), np.float32(1e-30))
    s = np.float32(math.sqrt(ratio))
    return _matrix(p, 9, lab0, c1 * s, c2 * s)


# ------------------------------------------------------------------ kernel
@njit(**_JIT)
def _rgb_buffers(shape):
    """Three float32 tile buffers of ``shape``, each its own allocation.

    Not slices of one block: separate allocations let LLVM check the row loops'
    streams for overlap at run time and vectorise them.
    """
    return (
        np.empty(shape, np.float32),
        np.empty(shape, np.float32),
        np.empty(shape, np.float32),
    )


@njit(**_JIT)
def _scratch_buffers(shape):
    """The demosaics' 18 intermediate tile buffers (see :func:`_rgb_buffers`)."""
    a, b, c, d = _rgb_buffers(shape), _rgb_buffers(shape), _rgb_buffers(shape), _rgb_buffers(shape)
    e, f = _rgb_buffers(shape), _rgb_buffers(shape)
    return a + b + c + d + e + f


def _bayer_kernel(name: str, learned: bool):
    """A Bayer render kernel named ``name``: ``learned``'s demosaic if ``learned``,
    else the others. ``learned`` is a constant of each kernel's closure, so numba
    compiles only its branch: a first render with the default demosaic compiles
    neither ``menon``, ``malvar`` nor ``bilinear`` (a first ``process`` took 30 s
    against 49 s with one kernel for all, on a 2-core AMD EPYC Zen 5)."""

    def kernel(
        raw,
        colors,
        method,
        filters,
        table,
        near,
        near_rows,
        to_xyz,
        pre_ops,
        pre_f,
        post_ops,
        post_f,
        out_mode,
        lut,
        gamma,
        scale,
        orient,
        out,
        threads,
        tile_rows,
        tile_cols,
    ):
        """Render the (H, W) uint16 mosaic ``raw`` into ``out`` (see :func:`_finish`).

        ``colors``: the CFA's colour index at the 4 tile sites (row-major);
        ``method``: a :data:`DEMOSAIC_CODES` value (:func:`bayer_kernel` picks the kernel
        for it); ``filters``: the ``learned`` one's (:func:`_correct`; any float32 array of
        that shape for the others). ``near``/``near_rows``/``to_xyz``: the magenta guard's
        (:func:`_guard`).
        ``threads``: numba's thread count (each thread gets its
        own tile buffers); tiles are ``tile_rows`` × ``tile_cols`` (even numbers: tiles keep
        the CFA phase; default :data:`TILE_ROWS`, :data:`TILE_COLS`).
        """
        h, w = raw.shape
        rows, cols = (h + tile_rows - 1) // tile_rows, (w + tile_cols - 1) // tile_cols
        tiles = rows * cols
        threads = max(1, min(tiles, threads))
        shape = (tile_rows + 2 * HALO, tile_cols + 2 * HALO)
        cmap = np.empty((2, shape[1]), np.int8)  # colour index at (row parity, buffer column)
        for j in range(shape[1]):
            cmap[0, j], cmap[1, j] = colors[j & 1], colors[2 + (j & 1)]
        counter = np.zeros(1, np.int64)  # the next tile (see rawsim.engine.tiles)
        for _ in prange(threads):  # each thread: its buffers, then tiles while any are left
            m = np.empty(shape, np.float32)
            rgb = _rgb_buffers(shape)
            bufs = _scratch_buffers(shape)
            while True:
                tile = next_tile(counter)
                if tile >= tiles:
                    break
                r0, c0 = (tile // cols) * tile_rows, (tile % cols) * tile_cols
                r1, c1 = min(h, r0 + tile_rows), min(w, c0 + tile_cols)
                _load_mosaic(raw, m, table, colors, pre_ops, pre_f, r0, r1, c0, c1, h, w)
                if learned:
                    first = (bufs[13], bufs[14], bufs[15])  # wcd; bufs[:6] are free after it
                    _wcd(m, bufs, first, cmap, r0, r1, c0, c1, h, w, np.int64(2))
                    for buf in first:
                        _mirror(buf, np.int64(2), r0, r1, c0, c1, h, w)
                    _correct(first, bufs, rgb, cmap, filters, r0, r1, c0, c1, h, w)
                elif method == 0:
                    _bilinear(m, rgb, cmap, r0, r1, c0, c1, h, w)
                elif method == 1:
                    _malvar(m, rgb, cmap, r0, r1, c0, c1, h, w)
                elif method == 2:
                    _menon(m, bufs, rgb, cmap, r0, r1, c0, c1, h, w)
                else:
                    _wcd(m, bufs, rgb, cmap, r0, r1, c0, c1, h, w, np.int64(0))
                if near.shape[0]:
                    _guard(rgb, near, near_rows, to_xyz, post_ops, r0, r1, c0, c1, h, w)
                _finish(
                    rgb,
                    post_ops,
                    post_f,
                    out_mode,
                    lut,
                    gamma,
                    scale,
                    orient,
                    out,
                    r0,
                    r1,
                    c0,
                    c1,
                    h,
                    w,
                )

    kernel.__name__ = kernel.__qualname__ = name
    return njit(parallel=True, nogil=True, **_JIT)(kernel)


#: The default demosaic's kernel, and the other Bayer demosaics' (:func:`_bayer_kernel`).
learned_kernel = _bayer_kernel("learned_kernel", True)
process_kernel = _bayer_kernel("process_kernel", False)


def bayer_kernel(method: int):
    """The Bayer render kernel for ``method``, a :data:`DEMOSAIC_CODES` value."""
    return learned_kernel if method == DEMOSAIC_CODES["learned"] else process_kernel


# ------------------------------------------------------ other periodic CFAs
@njit(**_JIT)
def _load_planes(raw, m, rows, cols, r0, c0, cmap, table, ops, opf, h, w):
    """Mosaic stages of the tile whose first output site is (r0, c0), into its phase
    planes ``m`` (see :mod:`rawsim.engine.xtrans`): raw DN (uint16) → white = 1.

    Each buffer site takes the value of its source site (``rows``/``cols``, the
    image's sites and their phase-preserving reflection): the reference runs these
    stages before it extends the mosaic. Levels and white balance are per colour
    (``cmap``, the colour of each phase); through ``table`` (one row per colour,
    :func:`mosaic_table`) when it has rows, else site by site.
    """
    _, ph, pw, ny, nx = m.shape
    cy, cx = (h - 1) / 2, (w - 1) / 2
    for pr in range(ph):
        for y in range(ny):
            sy = rows[r0 + y * ph + pr]
            src = raw[sy]
            for pc in range(pw):
                dst = m[0, pr, pc, y]
                color = cmap[pr, pc]
                if table.shape[0]:
                    tab = table[color]
                    for x in range(nx):
                        dst[x] = tab[src[cols[c0 + x * pw + pc]]]
                    continue
                for x in range(nx):
                    sx = cols[c0 + x * pw + pc]
                    v = np.float32(src[sx])
                    dst[x] = _mosaic_value(v, color, color, sy, sx, cy, cx, ops, opf)


@njit(parallel=True, nogil=True, **_JIT)
def periodic_kernel(
    raw,
    rows,
    cols,
    geometry,
    table,
    near,
    near_rows,
    to_xyz,
    pre_ops,
    pre_f,
    post_ops,
    post_f,
    out_mode,
    lut,
    gamma,
    scale,
    orient,
    out,
    threads,
    tile_rows,
    tile_cols,
    halo_rows,
    halo_cols,
):
    """:func:`process_kernel` for any periodic CFA (X-Trans): the mosaic stages per
    colour, the demosaic of :mod:`rawsim.engine.xtrans` (``geometry``: its
    ``Planes.args()``) in phase planes, then the same RGB stages and output.

    ``near``/``near_rows``/``to_xyz``: the magenta guard's (:func:`_guard`).
    ``rows``/``cols``: :func:`rawsim.engine.xtrans.tile_index` of the image for tiles of
    ``tile_rows`` × ``tile_cols`` (whole periods) and halos ``halo_rows``/``halo_cols``.
    Levels ops hold black and white − black per colour (R, G, B) in their site slots.
    """
    h, w = raw.shape
    cmap = geometry[0]
    ph, pw = cmap.shape
    n_r, n_c = (h + tile_rows - 1) // tile_rows, (w + tile_cols - 1) // tile_cols
    tiles = n_r * n_c
    threads = max(1, min(tiles, threads))
    ny, nx = (tile_rows + 2 * halo_rows) // ph, (tile_cols + 2 * halo_cols) // pw
    counter = np.zeros(1, np.int64)  # the next tile (see rawsim.engine.tiles)
    for _ in prange(threads):  # each thread: its buffers, then tiles while any are left
        m, est, buf, scratch = xt.new_buffers(ph, pw, ny, nx)
        rgb = _rgb_buffers((tile_rows + 2 * HALO, tile_cols + 2 * HALO))
        while True:
            tile = next_tile(counter)
            if tile >= tiles:
                break
            r0, c0 = (tile // n_c) * tile_rows, (tile % n_c) * tile_cols
            r1, c1 = min(h, r0 + tile_rows), min(w, c0 + tile_cols)
            _load_planes(raw, m, rows, cols, r0, c0, cmap, table, pre_ops, pre_f, h, w)
            result = xt.demosaic_planes(m, est, buf, scratch, geometry)
            xt.planes_to_image(
                result, halo_rows, halo_cols, r1 - r0, c1 - c0, rgb, np.int64(HALO), np.int64(HALO)
            )
            if near.shape[0]:
                _guard(rgb, near, near_rows, to_xyz, post_ops, r0, r1, c0, c1, h, w)
            _finish(
                rgb,
                post_ops,
                post_f,
                out_mode,
                lut,
                gamma,
                scale,
                orient,
                out,
                r0,
                r1,
                c0,
                c1,
                h,
                w,
            )


# ---------------------------------------------------------------- half size
@njit(inline="always", **_JIT)
def _site(raw, y, x, k, color, table, ops, opf, cy, cx):
    """The mosaic stages at site (y, x) of table row (levels slot) ``k``: white = 1."""
    if table.shape[0]:
        return table[k, raw[y, x]]
    return _mosaic_value(np.float32(raw[y, x]), k, color, y, x, cy, cx, ops, opf)


@njit(**_JIT)
def _half_row(raw, y0, j0, j1, classes, cmap, table, rgb, row, shift):
    """Blocks j0 … j1 − 1 of block row y0 / 2 of a 2 × 2 layout with every colour,
    into ``rgb`` row ``row`` at columns j + ``shift``: :func:`half_kernel`'s whole
    blocks, the same expression, over unit-stride output views."""
    a, b, c, d = cmap[0, 0], cmap[0, 1], cmap[1, 0], cmap[1, 1]
    ta, tb = table[classes[0, 0]], table[classes[0, 1]]
    tc, td = table[classes[1, 0]], table[classes[1, 1]]
    top, bottom = raw[y0, 2 * j0 : 2 * j1], raw[y0 + 1, 2 * j0 : 2 * j1]
    for k in range(3):
        n = (a == k) + (b == k) + (c == k) + (d == k)
        dst = rgb[k][row, j0 + shift : j1 + shift]
        for q in range(j1 - j0):
            va, vb = ta[top[2 * q]], tb[top[2 * q + 1]]
            vc, vd = tc[bottom[2 * q]], td[bottom[2 * q + 1]]
            s = ((va * (a == k) + vb * (b == k)) + vc * (c == k)) + vd * (d == k)
            dst[q] = s / np.float32(n)


@njit(parallel=True, nogil=True, **_JIT)
def half_kernel(
    raw,
    classes,
    cmap,
    table,
    pre_ops,
    pre_f,
    post_ops,
    post_f,
    out_mode,
    lut,
    gamma,
    scale,
    orient,
    out,
    threads,
    tile_rows,
    tile_cols,
):
    """Half-size render (:mod:`rawsim.isp.half_size`): the mosaic stages, each output
    pixel's colours from its 2×2 block (a missing colour from the 4×4 window around
    it), then the RGB stages and output of :func:`_finish`, into ``out`` of
    ⌈H/2⌉ × ⌈W/2⌉ (oriented). Tiles of ``tile_rows`` × ``tile_cols`` output pixels.

    ``classes``/``cmap``: the table row (levels slot) and the colour of each site of
    one period (Bayer: the 4 sites; other patterns: the colour for both).
    """
    h, w = raw.shape
    ph, pw = cmap.shape
    h2, w2 = (h + 1) // 2, (w + 1) // 2
    cy, cx = (h - 1) / 2, (w - 1) / 2
    row_phase = np.arange(h) % ph  # no division in the loops
    col_phase = np.arange(w) % pw
    n_r, n_c = (h2 + tile_rows - 1) // tile_rows, (w2 + tile_cols - 1) // tile_cols
    tiles = n_r * n_c
    threads = max(1, min(tiles, threads))
    # A 2 × 2 period with every colour, through the table: each whole block is alike.
    bayer = ph == 2 and pw == 2 and table.shape[0] > 0
    for k in range(3):
        bayer = bayer and ((cmap == k).sum() > 0)
    counter = np.zeros(1, np.int64)  # the next tile (see rawsim.engine.tiles)
    for _ in prange(threads):  # each thread: its buffers, then tiles while any are left
        rgb = _rgb_buffers((tile_rows + 2 * HALO, tile_cols + 2 * HALO))
        total = np.zeros(3, np.float32)
        count = np.zeros(3, np.int64)
        while True:
            tile = next_tile(counter)
            if tile >= tiles:
                break
            r0, c0 = (tile // n_c) * tile_rows, (tile % n_c) * tile_cols
            r1, c1 = min(h2, r0 + tile_rows), min(w2, c0 + tile_cols)
            for i in range(r0, r1):
                y0, y1 = 2 * i, 2 * i + 1
                j0 = c0  # the first block left to the loop below
                if bayer and y1 < h:  # whole 2×2 blocks of one layout: a vectorised row
                    j0 = max(c0, min(c1, w // 2))
                    _half_row(raw, y0, c0, j0, classes, cmap, table, rgb, HALO + i - r0, HALO - c0)
                for j in range(j0, c1):
                    x0, x1 = 2 * j, 2 * j + 1
                    if y1 < h and x1 < w:  # a whole block, in scalars
                        p0, p1, q0, q1 = row_phase[y0], row_phase[y1], col_phase[x0], col_phase[x1]
                        a, b = cmap[p0, q0], cmap[p0, q1]
                        c, d = cmap[p1, q0], cmap[p1, q1]
                        va = _site(raw, y0, x0, classes[p0, q0], a, table, pre_ops, pre_f, cy, cx)
                        vb = _site(raw, y0, x1, classes[p0, q1], b, table, pre_ops, pre_f, cy, cx)
                        vc = _site(raw, y1, x0, classes[p1, q0], c, table, pre_ops, pre_f, cy, cx)
                        vd = _site(raw, y1, x1, classes[p1, q1], d, table, pre_ops, pre_f, cy, cx)
                        missing = False
                        for k in range(3):
                            n = (a == k) + (b == k) + (c == k) + (d == k)
                            if n == 0:
                                missing = True
                                break
                            s = ((va * (a == k) + vb * (b == k)) + vc * (c == k)) + vd * (d == k)
                            rgb[k][HALO + i - r0, HALO + j - c0] = s / np.float32(n)
                        if not missing:
                            continue
                    for k in range(3):  # an edge block, or one missing a colour
                        total[k] = np.float32(0.0)
                        count[k] = 0
                    for y in range(y0, min(h, y0 + 2)):
                        for x in range(x0, min(w, x0 + 2)):
                            py, px = row_phase[y], col_phase[x]
                            c = cmap[py, px]
                            v = _site(raw, y, x, classes[py, px], c, table, pre_ops, pre_f, cy, cx)
                            total[c] += v
                            count[c] += 1
                    for k in range(3):
                        if count[k]:
                            value = total[k] / np.float32(count[k])
                        else:  # not in the block: the 4×4 window around it
                            s, n = np.float32(0.0), 0
                            for y in range(max(0, y0 - 1), min(h, y0 + 3)):
                                py = row_phase[y]
                                for x in range(max(0, x0 - 1), min(w, x0 + 3)):
                                    px = col_phase[x]
                                    if cmap[py, px] == k:
                                        k2 = classes[py, px]
                                        s += _site(raw, y, x, k2, k, table, pre_ops, pre_f, cy, cx)
                                        n += 1
                            value = s / np.float32(max(n, 1))
                        rgb[k][HALO + i - r0, HALO + j - c0] = value
            _finish(
                rgb,
                post_ops,
                post_f,
                out_mode,
                lut,
                gamma,
                scale,
                orient,
                out,
                r0,
                r1,
                c0,
                c1,
                h2,
                w2,
            )
