"""The fused process kernel: a Bayer mosaic in DN → an RGB image, tile by tile.

The image is cut into tiles of :data:`TILE_ROWS` × :data:`TILE_COLS` pixels,
parallel over tiles (``prange`` over the threads, each with its own buffers).
For each tile every stage runs while the data is in cache: the mosaic stages
(black level, lens shading, white balance, highlight clip, in the config's
order) on the tile and a :data:`HALO` of context, the demosaic
(:mod:`rawsim.isp.demosaic`: ``bilinear``, ``malvar``, ``menon``, ``wcd``), then
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
monotone with f(0) = 0 and f(1) = 1, so clipping before them is clipping after.
A power-law transfer, whose slope is unbounded at 0, is evaluated exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rawsim.engine import configure

configure()

TILE_ROWS = 64
TILE_COLS = 512
#: Context around a tile: the largest reach of any demosaic's chain (Menon's is 11).
HALO = 12

#: Demosaic codes.
DEMOSAIC_CODES = {"bilinear": 0, "malvar": 1, "menon": 2, "wcd": 3}
#: Pointwise op codes (mosaic and RGB stages).
OP_LEVELS, OP_SHADING, OP_WB, OP_CLIP, OP_BLEND, OP_MATRIX, OP_EXPOSURE = range(7)
#: Transfer codes of the output: table (tone ∘ transfer on [0, 1]), power law, none.
OUT_TABLE, OUT_GAMMA, OUT_FLOAT = range(3)
LUT_SIZE = 65536

_EPS = np.float32(1e-10)
_HALF = np.float32(0.5)
_QUARTER = np.float32(-0.25)
_THIRD = np.float32(1 / 3)


# --------------------------------------------------------------------- tiles
@njit(cache=True, inline="always")
def _span(q, r0, r1, c0, c1, h, w):
    """Buffer index ranges (rows, cols) of the in-image part of reach ``q``."""
    return (
        max(0, r0 - q) - r0 + HALO,
        min(h, r1 + q) - r0 + HALO,
        max(0, c0 - q) - c0 + HALO,
        min(w, c1 + q) - c0 + HALO,
    )


@njit(cache=True)
def _mirror(b, q, r0, r1, c0, c1, h, w):
    """Fill the out-of-image positions within reach ``q`` by reflection (no edge repeat)."""
    ia, ib, ja, jb = _span(q, r0, r1, c0, c1, h, w)
    jlo, jhi = HALO - q, c1 - c0 + HALO + q
    for i in range(ia, ib):
        for j in range(jlo, ja):  # virtual column vc < 0 mirrors −vc
            b[i, j] = b[i, 2 * (HALO - c0) - j]
        for j in range(jb, jhi):  # vc ≥ w mirrors 2(w − 1) − vc
            b[i, j] = b[i, 2 * (w - 1 - c0 + HALO) - j]
    for i in range(HALO - q, ia):
        b[i, jlo:jhi] = b[2 * (HALO - r0) - i, jlo:jhi]
    for i in range(ib, r1 - r0 + HALO + q):
        b[i, jlo:jhi] = b[2 * (h - 1 - r0 + HALO) - i, jlo:jhi]


# ------------------------------------------------------------ mosaic stages
@njit(cache=True, inline="always")
def _mosaic_value(v, site, color, y, x, cy, cx, ops, opf):
    """The mosaic stages at one site: DN ``v`` (float32) → linear value, white = 1.

    ``ops`` lists the stages in order; ``opf[k]`` holds op ``k``'s numbers: levels
    (black per site ×4, then white − black per site ×4), white balance (R, G, B
    gains), shading (k1, k2, k3, strength). Clip has none.
    """
    for k in range(ops.size):
        op = ops[k]
        if op == OP_LEVELS:
            v = (v - np.float32(opf[k, site])) / np.float32(opf[k, 4 + site])
        elif op == OP_WB:
            v = v * np.float32(opf[k, color])
        elif op == OP_CLIP:
            v = min(v, np.float32(1.0))
        elif op == OP_SHADING:
            v = v * _shading_gain(y, x, cy, cx, opf[k])
    return v


@njit(cache=True)
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


@njit(cache=True)
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
    _mirror(m, HALO, r0, r1, c0, c1, h, w)


@njit(cache=True, inline="always")
def _shading_gain(y, x, cy, cx, p):
    """``rawsim.isp.lens_shading.radial_gain`` at (y, x), float64 → float32."""
    r2 = ((y - cy) ** 2 + (x - cx) ** 2) / (cy * cy + cx * cx)
    v = 1 + p[0] * r2 + p[1] * r2**2 + p[2] * r2**3
    return np.float32(1 + p[3] * (v - 1))


# --------------------------------------------------------------- demosaics
# Each demosaic reads the mosaic ``m`` (valid within HALO) and writes ``rgb``
# (3 buffers) on the tile. Sums follow the reference's tap order
# (:func:`rawsim.isp.planes.correlate`: row-major over the kernel's non-zeros).


@njit(cache=True)
def _bilinear(m, rgb, colors, r0, r1, c0, c1, h, w):
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            v = m[i, j]
            cross = (
                (m[i - 1, j] * np.float32(0.25) + np.float32(0.25) * m[i, j - 1])
                + np.float32(0.25) * m[i, j + 1]
            ) + np.float32(0.25) * m[i + 1, j]
            diag = (
                (m[i - 1, j - 1] * np.float32(0.25) + np.float32(0.25) * m[i - 1, j + 1])
                + np.float32(0.25) * m[i + 1, j - 1]
            ) + np.float32(0.25) * m[i + 1, j + 1]
            along_row = m[i, j - 1] * _HALF + _HALF * m[i, j + 1]
            along_col = m[i - 1, j] * _HALF + _HALF * m[i + 1, j]
            if c == 1:
                red_row = colors[(i & 1) * 2 + ((j + 1) & 1)] == 0
                rgb[1, i, j] = v
                rgb[0, i, j] = along_row if red_row else along_col
                rgb[2, i, j] = along_col if red_row else along_row
            else:
                rgb[1, i, j] = cross
                rgb[c, i, j] = v
                rgb[2 - c, i, j] = diag


@njit(cache=True)
def _malvar(m, rgb, colors, r0, r1, c0, c1, h, w):
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    e = np.float32(0.125)
    two, four, five, six = np.float32(2), np.float32(4), np.float32(5), np.float32(6)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            v = m[i, j]
            diagonals = (m[i - 1, j - 1] + m[i - 1, j + 1]) + (m[i + 1, j - 1] + m[i + 1, j + 1])
            if c == 1:
                row = (
                    _HALF * (m[i - 2, j] + m[i + 2, j])
                    - diagonals
                    - (m[i, j - 2] + m[i, j + 2])
                    + four * (m[i, j - 1] + m[i, j + 1])
                    + five * v
                ) * e
                col = (
                    _HALF * (m[i, j - 2] + m[i, j + 2])
                    - diagonals
                    - (m[i - 2, j] + m[i + 2, j])
                    + four * (m[i - 1, j] + m[i + 1, j])
                    + five * v
                ) * e
                red_row = colors[(i & 1) * 2 + ((j + 1) & 1)] == 0
                rgb[1, i, j] = v
                rgb[0, i, j] = row if red_row else col
                rgb[2, i, j] = col if red_row else row
            else:
                far = (m[i - 2, j] + m[i + 2, j]) + (m[i, j - 2] + m[i, j + 2])
                near = (m[i - 1, j] + m[i + 1, j]) + (m[i, j - 1] + m[i, j + 1])
                rgb[1, i, j] = (two * near - far + four * v) * e
                rgb[c, i, j] = v
                rgb[2 - c, i, j] = (two * diagonals - np.float32(1.5) * far + six * v) * e


@njit(cache=True, inline="always")
def _ha_h(m, i, j):
    """_h(m, _H0) + _h(m, _H1): Hamilton–Adams green estimate along the row."""
    a = m[i, j - 1] * _HALF + _HALF * m[i, j + 1]
    b = (m[i, j - 2] * _QUARTER + _HALF * m[i, j]) + _QUARTER * m[i, j + 2]
    return a, b


@njit(cache=True, inline="always")
def _ha_v(m, i, j):
    a = m[i - 1, j] * _HALF + _HALF * m[i + 1, j]
    b = (m[i - 2, j] * _QUARTER + _HALF * m[i, j]) + _QUARTER * m[i + 2, j]
    return a, b


@njit(cache=True, inline="always")
def _inv_sq(x):
    """(x + ε)⁻², the reference's ``(x + _EPS) ** -2``."""
    y = x + _EPS
    return np.float32(1.0) / (y * y)


