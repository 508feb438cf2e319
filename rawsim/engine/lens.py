"""Lens correction as a compiled kernel: the twin of :mod:`rawsim.isp.lens`.

:func:`lens_kernel` is the process engine's second pass when the config corrects
the lens: it reads the first pass's linear render (H, W, 3) float32, fills each
tile's RGB buffers with the remapped pixels (per channel: the radial tables of
a :class:`~rawsim.io.lensfun.LensField`, a Lanczos-3 sample (:mod:`rawsim.resample`),
the gain), then runs
the same :func:`rawsim.engine.process._finish` as the other kernels (the RGB
stages after the lens stage, tone/transfer, quantisation, orientation).
:func:`correct_lens` and :func:`add_lens` are the numpy twins of the torch
functions, for pipelines without gradients (unprocess). :func:`correct_mosaic_tca`
is the process engine's pre-pass that takes lateral CA out of a Bayer mosaic
(the twin of :func:`rawsim.isp.lens.correct_mosaic_tca`).

Arithmetic is float32 in the reference's order of operations, so the two agree
to rounding. numba caches this kernel keyed on this file only: after editing
:mod:`rawsim.engine.process` alone, touch this file (see :mod:`rawsim.engine`).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from rawsim.engine import configure
from rawsim.engine.process import (
    HALO,
    OP_LEVELS,
    OP_NUMBERS,
    OP_ROOT,
    OP_SHADING,
    OUT_FLOAT,
    TILE_COLS,
    TILE_ROWS,
    _finish,
    _mosaic_value,
    _rgb_buffers,
    _to_root,
    mosaic_table,
)
from rawsim.engine.tiles import next_tile
from rawsim.errors import ParameterError, check_choice
from rawsim.io.lensfun import LensField, LensParams, lens_field, mosaic_tca_fields
from rawsim.resample import FIRST, PHASES, TAPS, lanczos_table

configure()

_JIT = {"cache": True, "error_model": "numpy"}

#: The resampling weights by phase (a compile-time constant of the kernels).
_WEIGHTS = lanczos_table()
#: ``padding`` codes, in :data:`rawsim.isp.lens.PADDINGS` order.
PADDING_CODES = {"zeros": 0, "border": 1, "reflect": 2}


@njit(inline="always", **_JIT)
def _index(i, n, padding):
    """Index ``i`` of an axis of ``n``, or −1 for zeros outside (see ``padding``)."""
    if 0 <= i < n:
        return i
    if padding == 0:
        return -1
    if padding == 2:
        i = -i if i < 0 else i
        i = 2 * (n - 1) - i if i > n - 1 else i
    return min(max(i, 0), n - 1)


@njit(inline="always", **_JIT)
def _tap(src, y, x, k, h, w, padding):
    yy, xx = _index(y, h, padding), _index(x, w, padding)
    if yy < 0 or xx < 0:
        return np.float32(0.0)
    return src[yy, xx, k]


@njit(inline="always", **_JIT)
def _sample(src, c, table, k, t, f, dx, dy, i, j, padding):
    """Output pixel (i, j) of ``src``'s channel ``c`` through the table's channel ``k``,
    at knot ``t`` + ``f`` of radius, (dx, dy) from the centre: the Lanczos-3 sample,
    kept within the range of the 2 × 2 pixels around it, times the gain."""
    h, w = src.shape[0], src.shape[1]
    weights = _WEIGHTS
    lo_r, hi_r = table[t, k, 0], table[t + 1, k, 0]
    lo_g, hi_g = table[t, k, 1], table[t + 1, k, 1]
    ratio = lo_r + f * (hi_r - lo_r)
    gain = lo_g + f * (hi_g - lo_g)
    m = ratio - np.float32(1.0)
    ox, oy = dx * m, dy * m
    fx, fy = np.floor(ox), np.floor(oy)
    phases, half = np.float32(PHASES), np.float32(0.5)
    px, py = int((ox - fx) * phases + half), int((oy - fy) * phases + half)
    x0, y0 = j + int(fx) + FIRST, i + int(fy) + FIRST
    inside = 0 <= x0 and x0 + TAPS <= w and 0 <= y0 and y0 + TAPS <= h
    acc = np.float32(0.0)
    if inside:  # all taps in the frame: no padding to look up
        for b in range(TAPS):
            row = np.float32(0.0)
            for a in range(TAPS):
                row += weights[px, a] * src[y0 + b, x0 + a, c]
            acc += weights[py, b] * row
    else:
        for b in range(TAPS):
            row = np.float32(0.0)
            for a in range(TAPS):
                row += weights[px, a] * _tap(src, y0 + b, x0 + a, c, h, w, padding)
            acc += weights[py, b] * row
    # no ringing: within the range of the 2 × 2 pixels around the sample
    ya, xa = y0 - FIRST, x0 - FIRST  # the tap at the sample's floor
    if inside:
        a0, a1 = src[ya, xa, c], src[ya, xa + 1, c]
        a2, a3 = src[ya + 1, xa, c], src[ya + 1, xa + 1, c]
    else:
        a0 = _tap(src, ya, xa, c, h, w, padding)
        a1 = _tap(src, ya, xa + 1, c, h, w, padding)
        a2 = _tap(src, ya + 1, xa, c, h, w, padding)
        a3 = _tap(src, ya + 1, xa + 1, c, h, w, padding)
    lo = min(min(a0, a1), min(a2, a3))
    hi = max(max(a0, a1), max(a2, a3))
    return min(max(acc, lo), hi) * gain


@njit(inline="always", **_JIT)
def _knot(table, knots, dx, dy):
    """The knot t and fraction f of the radius of offset (dx, dy) (float32)."""
    r = np.float32(np.sqrt(np.float64(dx * dx + dy * dy)))
    u = r * knots
    t = min(int(u), table.shape[0] - 2)
    return t, u - np.float32(t)


@njit(**_JIT)
def _remap_tile(src, table, knots, cy, cx, padding, rgb, r0, r1, c0, c1):
    """Output pixels [r0, r1) × [c0, c1) into the tile buffers ``rgb`` (offset HALO)."""
    for i in range(r0, r1):
        dy = np.float32(i) - cy
        for j in range(c0, c1):
            dx = np.float32(j) - cx
            t, f = _knot(table, knots, dx, dy)
            for k in range(3):
                v = _sample(src, k, table, k, t, f, dx, dy, i, j, padding)
                rgb[k][HALO + i - r0, HALO + j - c0] = v


@njit(parallel=True, nogil=True, **_JIT)
def _remap_plane(src, table, knots, cy, cx, padding, out):
    """``src`` (H, W, 1) float32 through a field's green channel into ``out`` (H, W)."""
    h, w = src.shape[0], src.shape[1]
    for i in prange(h):
        dy = np.float32(i) - cy
        for j in range(w):
            dx = np.float32(j) - cx
            t, f = _knot(table, knots, dx, dy)
            out[i, j] = _sample(src, 0, table, 1, t, f, dx, dy, i, j, padding)


