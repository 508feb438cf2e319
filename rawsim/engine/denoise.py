"""Profiled denoising of a raw mosaic, compiled: the engine's form of
:mod:`rawsim.denoise.profiled` (the torch reference, which defines the method).

:func:`denoise_mosaic` turns a uint16 mosaic (DN) into a denoised uint16 mosaic
(DN, rounded) that the render kernels of :mod:`rawsim.engine.process` then take
as they take any raw. Work is split in chunks of ``CHUNK`` plane rows, handed
to the threads on demand (:func:`rawsim.engine.tiles.next_tile`; the threads
are Python's, running :func:`denoise_worker`, which releases the GIL: a
``parallel=True`` kernel took twice as long to compile); a chunk reads
the rows it needs around it (``REACH`` plane rows each side for each of the
two passes) and writes only its own, so chunks and threads never change a value
and memory stays a few megabytes per thread at any image size.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rawsim.cfa import CFA
from rawsim.denoise.layout import (
    CHUNK,
    PATCH,
    REACH,
    STEP,
    THRESHOLD,
    large_enough,
    modulation_pads,
    plane_layout,
    plane_shape,
)
from rawsim.denoise.vst import tables
from rawsim.engine import configure
from rawsim.engine.tiles import next_tile

configure()

_JIT = {"cache": True, "error_model": "numpy"}

#: Patches transformed at once (a row's patches, in blocks that stay in the L1/L2 cache).
BLOCK = 64


@njit(inline="always", **_JIT)
def _reflect(i, n):
    """Index ``i`` mirrored into [0, n) without repeating the edge (n ≥ ``PATCH``)."""
    if i < 0:
        return -i
    if i >= n:
        return 2 * (n - 1) - i
    return i


@njit(inline="always", **_JIT)
def _forward_vst(x, gain, offset):
    """Generalised Anscombe transform of ``x`` (white = 1) with variance gain·x + offset."""
    z = x / gain + np.float32(0.375) + offset / (gain * gain)
    return np.float32(2.0) * math.sqrt(max(z, np.float32(0.0)))


@njit(inline="always", **_JIT)
def _inverse_vst(d, gain, offset, td, tx):
    """The exact unbiased inverse of :func:`_forward_vst` (:mod:`rawsim.denoise.vst`):
    the table (``td`` → ``tx``, linear between points) up to its last point, the
    closed form of Mäkitalo & Foi (2013) above."""
    n = td.size
    if d > td[n - 1]:
        c = max(d, np.float32(1.0))
        r = np.float32(math.sqrt(1.5))
        i = (
            np.float32(0.25) * c * c
            + np.float32(0.25) * r / c
            - np.float32(1.375) / (c * c)
            + np.float32(0.625) * r / (c * c * c)
            - np.float32(0.125)
            - offset / (gain * gain)
        )
        return max(i, np.float32(0.0)) * gain
    lo, hi = 1, n - 1
    while lo < hi:  # the first point ≥ d, at least the second
        mid = (lo + hi) // 2
        if td[mid] < d:
            lo = mid + 1
        else:
            hi = mid
    w = min(max((d - td[lo - 1]) / (td[lo] - td[lo - 1]), np.float32(0.0)), np.float32(1.0))
    return tx[lo - 1] + w * (tx[lo] - tx[lo - 1])


@njit(**_JIT)
def _dct8(src, dst, e, o, count, rows, inverse):
    """8-point DCTs (or inverses) of ``count`` patches at once, along each patch's rows
    (``rows``: src[i, :, n] → dst[i, :, n]) or columns (src[:, m, n] → dst[:, m, n]).

    Even/odd split: with a_j = x_j + x_{7−j} and b_j = x_j − x_{7−j}, y_{2m} = Σ e[m, j] a_j
    and y_{2m+1} = Σ o[m, j] b_j (``e``, ``o``: the DCT's even and odd rows, first
    four columns); the inverse runs it backwards. Patches are the innermost index,
    so each statement works on a vector of patches.
    """
    for line in range(PATCH):
        for n in range(count):
            if rows:
                x0, x1, x2, x3 = src[line, 0, n], src[line, 1, n], src[line, 2, n], src[line, 3, n]
                x4, x5, x6, x7 = src[line, 4, n], src[line, 5, n], src[line, 6, n], src[line, 7, n]
            else:
                x0, x1, x2, x3 = src[0, line, n], src[1, line, n], src[2, line, n], src[3, line, n]
                x4, x5, x6, x7 = src[4, line, n], src[5, line, n], src[6, line, n], src[7, line, n]
            if inverse:  # x0..x7 hold y0..y7
                a0 = e[0, 0] * x0 + e[1, 0] * x2 + e[2, 0] * x4 + e[3, 0] * x6
                a1 = e[0, 1] * x0 + e[1, 1] * x2 + e[2, 1] * x4 + e[3, 1] * x6
                a2 = e[0, 2] * x0 + e[1, 2] * x2 + e[2, 2] * x4 + e[3, 2] * x6
                a3 = e[0, 3] * x0 + e[1, 3] * x2 + e[2, 3] * x4 + e[3, 3] * x6
                b0 = o[0, 0] * x1 + o[1, 0] * x3 + o[2, 0] * x5 + o[3, 0] * x7
                b1 = o[0, 1] * x1 + o[1, 1] * x3 + o[2, 1] * x5 + o[3, 1] * x7
                b2 = o[0, 2] * x1 + o[1, 2] * x3 + o[2, 2] * x5 + o[3, 2] * x7
                b3 = o[0, 3] * x1 + o[1, 3] * x3 + o[2, 3] * x5 + o[3, 3] * x7
                y0, y1, y2, y3 = a0 + b0, a1 + b1, a2 + b2, a3 + b3
                y4, y5, y6, y7 = a3 - b3, a2 - b2, a1 - b1, a0 - b0
            else:
                a0, a1, a2, a3 = x0 + x7, x1 + x6, x2 + x5, x3 + x4
                b0, b1, b2, b3 = x0 - x7, x1 - x6, x2 - x5, x3 - x4
                y0 = e[0, 0] * a0 + e[0, 1] * a1 + e[0, 2] * a2 + e[0, 3] * a3
                y2 = e[1, 0] * a0 + e[1, 1] * a1 + e[1, 2] * a2 + e[1, 3] * a3
                y4 = e[2, 0] * a0 + e[2, 1] * a1 + e[2, 2] * a2 + e[2, 3] * a3
                y6 = e[3, 0] * a0 + e[3, 1] * a1 + e[3, 2] * a2 + e[3, 3] * a3
                y1 = o[0, 0] * b0 + o[0, 1] * b1 + o[0, 2] * b2 + o[0, 3] * b3
                y3 = o[1, 0] * b0 + o[1, 1] * b1 + o[1, 2] * b2 + o[1, 3] * b3
                y5 = o[2, 0] * b0 + o[2, 1] * b1 + o[2, 2] * b2 + o[2, 3] * b3
                y7 = o[3, 0] * b0 + o[3, 1] * b1 + o[3, 2] * b2 + o[3, 3] * b3
            if rows:
                dst[line, 0, n], dst[line, 1, n], dst[line, 2, n], dst[line, 3, n] = y0, y1, y2, y3
                dst[line, 4, n], dst[line, 5, n], dst[line, 6, n], dst[line, 7, n] = y4, y5, y6, y7
            else:
                dst[0, line, n], dst[1, line, n], dst[2, line, n], dst[3, line, n] = y0, y1, y2, y3
                dst[4, line, n], dst[5, line, n], dst[6, line, n], dst[7, line, n] = y4, y5, y6, y7


@njit(**_JIT)
def _transform(src, even, odd, tmp, dst, count, inverse):
    """2-D DCT (or its inverse) of ``count`` 8×8 patches at once: ``src``/``dst``
    (8, 8, n), patch index last (:func:`_dct8` along rows, then columns)."""
    _dct8(src, tmp, even, odd, count, True, inverse)
    _dct8(tmp, dst, even, odd, count, False, inverse)


@njit(**_JIT)
def _pass(noisy, n0, pilot, a, wiener, lo, hi, hp, sigma, threshold, even, odd, num, den, s):
    """One pass over the patches that touch plane rows [lo, hi), summed into ``num`` and
    ``den`` (C, hi − lo, wp): hard thresholding at ``threshold``·``sigma``, each patch
    weighted by 1 / its kept coefficients; or, when ``wiener``, Wiener shrinkage by
    the ``pilot`` patch's coefficients, weighted by 1 / Σ shrink². The DC coefficient
    is kept whole by both (shrinking it would pull a weak colour towards grey).

    ``noisy``: (C, rows, wp + 2·REACH), row 0 plane row ``n0``, column 0 plane column
    −REACH (mirrored values past the edges). ``pilot``: the same columns, row 0 plane
    row ``a``, its rows read mirrored about the plane's edges (``hp`` rows). Patches
    start on the plane rows and columns −REACH + STEP·k. ``s``: scratch (4, 8, 8, BLOCK),
    a row of up to BLOCK patches at a time.
    """
    channels, wp = num.shape[0], num.shape[2]
    num[:] = 0
    den[:] = 0
    start = lo - REACH + lo % STEP  # the first row on the grid −REACH + STEP·k
    p, t, tmp, q = s[0], s[1], s[2], s[3]
    s2 = sigma * sigma
    limit = threshold * sigma
    per_row = (wp + REACH + STEP - 1) // STEP  # patch columns: −REACH … wp − 1
    weight = np.empty(BLOCK, np.float32)
    for c in range(channels):
        for r in range(start, hi, STEP):
            for n0c in range(0, per_row, BLOCK):
                count = min(BLOCK, per_row - n0c)
                for i in range(PATCH):
                    row = noisy[c, r + i - n0]
                    for j in range(PATCH):
                        for n in range(count):
                            p[i, j, n] = row[STEP * (n0c + n) + j]
                _transform(p, even, odd, tmp, t, count, False)
                if wiener:
                    for i in range(PATCH):
                        row = pilot[c, _reflect(r + i, hp) - a]
                        for j in range(PATCH):
                            for n in range(count):
                                p[i, j, n] = row[STEP * (n0c + n) + j]
                    _transform(p, even, odd, tmp, q, count, False)
                    for n in range(count):
                        weight[n] = 1  # the DC, kept whole
                    for i in range(PATCH):
                        for j in range(PATCH):
                            if i == 0 and j == 0:
                                continue
                            for n in range(count):
                                g = q[i, j, n] * q[i, j, n]
                                shrink = g / (g + s2)
                                t[i, j, n] *= shrink
                                weight[n] += shrink * shrink
                    for n in range(count):
                        weight[n] = np.float32(1.0) / weight[n]
                else:
                    for n in range(count):
                        weight[n] = 1  # the DC, always kept
                    for i in range(PATCH):
                        for j in range(PATCH):
                            if i == 0 and j == 0:
                                continue
                            for n in range(count):
                                keep = abs(t[i, j, n]) > limit
                                t[i, j, n] = t[i, j, n] if keep else np.float32(0.0)
                                weight[n] += np.float32(1.0) if keep else np.float32(0.0)
                    for n in range(count):
                        weight[n] = np.float32(1.0) / weight[n]
                _transform(t, even, odd, tmp, q, count, True)
                for i in range(PATCH):
                    y = r + i - lo
                    if 0 <= y < hi - lo:
                        for n in range(count):
                            x0 = STEP * (n0c + n) - REACH
                            for j in range(PATCH):
                                x = x0 + j
                                if 0 <= x < wp:
                                    num[c, y, x] += weight[n] * q[i, j, n]
                                    den[c, y, x] += weight[n]


@njit(**_JIT)
def _chunk(
    raw,
    out,
    k,
    hp,
    offsets,
    step,
    colors,
    matrix,
    black,
    span,
    gain,
    offset,
    td,
    tx,
    sigma,
    threshold,
    even,
    odd,
    noisy,
    pilot,
    num,
    den,
    scratch,
    values,
    pattern,
):
    """Chunk ``k`` of :func:`denoise_worker`: its plane rows of ``out``, with the thread's
    buffers."""
    patterned = pattern.shape[0] > 0
    channels, wp = offsets.shape[0], num.shape[2]
    ph, pw = colors.shape
    r0, r1 = k * CHUNK, min(hp, (k + 1) * CHUNK)
    a, b = max(0, r0 - REACH), min(hp, r1 + REACH)
    n0 = a - REACH
    for rr in range(b + REACH - n0):
        y = _reflect(n0 + rr, hp)
        for cc in range(wp + 2 * REACH):
            x = _reflect(cc - REACH, wp)
            for c in range(channels):
                my, mx = offsets[c, 0] + step * y, offsets[c, 1] + step * x
                sy, sx = my % ph, mx % pw
                col = colors[sy, sx]
                v = (np.float32(raw[my, mx]) - black[sy, sx]) / span[sy, sx]
                values[c] = _forward_vst(v, gain[col], offset[col])
                if patterned:
                    values[c] -= pattern[my, mx]
            for c in range(channels):
                acc = np.float32(0.0)
                for d in range(channels):
                    acc += matrix[c, d] * values[d]
                noisy[c, rr, cc] = acc
    e1 = pilot[:, : b - a]
    n1, d1 = num[:, : b - a], den[:, : b - a]
    _pass(noisy, n0, e1, a, False, a, b, hp, sigma, threshold, even, odd, n1, d1, scratch)
    for c in range(channels):
        for y in range(b - a):
            for x in range(-REACH, wp + REACH):
                xs = _reflect(x, wp)
                e1[c, y, x + REACH] = n1[c, y, xs] / d1[c, y, xs]
    n2, d2 = num[:, : r1 - r0], den[:, : r1 - r0]
    _pass(noisy, n0, e1, a, True, r0, r1, hp, sigma, threshold, even, odd, n2, d2, scratch)
    for y in range(r0, r1):
        for x in range(wp):
            for c in range(channels):
                values[c] = n2[c, y - r0, x] / d2[c, y - r0, x]
            for c in range(channels):
                acc = np.float32(0.0)
                for d in range(channels):
                    acc += matrix[d, c] * values[d]
                my, mx = offsets[c, 0] + step * y, offsets[c, 1] + step * x
                sy, sx = my % ph, mx % pw
                dn = raw[my, mx]
                if np.float32(dn) - black[sy, sx] >= span[sy, sx]:
                    continue  # clipped: kept as it is
                col = colors[sy, sx]
                if patterned:
                    acc += pattern[my, mx]
                v = _inverse_vst(acc, gain[col], offset[col], td[col], tx[col])
                dnv = black[sy, sx] + v * span[sy, sx]
                out[my, mx] = min(max(round(dnv), 0), 65535)


@njit(nogil=True, **_JIT)
def denoise_worker(
    raw,
    out,
    counter,
    hp,
    wp,
    offsets,
    step,
    colors,
    matrix,
    black,
    span,
    gain,
    offset,
    td,
    tx,
    sigma,
    threshold,
    pattern,
):
    """One thread's share of denoising the (H, W) uint16 mosaic ``raw`` into ``out``
    (DN, rounded, in [0, 65535]; ``out`` starts as a copy of ``raw``): chunks of
    ``CHUNK`` plane rows taken from ``counter`` (int64 (1,), from 0) until none is left.
    Threads running it on the same arguments share the work.

    The mosaic is read as C planes: plane c holds the sites (offsets[c] + step·(i, j)),
    (``hp``, ``wp``) the smallest plane's size (:func:`~rawsim.denoise.layout.
    plane_shape`); sites outside the planes and sites at or
    above white (``raw`` ≥ black + span) keep their value. ``colors``: (ph, pw) CFA
    colour index per site of a period; ``black``, ``span`` (ph, pw) DN per site;
    ``gain``, ``offset`` (3,) the noise model per colour (variance gain·x + offset,
    x = (DN − black) / span); ``td``, ``tx`` (3, N) its unbiased inverse's table
    (:func:`rawsim.denoise.vst.tables`); ``matrix`` (C, C) orthonormal, mixing the planes'
    transformed values. ``sigma``: the noise σ the passes assume after the transform
    (1 × strength); ``threshold``: the first pass's hard threshold in σ.
    ``pattern``: (H, W) float32, the colour pattern taken out of a one-plane mosaic's
    transformed values and put back after
    (:func:`colour_pattern`), or (0, 0): none (Bayer).
    """
    channels = offsets.shape[0]
    even, odd = _basis()
    chunks = (hp + CHUNK - 1) // CHUNK
    noisy = np.empty((channels, CHUNK + 4 * REACH, wp + 2 * REACH), np.float32)
    pilot = np.empty((channels, CHUNK + 2 * REACH, wp + 2 * REACH), np.float32)
    num = np.empty((channels, CHUNK + 2 * REACH, wp), np.float32)
    den = np.empty((channels, CHUNK + 2 * REACH, wp), np.float32)
    scratch = np.empty((4, PATCH, PATCH, BLOCK), np.float32)
    values = np.empty(channels, np.float32)
    while True:
        k = next_tile(counter)
        if k >= chunks:
            return
        _chunk(
            raw,
            out,
            k,
            hp,
            offsets,
            step,
            colors,
            matrix,
            black,
            span,
            gain,
            offset,
            td,
            tx,
            sigma,
            threshold,
            even,
            odd,
            noisy,
            pilot,
            num,
            den,
            scratch,
            values,
            pattern,
        )


@njit(**_JIT)
def _basis():
    """The orthonormal 8-point DCT-II's even and odd rows, first four columns (the rest
    follow by symmetry): two (4, 4) float32."""
    even = np.empty((PATCH // 2, PATCH // 2), np.float32)
    odd = np.empty((PATCH // 2, PATCH // 2), np.float32)
    for k in range(PATCH):
        scale = math.sqrt((1.0 if k == 0 else 2.0) / PATCH)
        for j in range(PATCH // 2):
            value = scale * math.cos(math.pi * (2 * j + 1) * k / (2 * PATCH))
            if k % 2:
                odd[k // 2, j] = value
            else:
                even[k // 2, j] = value
    return even, odd


@njit(parallel=True, nogil=True, **_JIT)
def colour_pattern(raw, colors, black, span, gain, offset, top, left, out, threads):
    """The colour pattern of the transformed one-plane mosaic (the torch reference's
    :func:`rawsim.denoise.profiled.colour_modulation`) into ``out`` (H, W) float32:
    at each site of the (H, W) uint16 ``raw``, the mean of the transformed values
    (:func:`_forward_vst` of (DN − black) / span, as :func:`_chunk` forms them) of its
    colour over the (ph, pw) box from ``top`` rows above and ``left`` columns left
    of it, less the mean of all sites there, the mosaic mirrored at its edges
    (:func:`_reflect`). Bands of rows go to the threads as they finish one: each
    forms its rows' sums along rows (float64, each colour's masked values added in
    column order), then adds ``ph`` of them. The per-site lookups of a row phase,
    and how many sites of each colour a row's ``pw`` columns hold (the mirror at the
    edges breaks the period), are tables made once, so the loops run without
    branches or divisions of indices."""
    h, w = raw.shape
    ph, pw = colors.shape
    band = 32
    n = w + pw - 1
    xs = np.empty(n, np.int64)  # the mirrored column of each padded column
    for xx in range(n):
        xs[xx] = _reflect(xx - left, w)
    # per row phase and padded column: colour, black, span, gain and offset
    kind = np.empty((ph, n), np.int64)
    lows = np.empty((ph, n), np.float32)
    spans = np.empty((ph, n), np.float32)
    gains = np.empty((ph, n), np.float32)
    offsets = np.empty((ph, n), np.float32)
    for sy in range(ph):
        for xx in range(n):
            sx = xs[xx] % pw
            col = colors[sy, sx]
            kind[sy, xx] = col
            lows[sy, xx], spans[sy, xx] = black[sy, sx], span[sy, sx]
            gains[sy, xx], offsets[sy, xx] = gain[col], offset[col]
    counts = np.zeros((ph, 3, w), np.float64)  # each colour's sites in a row's pw columns
    for sy in range(ph):
        for x in range(w):
            for d in range(pw):
                counts[sy, kind[sy, x + d], x] += 1.0
    full = np.zeros((3, w), np.float64)  # those of a box of ph unmirrored rows
    for sy in range(ph):
        for c in range(3):
            for x in range(w):
                full[c, x] += counts[sy, c, x]
    own_row = np.empty((ph, w), np.int64)  # the colour of each output site
    for sy in range(ph):
        for x in range(w):
            own_row[sy, x] = colors[sy, x % pw]
    whole = np.float64(ph * pw)
    counter = np.zeros(1, np.int64)  # the next band (rawsim.engine.tiles)
    for _ in prange(threads):
        rows = band + ph - 1
        sums = np.empty((rows, 4, w), np.float64)  # R, G, B, all: sums along a row
        line = np.empty(n, np.float32)
        masked = np.empty((4, n), np.float64)  # a row's values, each colour's alone
        totals = np.empty((4, w), np.float64)
        phases = np.empty(rows, np.int64)  # the row phase of each of a band's rows
        edge = np.empty((3, w), np.float64)
        while True:
            k = next_tile(counter)
            y0 = k * band
            if y0 >= h:
                break
            y1 = min(h, y0 + band)
            for rr in range(y1 - y0 + ph - 1):
                src = _reflect(y0 - top + rr, h)
                sy = src % ph
                phases[rr] = sy
                for xx in range(n):  # the gather apart, so the transform vectorises
                    line[xx] = np.float32(raw[src, xs[xx]])
                for xx in range(n):
                    v = (line[xx] - lows[sy, xx]) / spans[sy, xx]
                    value = np.float64(_forward_vst(v, gains[sy, xx], offsets[sy, xx]))
                    col = kind[sy, xx]
                    masked[0, xx] = value if col == 0 else 0.0
                    masked[1, xx] = value if col == 1 else 0.0
                    masked[2, xx] = value if col == 2 else 0.0
                    masked[3, xx] = value
                for c in range(4):
                    for x in range(w):
                        sums[rr, c, x] = 0.0
                    for d in range(pw):
                        for x in range(w):
                            sums[rr, c, x] += masked[c, x + d]
            for y in range(y0, y1):
                for c in range(4):
                    for x in range(w):
                        totals[c, x] = 0.0
                    for d in range(ph):
                        for x in range(w):
                            totals[c, x] += sums[y - y0 + d, c, x]
                box = full  # each colour's sites in the box: ph unmirrored rows' ...
                if not top <= y < h - (ph - 1 - top):  # ... else the mirrored rows'
                    box = edge
                    for c in range(3):
                        for x in range(w):
                            edge[c, x] = 0.0
                        for d in range(ph):
                            for x in range(w):
                                edge[c, x] += counts[phases[y - y0 + d], c, x]
                sy = y % ph
                for x in range(w):
                    col = own_row[sy, x]
                    out[y, x] = np.float32(totals[col, x] / box[col, x] - totals[3, x] / whole)


def _pattern(raw, cfa: CFA, black, span, gain, offset) -> np.ndarray:
    """:func:`colour_pattern` of ``raw`` for a one-plane layout; (0, 0) for Bayer."""
    if cfa.is_bayer:
        return np.zeros((0, 0), np.float32)
    import numba

    top, _, left, _ = modulation_pads(cfa)
    colors = np.array(cfa.colors, np.int64).reshape(cfa.period)
    out = np.empty(raw.shape, np.float32)
    threads = numba.get_num_threads()
    colour_pattern(raw, colors, black, span, gain, offset, top, left, out, threads)
    return out


def denoise_mosaic(
    data: np.ndarray,
    cfa: CFA,
    black: np.ndarray,
    white: float,
    gain,
    offset,
    strength: float = 1.0,
    threshold: float = THRESHOLD,
) -> np.ndarray:
    """The (H, W) uint16 mosaic ``data`` of ``cfa`` denoised: a new uint16 mosaic (DN).

    ``black``: the black level per site of a period (ph, pw) or one number (DN);
    ``white``: the white level (DN); ``gain``, ``offset``: the noise model per colour
    (R, G, B) for values normalised to white = 1, as :func:`rawsim.denoise.profiled.
    profiled_denoise` takes them; ``strength`` scales the σ removed; ``threshold``:
    the first pass's, in σ. A mosaic whose planes are under ``PATCH`` a side comes
    back as it is.
    """
    from concurrent.futures import ThreadPoolExecutor

    import numba

    offsets, step, mix = plane_layout(cfa)
    ph, pw = cfa.period
    colors = np.array(cfa.colors, np.int64).reshape(ph, pw)
    black = np.broadcast_to(np.asarray(black, np.float32), (ph, pw)).copy()
    span = (np.float32(white) - black).astype(np.float32)
    raw = np.ascontiguousarray(data)
    out = raw.copy()
    if not large_enough(raw.shape, cfa):
        return out  # as the torch reference: too small for a patch
    model = np.asarray(gain, np.float32), np.asarray(offset, np.float32)
    hp, wp = plane_shape(raw.shape, cfa)
    args = (raw, out, np.zeros(1, np.int64), hp, wp, offsets, step, colors, mix, black, span)
    args += model
    args += tables(*model)
    args += (np.float32(strength), np.float32(threshold), _pattern(raw, cfa, black, span, *model))
    threads = max(1, min(numba.get_num_threads(), -(-hp // CHUNK)))
    if threads == 1:
        denoise_worker(*args)
    else:  # the worker releases the GIL: threads of this process share the chunks
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda _: denoise_worker(*args), range(threads)))
    return out