@njit(cache=True, inline="always")
def _diagonal_weight(m, grn, i, j, dy, dx):
    """1 / (local gradient towards the diagonal neighbour (dy, dx))², as the reference."""
    grad = abs(m[i + dy, j + dx] - m[i - dy, j - dx]) + abs(grn[i + dy, j + dx] - grn[i, j])
    return _inv_sq(grad + abs(m[i + 2 * dy, j + 2 * dx] - m[i, j]))


@njit(cache=True)
def _wcd(m, b, rgb, colors, r0, r1, c0, c1, h, w):
    """Weighted colour-difference demosaic (:func:`rawsim.isp.demosaic.demosaic_wcd`)."""
    dh, dv, gh, gv, bh, bv, sh, sv = b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]
    we, ww, ws, wn, tot, grn, xr, xb = b[8], b[9], b[10], b[11], b[12], b[13], b[14], b[15]
    red1, blue1, yr, yb = b[16], b[17], b[18], b[19]
    # Colour differences G − C along rows and columns (reach 9).
    ia, ib, ja, jb = _span(9, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        even, odd = colors[(i & 1) * 2], colors[(i & 1) * 2 + 1]
        for j in range(ja, jb):
            sign = np.float32(1.0) if (even if j & 1 == 0 else odd) == 1 else np.float32(-1.0)
            a, c = _ha_h(m, i, j)
            dh[i, j] = sign * (m[i, j] - a - c)
            a, c = _ha_v(m, i, j)
            dv[i, j] = sign * (m[i, j] - a - c)
    for x in (dh, dv):
        _mirror(x, 9, r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(8, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            gh[i, j] = abs(dh[i, j - 1] - dh[i, j + 1])
            gv[i, j] = abs(dv[i - 1, j] - dv[i + 1, j])
    for x in (gh, gv):
        _mirror(x, 8, r0, r1, c0, c1, h, w)
    # 5 × 5 box sums: along rows, then along columns.
    ia, ib, ja, jb = _span(6, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            bh[i, j] = (((gh[i, j - 2] + gh[i, j - 1]) + gh[i, j]) + gh[i, j + 1]) + gh[i, j + 2]
            bv[i, j] = (((gv[i, j - 2] + gv[i, j - 1]) + gv[i, j]) + gv[i, j + 1]) + gv[i, j + 2]
    for x in (bh, bv):
        _mirror(x, 6, r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(4, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            sh[i, j] = (((bh[i - 2, j] + bh[i - 1, j]) + bh[i, j]) + bh[i + 1, j]) + bh[i + 2, j]
            sv[i, j] = (((bv[i - 2, j] + bv[i - 1, j]) + bv[i, j]) + bv[i + 1, j]) + bv[i + 2, j]
    for x in (sh, sv):
        _mirror(x, 4, r0, r1, c0, c1, h, w)
    # Green: the four one-sided estimates, weighted by 1 / (gradient sum)².
    ia, ib, ja, jb = _span(2, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        even, odd = colors[(i & 1) * 2], colors[(i & 1) * 2 + 1]
        for j in range(ja, jb):
            c = even if j & 1 == 0 else odd
            e_e = (dh[i, j] * _THIRD + _THIRD * dh[i, j + 1]) + _THIRD * dh[i, j + 2]
            e_w = (dh[i, j - 2] * _THIRD + _THIRD * dh[i, j - 1]) + _THIRD * dh[i, j]
            e_s = (dv[i, j] * _THIRD + _THIRD * dv[i + 1, j]) + _THIRD * dv[i + 2, j]
            e_n = (dv[i - 2, j] * _THIRD + _THIRD * dv[i - 1, j]) + _THIRD * dv[i, j]
            w_e, w_w = _inv_sq(sh[i, j + 2]), _inv_sq(sh[i, j - 2])
            w_s, w_n = _inv_sq(sv[i + 2, j]), _inv_sq(sv[i - 2, j])
            total = ((w_e + w_w) + w_s) + w_n
            we[i, j], ww[i, j], ws[i, j], wn[i, j], tot[i, j] = w_e, w_w, w_s, w_n, total
            delta = (((w_e * e_e + w_w * e_w) + w_s * e_s) + w_n * e_n) / total
            g = m[i, j] if c == 1 else m[i, j] + delta
            grn[i, j] = g
            xr[i, j] = g - m[i, j] if c == 0 else np.float32(0.0)
            xb[i, j] = g - m[i, j] if c == 2 else np.float32(0.0)
    for x in (grn, xr, xb):
        _mirror(x, 2, r0, r1, c0, c1, h, w)
    # Red at blue sites and blue at red sites: diagonal colour differences.
    ia, ib, ja, jb = _span(1, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        even, odd = colors[(i & 1) * 2], colors[(i & 1) * 2 + 1]
        for j in range(ja, jb):
            c = even if j & 1 == 0 else odd
            w0 = _diagonal_weight(m, grn, i, j, -1, -1)
            w1 = _diagonal_weight(m, grn, i, j, -1, 1)
            w2 = _diagonal_weight(m, grn, i, j, 1, -1)
            w3 = _diagonal_weight(m, grn, i, j, 1, 1)
            total = ((w0 + w1) + w2) + w3
            mr = (
                (w0 * xr[i - 1, j - 1] + w1 * xr[i - 1, j + 1]) + w2 * xr[i + 1, j - 1]
            ) + w3 * xr[i + 1, j + 1]
            mb = (
                (w0 * xb[i - 1, j - 1] + w1 * xb[i - 1, j + 1]) + w2 * xb[i + 1, j - 1]
            ) + w3 * xb[i + 1, j + 1]
            g = grn[i, j]
            r = m[i, j] if c == 0 else (g - mr / total if c == 2 else np.float32(0.0))
            bl = m[i, j] if c == 2 else (g - mb / total if c == 0 else np.float32(0.0))
            red1[i, j], blue1[i, j] = r, bl
            yr[i, j] = g - r if c != 1 else np.float32(0.0)
            yb[i, j] = g - bl if c != 1 else np.float32(0.0)
    for x in (yr, yb):
        _mirror(x, 1, r0, r1, c0, c1, h, w)
    # Red and blue at green sites: the four neighbours' differences, weighted as green.
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            g = grn[i, j]
            rgb[1, i, j] = g
            if colors[(i & 1) * 2 + (j & 1)] == 1:
                w_e, w_w, w_s, w_n, total = we[i, j], ww[i, j], ws[i, j], wn[i, j], tot[i, j]
                cr = ((w_e * yr[i, j + 1] + w_w * yr[i, j - 1]) + w_s * yr[i + 1, j]) + w_n * yr[
                    i - 1, j
                ]
                cb = ((w_e * yb[i, j + 1] + w_w * yb[i, j - 1]) + w_s * yb[i + 1, j]) + w_n * yb[
                    i - 1, j
                ]
                rgb[0, i, j] = g - cr / total
                rgb[2, i, j] = g - cb / total
            else:
                rgb[0, i, j] = red1[i, j]
                rgb[2, i, j] = blue1[i, j]


@njit(cache=True, inline="always")
def _pair_h(x, i, j):
    """_h(x, _PAIR): the mean of the left and right neighbours."""
    return x[i, j - 1] * _HALF + _HALF * x[i, j + 1]


@njit(cache=True, inline="always")
def _pair_v(x, i, j):
    return x[i - 1, j] * _HALF + _HALF * x[i + 1, j]


@njit(cache=True, inline="always")
def _mean3(x, i, j, horizontal):
    """smoothed(x, _MEAN3): the mean of three along the decided direction."""
    if horizontal:
        return (x[i, j - 1] * _THIRD + _THIRD * x[i, j]) + _THIRD * x[i, j + 1]
    return (x[i - 1, j] * _THIRD + _THIRD * x[i, j]) + _THIRD * x[i + 1, j]


@njit(cache=True)
def _menon(m, b, rgb, colors, r0, r1, c0, c1, h, w):
    """Menon et al. 2007 with refining (:func:`rawsim.isp.demosaic.demosaic_menon`)."""
    g_h, g_v, c_h, c_v, d_h, d_v, hz, grn = b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]
    red0, blue0, red1, blue1, grn2, red2, blue2 = b[8], b[9], b[10], b[11], b[12], b[13], b[14]
    dif_r, dif_b, rb = b[15], b[16], b[17]
    # 1. Directional green estimates and colour differences at R/B sites (reach 9).
    ia, ib, ja, jb = _span(9, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            v = m[i, j]
            if colors[(i & 1) * 2 + (j & 1)] == 1:
                g_h[i, j], g_v[i, j] = v, v
                c_h[i, j], c_v[i, j] = np.float32(0.0), np.float32(0.0)
            else:
                a, c = _ha_h(m, i, j)
                g_h[i, j] = a + c
                c_h[i, j] = v - (a + c)
                a, c = _ha_v(m, i, j)
                g_v[i, j] = a + c
                c_v[i, j] = v - (a + c)
    for x in (g_h, g_v, c_h, c_v):
        _mirror(x, 9, r0, r1, c0, c1, h, w)
    # 2. The decision: colour differences vary less along the edge.
    ia, ib, ja, jb = _span(7, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            d_h[i, j] = abs(c_h[i, j] - c_h[i, j + 2])
            d_v[i, j] = abs(c_v[i, j] - c_v[i + 2, j])
    for x in (d_h, d_v):
        _mirror(x, 7, r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(5, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            # Taps in the reference's order; its weight-3 taps are fused multiply-adds
            # (one rounding), done here in float64, which is exact before the rounding.
            sh = d_h[i - 2, j] + d_h[i - 2, j + 2]
            sh = sh + d_h[i - 1, j + 1]
            sh = np.float32(np.float64(sh) + 3.0 * np.float64(d_h[i, j]))
            sh = np.float32(np.float64(sh) + 3.0 * np.float64(d_h[i, j + 2]))
            sh = sh + d_h[i + 1, j + 1]
            sh = sh + d_h[i + 2, j]
            sh = sh + d_h[i + 2, j + 2]
            sv = np.float32(np.float64(d_v[i, j - 2]) + 3.0 * np.float64(d_v[i, j]))
            sv = sv + d_v[i, j + 2]
            sv = sv + d_v[i + 1, j - 1]
            sv = sv + d_v[i + 1, j + 1]
            sv = sv + d_v[i + 2, j - 2]
            sv = np.float32(np.float64(sv) + 3.0 * np.float64(d_v[i + 2, j]))
            sv = sv + d_v[i + 2, j + 2]
            horizontal = sv >= sh
            hz[i, j] = np.float32(1.0) if horizontal else np.float32(0.0)
            grn[i, j] = g_h[i, j] if horizontal else g_v[i, j]
    for x in (hz, grn):
        _mirror(x, 5, r0, r1, c0, c1, h, w)
    ia, ib, ja, jb = _span(5, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            dif_r[i, j] = m[i, j] if c == 0 else np.float32(0.0)  # red, sparse
            dif_b[i, j] = m[i, j] if c == 2 else np.float32(0.0)  # blue, sparse
            rb[i, j] = grn[i, j] if c == 0 else np.float32(0.0)  # green * r
            red0[i, j] = grn[i, j] if c == 2 else np.float32(0.0)  # green * b (scratch)
    for x in (dif_r, dif_b, rb, red0):
        _mirror(x, 5, r0, r1, c0, c1, h, w)
    # 3. Red and blue at green sites from the colour difference along the row/column.
    ia, ib, ja, jb = _span(4, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            g = grn[i, j]
            if c == 1:
                on_red_row = colors[(i & 1) * 2 + ((j + 1) & 1)] == 0
                red_h = (g + _pair_h(dif_r, i, j)) - _pair_h(rb, i, j)
                red_v = (g + _pair_v(dif_r, i, j)) - _pair_v(rb, i, j)
                blue_h = (g + _pair_h(dif_b, i, j)) - _pair_h(red0, i, j)
                blue_v = (g + _pair_v(dif_b, i, j)) - _pair_v(red0, i, j)
                red1[i, j] = red_h if on_red_row else red_v
                blue1[i, j] = blue_v if on_red_row else blue_h
            else:
                red1[i, j] = m[i, j] if c == 0 else np.float32(0.0)
                blue1[i, j] = m[i, j] if c == 2 else np.float32(0.0)
    for x in (red1, blue1):
        _mirror(x, 4, r0, r1, c0, c1, h, w)
    # 4. Red at blue sites and blue at red sites, along the decided direction.
    ia, ib, ja, jb = _span(3, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            r, bl = red1[i, j], blue1[i, j]
            horizontal = hz[i, j] != 0
            if c == 2:
                if horizontal:
                    r = (bl + _pair_h(red1, i, j)) - _pair_h(blue1, i, j)
                else:
                    r = (bl + _pair_v(red1, i, j)) - _pair_v(blue1, i, j)
            elif c == 0:
                if horizontal:
                    bl = (r + _pair_h(blue1, i, j)) - _pair_h(red1, i, j)
                else:
                    bl = (r + _pair_v(blue1, i, j)) - _pair_v(red1, i, j)
            red0[i, j], blue0[i, j] = r, bl
            dif_r[i, j] = r - grn[i, j]
            dif_b[i, j] = bl - grn[i, j]
    for x in (red0, blue0, dif_r, dif_b):
        _mirror(x, 3, r0, r1, c0, c1, h, w)
    # 5. Refining: green at R/B sites from the smoothed differences (reach 2) ...
    ia, ib, ja, jb = _span(2, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            horizontal = hz[i, j] != 0
            if c == 0:
                grn2[i, j] = red0[i, j] - _mean3(dif_r, i, j, horizontal)
            elif c == 2:
                grn2[i, j] = blue0[i, j] - _mean3(dif_b, i, j, horizontal)
            else:
                grn2[i, j] = grn[i, j]
            g_h[i, j] = red0[i, j] - grn2[i, j]  # red − green (scratch)
            g_v[i, j] = blue0[i, j] - grn2[i, j]  # blue − green (scratch)
    for x in (grn2, g_h, g_v):
        _mirror(x, 2, r0, r1, c0, c1, h, w)
    # ... red and blue at green sites from their neighbours' differences (reach 1) ...
    ia, ib, ja, jb = _span(1, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            g = grn2[i, j]
            r, bl = red0[i, j], blue0[i, j]
            if c == 1:
                on_red_row = colors[(i & 1) * 2 + ((j + 1) & 1)] == 0
                if on_red_row:
                    r = g + _pair_h(g_h, i, j)
                    bl = g + _pair_v(g_v, i, j)
                else:
                    r = g + _pair_v(g_h, i, j)
                    bl = g + _pair_h(g_v, i, j)
            red2[i, j], blue2[i, j] = r, bl
            c_h[i, j] = r - bl  # red − blue (scratch)
    for x in (red2, blue2, c_h):
        _mirror(x, 1, r0, r1, c0, c1, h, w)
    # ... and red at blue sites, blue at red sites from the smoothed R − B difference.
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    for i in range(ia, ib):
        for j in range(ja, jb):
            c = colors[(i & 1) * 2 + (j & 1)]
            red_blue = _mean3(c_h, i, j, hz[i, j] != 0)
            r, bl = red2[i, j], blue2[i, j]
            if c == 2:
                r = bl + red_blue
            elif c == 0:
                bl = r - red_blue
            rgb[0, i, j], rgb[1, i, j], rgb[2, i, j] = r, grn2[i, j], bl


# --------------------------------------------------------------- RGB stages
@njit(cache=True)
def _finish(rgb, ops, opf, out_mode, lut, gamma, scale, orient, out, r0, r1, c0, c1, h, w):
    """RGB stages, tone/transfer and quantisation of the tile, written to ``out``.

    ``out`` is (H', W', 3): uint8/uint16 codes (``scale`` = 2^bits − 1) or float32
    (``out_mode`` OUT_FLOAT), already in display orientation: ``orient`` = (transpose,
    flip rows, flip columns). Returns whether any tone input left [0, 1].
    """
    ia, ib, ja, jb = _span(0, r0, r1, c0, c1, h, w)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    transpose, flip_rows, flip_cols = orient[0], orient[1], orient[2]
    out_h, out_w = out.shape[0], out.shape[1]
    outside = False
    one = np.float32(1.0)
    for i in range(ia, ib):
        y = r0 - HALO + i
        for j in range(ja, jb):
            x = c0 - HALO + j
            r, g, b = rgb[0, i, j], rgb[1, i, j], rgb[2, i, j]
            for k in range(ops.size):
                op, p = ops[k], opf[k]
                if op == OP_WB:
                    r, g, b = r * np.float32(p[0]), g * np.float32(p[1]), b * np.float32(p[2])
                elif op == OP_CLIP:
                    r, g, b = min(r, one), min(g, one), min(b, one)
                elif op == OP_MATRIX:
                    r, g, b = _matrix(p, 0, r, g, b)
                elif op == OP_EXPOSURE:
                    s = np.float32(p[0])
                    r, g, b = r * s, g * s, b * s
                elif op == OP_SHADING:
                    s = _shading_gain(y, x, cy, cx, p)
                    r, g, b = r * s, g * s, b * s
                elif op == OP_BLEND:
                    r, g, b = _blend(p, r, g, b)
            oy, ox = (x, y) if transpose else (y, x)
            if flip_rows:
                oy = out_h - 1 - oy
            if flip_cols:
                ox = out_w - 1 - ox
            if out_mode == OUT_FLOAT:
                out[oy, ox, 0], out[oy, ox, 1], out[oy, ox, 2] = r, g, b
                continue
            for c in range(3):
                v = r if c == 0 else (g if c == 1 else b)
                if v < 0 or v > 1:
                    outside = True
                v = min(max(v, np.float32(0.0)), one)
                t = v * np.float32(LUT_SIZE - 1)
                n = min(int(t), LUT_SIZE - 2)
                v = lut[n] + (t - np.float32(n)) * (lut[n + 1] - lut[n])
                if out_mode == OUT_GAMMA:
                    v = np.float32(max(v, np.float32(1e-12)) ** gamma) if v > 0 else v
                v = min(max(v, np.float32(0.0)), one)
                out[oy, ox, c] = np.rint(v * np.float32(scale))
    return outside


@njit(cache=True, inline="always")
def _matrix(p, at, r, g, b):
    """(r, g, b) → M (r, g, b) with M row-major in p[at : at + 9], float32."""
    return (
        (np.float32(p[at]) * r + np.float32(p[at + 1]) * g) + np.float32(p[at + 2]) * b,
        (np.float32(p[at + 3]) * r + np.float32(p[at + 4]) * g) + np.float32(p[at + 5]) * b,
        (np.float32(p[at + 6]) * r + np.float32(p[at + 7]) * g) + np.float32(p[at + 8]) * b,
    )


@njit(cache=True, inline="always")
def _blend(p, r, g, b):
    """dcraw's highlight blend (:func:`rawsim.isp.highlights.handle_highlights`).

    p[0:9] is the lightness/chroma transform, p[9:18] its inverse.
    """
    one = np.float32(1.0)
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
@njit(parallel=True, cache=True)
def process_kernel(
    raw,
    colors,
    method,
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
    """Render the (H, W) uint16 mosaic ``raw`` into ``out`` (see :func:`_finish`).

    ``colors``: the CFA's colour index at the 4 tile sites (row-major);
    ``method``: a :data:`DEMOSAIC_CODES` value. Returns whether any value reaching
    the tone curve was outside [0, 1]. ``threads``: numba's thread count (each
    thread gets its own tile buffers); tiles are ``tile_rows`` × ``tile_cols``
    (even numbers: tiles keep the CFA phase; default :data:`TILE_ROWS`,
    :data:`TILE_COLS`).
    """
    h, w = raw.shape
    rows, cols = (h + tile_rows - 1) // tile_rows, (w + tile_cols - 1) // tile_cols
    tiles = rows * cols
    threads = max(1, min(tiles, threads))
    flags = np.zeros(threads, dtype=np.bool_)
    shape = (tile_rows + 2 * HALO, tile_cols + 2 * HALO)
    for t in prange(threads):
        m = np.empty(shape, np.float32)
        rgb = np.empty((3,) + shape, np.float32)
        bufs = np.empty((20,) + shape, np.float32)
        for tile in range(t, tiles, threads):
            r0, c0 = (tile // cols) * tile_rows, (tile % cols) * tile_cols
            r1, c1 = min(h, r0 + tile_rows), min(w, c0 + tile_cols)
            _load_mosaic(raw, m, table, colors, pre_ops, pre_f, r0, r1, c0, c1, h, w)
            if method == 0:
                _bilinear(m, rgb, colors, r0, r1, c0, c1, h, w)
            elif method == 1:
                _malvar(m, rgb, colors, r0, r1, c0, c1, h, w)
            elif method == 2:
                _menon(m, bufs, rgb, colors, r0, r1, c0, c1, h, w)
            else:
                _wcd(m, bufs, rgb, colors, r0, r1, c0, c1, h, w)
            outside = _finish(
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
            flags[t] = flags[t] or outside
    return flags.any()