@njit(parallel=True, nogil=True, **_JIT)
def lens_kernel(
    src,
    table,
    knots,
    cy,
    cx,
    padding,
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
    """Remap ``src`` (H, W, 3) float32 through a field (:func:`field_args`: ``table``
    (n, 3, 2), ``knots`` per pixel of radius, centre ``cy``, ``cx``, all float32;
    ``padding`` a :data:`PADDING_CODES` value), then the RGB stages
    ``post_ops``/``post_f``, tone/transfer and quantisation of
    :func:`rawsim.engine.process._finish` into ``out`` (oriented). Tiles of
    ``tile_rows`` × ``tile_cols``, parallel over ``threads``."""
    h, w = src.shape[0], src.shape[1]
    rows, cols = (h + tile_rows - 1) // tile_rows, (w + tile_cols - 1) // tile_cols
    tiles = rows * cols
    threads = max(1, min(tiles, threads))
    counter = np.zeros(1, np.int64)  # the next tile (see rawsim.engine.tiles)
    for _ in prange(threads):  # each thread: its buffers, then tiles while any are left
        rgb = _rgb_buffers((tile_rows + 2 * HALO, tile_cols + 2 * HALO))
        while True:
            tile = next_tile(counter)
            if tile >= tiles:
                break
            r0, c0 = (tile // cols) * tile_rows, (tile % cols) * tile_cols
            r1, c1 = min(h, r0 + tile_rows), min(w, c0 + tile_cols)
            _remap_tile(src, table, knots, cy, cx, padding, rgb, r0, r1, c0, c1)
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


def field_args(field: LensField) -> tuple:
    """The kernel's (table, knots, cy, cx) for ``field``."""
    cy, cx = field.centre
    knots = np.float32(field.scale)
    return np.ascontiguousarray(field.table), knots, np.float32(cy), np.float32(cx)


def remap_lens(image: np.ndarray, field: LensField, padding: str = "zeros") -> np.ndarray:
    """:func:`rawsim.isp.lens.remap_lens` compiled: ``image`` (H, W, 3) float32, linear
    RGB of the field's size → (H, W, 3) float32."""
    check_choice("padding", padding, PADDING_CODES)
    image = np.ascontiguousarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.float32:
        raise ParameterError(f"image must be (H, W, 3) float32, got {image.shape} {image.dtype}")
    if image.shape[:2] != (field.height, field.width):
        raise ParameterError(
            f"lens field is for {field.height} × {field.width} pixels, "
            f"the image is {image.shape[0]} × {image.shape[1]}"
        )
    if not np.isfinite(image).all():
        raise ParameterError("image contains NaN or infinite values")
    out = np.empty_like(image)
    ops, opf = np.zeros(0, np.int64), np.zeros((1, OP_NUMBERS))
    lut = np.zeros(2, np.float32)
    orient = np.zeros(3, np.bool_)
    lens_kernel(
        image,
        *field_args(field),
        PADDING_CODES[padding],
        ops,
        opf,
        OUT_FLOAT,
        lut,
        1.0,
        1.0,
        orient,
        out,
        numba.get_num_threads(),
        TILE_ROWS,
        TILE_COLS,
    )
    return out


def correct_lens(
    image: np.ndarray, params: LensParams | dict, padding: str = "zeros"
) -> np.ndarray:
    """:func:`rawsim.isp.lens.correct_lens` compiled, on (H, W, 3) float32."""
    return remap_lens(image, lens_field(params, *np.shape(image)[:2]), padding)


def add_lens(image: np.ndarray, params: LensParams | dict, padding: str = "reflect") -> np.ndarray:
    """:func:`rawsim.isp.lens.add_lens` compiled, on (H, W, 3) float32."""
    return remap_lens(image, lens_field(params, *np.shape(image)[:2], reverse=True), padding)


#: Codes a site's values are spread over when :func:`correct_mosaic_tca` re-encodes them.
CODES = 65535 * (1 - 1e-6)


def correct_mosaic_tca(
    data: np.ndarray, colors: tuple[int, ...], ops: np.ndarray, opf: np.ndarray, params
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lateral CA of ``params``'s lens taken out of ``data`` (H, W) uint16, a Bayer
    mosaic (``colors``: its 2 × 2 period's colours) read through the mosaic ops
    ``ops``/``opf`` (:func:`rawsim.engine.process._mosaic_value`); returns (codes, ops,
    numbers) for the demosaic kernels to read instead.

    The ops before the demosaic's square root (:data:`OP_ROOT`, if last) give linear
    values; each red and blue plane is remapped as
    :func:`rawsim.isp.lens.correct_mosaic_tca` does it (the same float32 arithmetic);
    the values, as square roots where the ops took them, are spread per site over
    :data:`CODES` codes (uint16), which one levels op reads back: within half a code
    (a site's range / 131070) of the reference's values.
    """
    h, w = data.shape
    ops = np.asarray(ops, np.int64)
    root = ops.size > 0 and ops[-1] == OP_ROOT
    linear_ops = ops[:-1] if root else ops
    colours = np.asarray(colors, np.int64)
    if (linear_ops == OP_SHADING).any():  # a gain that depends on position: site by site
        table = np.empty((0, 0), np.float32)
    else:
        table = mosaic_table(colours, linear_ops, opf)
    values = np.empty((h, w), np.float32)
    _linear_mosaic(np.ascontiguousarray(data), colours, table, linear_ops, opf, values)
    for oy, ox, field in mosaic_tca_fields(params, colors, h, w):
        plane = np.ascontiguousarray(values[oy::2, ox::2])
        out = np.empty(plane.shape, np.float32)
        _remap_plane(plane[:, :, None], *field_args(field), PADDING_CODES["reflect"], out)
        values[oy::2, ox::2] = out
    ranges = np.empty((h, 2, 4), np.float32)
    _roots_and_ranges(values, root, ranges)
    black, span = np.zeros(4), np.ones(4)
    for site in range(4):
        lo = float(ranges[site // 2 :: 2, 0, site].min(initial=np.inf))
        hi = float(ranges[site // 2 :: 2, 1, site].max(initial=-np.inf))
        if hi > lo:
            span[site] = np.float32(CODES / (hi - lo))
        if np.isfinite(lo):
            black[site] = np.float32(-lo * span[site])
    codes = np.empty((h, w), np.uint16)
    _encode(values, black, span, codes)
    numbers = np.zeros((1, opf.shape[1]))
    numbers[0, :4], numbers[0, 4:8] = black, span
    return codes, np.array([OP_LEVELS], np.int64), numbers


@njit(parallel=True, nogil=True, **_JIT)
def _linear_mosaic(raw, colors, table, ops, opf, out):
    """The mosaic ops at every site of ``raw`` (H, W) into ``out`` (float32), as the
    process kernels evaluate them: through ``table``
    (:func:`rawsim.engine.process.mosaic_table`) where it has rows, else site by site."""
    h, w = raw.shape
    cy, cx = (h - 1) / 2, (w - 1) / 2
    for y in prange(h):
        if table.shape[0]:
            even, odd = table[(y & 1) * 2], table[(y & 1) * 2 + 1]
            for x in range(w):
                out[y, x] = even[raw[y, x]] if x & 1 == 0 else odd[raw[y, x]]
            continue
        for x in range(w):
            site = (y & 1) * 2 + (x & 1)
            v = np.float32(raw[y, x])
            out[y, x] = _mosaic_value(v, site, colors[site], y, x, cy, cx, ops, opf)


@njit(parallel=True, nogil=True, **_JIT)
def _roots_and_ranges(values, root, ranges):
    """``values`` (H, W) as square roots in place where ``root``; each row's smallest
    and largest value per site into ``ranges`` (H, 2, 4) (±inf where a row has none)."""
    h, w = values.shape
    for y in prange(h):
        for site in range(4):
            ranges[y, 0, site], ranges[y, 1, site] = np.inf, -np.inf
        for x in range(w):
            v = _to_root(values[y, x]) if root else values[y, x]
            values[y, x] = v
            site = (y & 1) * 2 + (x & 1)
            ranges[y, 0, site] = min(ranges[y, 0, site], v)
            ranges[y, 1, site] = max(ranges[y, 1, site], v)


@njit(parallel=True, nogil=True, **_JIT)
def _encode(values, black, span, codes):
    """``values`` (H, W) float32 as codes ``values · span + black`` (per site, float64),
    rounded and held in [0, 65535]."""
    for y in prange(values.shape[0]):
        for x in range(values.shape[1]):
            site = (y & 1) * 2 + (x & 1)
            c = np.rint(np.float64(values[y, x]) * span[site] + black[site])
            codes[y, x] = np.uint16(min(max(c, 0.0), 65535.0))
