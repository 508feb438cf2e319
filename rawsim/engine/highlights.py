"""Highlight reconstruction of a raw mosaic, compiled: the engine's form of
:func:`rawsim.isp.highlights.reconstruct_highlights` (the torch reference, which
defines the method).

:func:`reconstruct_mosaic` is a pre-pass, as raw denoising is: it turns the uint16
mosaic (DN) into one whose clipped sites hold their rebuilt values (DN, rounded),
which the render kernels of :mod:`rawsim.engine.process` then take as any raw,
with no highlight op of their own. The mosaic stages before the highlight stage
(levels, white balance: the kernels' own arithmetic, tabulated once for every code at
each levels slot by :func:`~rawsim.engine.process.mosaic_table`) give the linear
values the method reads; rebuilt values go back through their inverse.
Values above the white level fit the uint16 codes above it; where they would not
(a white level near 65535) the whole mosaic is scaled down, and the levels' span
with it, so the kernels read the same linear values to rounding.

Work: one pass over the mosaic for each block's colour means and clip flags
(parallel over block rows); nothing else when nothing clipped. Otherwise the hue
fields live on the band of block rows that holds clipped blocks (plus the border),
as summed-area tables in float64, read only at clipped blocks; each clipped block
keeps its hue and least level, and its clipped sites are rebuilt from their 3 × 3
neighbourhoods as they are written (again, scaled, in the rare case where rebuilt
values need codes above 65535).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from rawsim.cfa import CFA
from rawsim.engine import configure
from rawsim.engine.process import OP_LEVELS, OP_WB, mosaic_table
from rawsim.isp.config import (
    HIGHLIGHT_BORDER,
    HIGHLIGHT_BORDER_POWER,
    HIGHLIGHT_CLIPPED,
    HIGHLIGHT_HEADROOM,
    HIGHLIGHT_HUE_SIGMA,
    HIGHLIGHT_NEUTRAL,
    HIGHLIGHT_RATIO_FLOOR,
    HIGHLIGHT_SCALE_WEIGHT,
    HIGHLIGHT_SCALES,
    HIGHLIGHT_WHITE_MARGIN,
    highlight_block,
)

configure()

_JIT = {"cache": True, "error_model": "numpy"}


@njit(parallel=True, **_JIT)
def _blocks(raw, cmap, slots, table, level, b, means, flags):
    """Each whole b × b block's colour means (3, Hb, Wb) and clip flags (bit c: colour c
    has a site ≥ ``level[c]``), the sites' values read from ``table``
    (:func:`~rawsim.engine.process.mosaic_table`, a row per levels slot); whether any
    block clipped."""
    hb, wb = flags.shape
    ph, pw = cmap.shape
    count = np.zeros(hb, np.int64)
    for i in prange(hb):
        sums = np.zeros((3, wb), np.float32)
        n = np.zeros((3, wb), np.float32)
        f = np.zeros(wb, np.uint8)
        for y in range(i * b, i * b + b):  # a row at a time, each block's sites in order
            p = y % ph
            q, j, bq = 0, 0, 0  # x % pw, the block column, x % b
            for x in range(wb * b):
                c = cmap[p, q]
                v = table[slots[p, q], raw[y, x]]
                sums[c, j] += v
                n[c, j] += 1
                if v >= level[c]:
                    f[j] |= 1 << c
                q = q + 1 if q + 1 < pw else 0
                bq += 1
                if bq == b:
                    bq, j = 0, j + 1
        for j in range(wb):
            for c in range(3):
                means[c, i, j] = sums[c, j] / n[c, j]
            flags[i, j] = f[j]
            if f[j]:
                count[i] += 1
    return count.sum() > 0


@njit(parallel=True, **_JIT)
def _sat(fields, near, r0, r1, hb, wb, border):
    """Summed-area tables over block rows [r0, r1): the hue fields (weight × share of
    R, G, B; weight) of the border blocks, and the count of blocks next to a clip
    (one table per thread at a time)."""
    n = r1 - r0
    sat = np.zeros((5, n + 1, wb + 1), np.float64)
    for k in prange(5):
        for i in range(n):
            for j in range(wb):
                v = np.float64(fields[k, i, j]) if k < 4 else np.float64(near[i, j])
                sat[k, i + 1, j + 1] = v + sat[k, i, j + 1] + sat[k, i + 1, j] - sat[k, i, j]
    return sat


@njit(inline="always", **_JIT)
def _box(sat, k, i0, i1, j0, j1):
    """Sum of field ``k`` over band rows [i0, i1) and columns [j0, j1)."""
    return sat[k, i1, j1] - sat[k, i0, j1] - sat[k, i1, j0] + sat[k, i0, j0]


@njit(parallel=True, **_JIT)
def _fields(means, flags, gains, r0, r1, border, power):
    """The border blocks' hue fields (4, band, Wb), read over each block's 3 × 3 blocks
    and weighted by their brightness to ``power`` (float32 products, as the reference
    forms them; summed in float64 by :func:`_sat`), and which blocks lie next to a
    clipped one (band, Wb)."""
    hb, wb = flags.shape
    n = r1 - r0
    clip = np.zeros((n + 1, wb + 1), np.int32)  # summed-area table of clipped blocks
    for i in range(n):
        for j in range(wb):
            hit = 1 if flags[r0 + i, j] else 0
            clip[i + 1, j + 1] = hit + clip[i, j + 1] + clip[i + 1, j] - clip[i, j]
    fields = np.zeros((4, n, wb), np.float32)
    near = np.zeros((n, wb), np.uint8)
    for i in prange(n):
        y = r0 + i
        around = np.empty(3, np.float32)  # the block's 3 × 3 blocks' colour means
        for j in range(wb):
            i0, i1 = max(i - 1, 0), min(i + 2, n)
            j0, j1 = max(j - 1, 0), min(j + 2, wb)
            close = clip[i1, j1] - clip[i0, j1] - clip[i1, j0] + clip[i0, j0] > 0
            i0, i1 = max(i - border, 0), min(i + border + 1, n)
            j0, j1 = max(j - border, 0), min(j + border + 1, wb)
            inside = clip[i1, j1] - clip[i0, j1] - clip[i1, j0] + clip[i0, j0] > 0
            near[i, j] = close
            if close or not inside:
                continue
            # the block's 3 × 3 blocks (in the image), summed as avg_pool2d sums them
            ya, yb, ja, jb = max(y - 1, 0), min(y + 2, hb), max(j - 1, 0), min(j + 2, wb)
            count = np.float32((yb - ya) * (jb - ja))
            for c in range(3):
                acc = np.float32(0.0)
                for yy in range(ya, yb):
                    for jj in range(ja, jb):
                        acc += means[c, yy, jj]
                around[c] = acc / count
            total = around[0] + around[1] + around[2]
            if not total > 0:
                continue
            bright = max(around[0] / gains[0], around[1] / gains[1], around[2] / gains[2])
            bright = np.float32(min(max(bright, np.float32(0.0)), np.float32(1.0)) ** power)
            for c in range(3):
                fields[c, i, j] = bright * (around[c] / total)
            fields[3, i, j] = bright
    return fields, near


@njit(inline="always", **_JIT)
def _log(v, floor):
    return np.log(max(v, floor))


@njit(inline="always", **_JIT)
def _hue_or_white(m, seen, hue, c, floor, sigma):
    """Colour ``c`` alone clipped: the odds of ``hue`` over white light (the reference's
    ``_hue_or_white``), ``m`` the block's means, ``seen`` its shares."""
    a, b = (1, 2) if c == 0 else ((0, 2) if c == 1 else (0, 1))
    seen_ratio = _log(seen[a], floor) - _log(seen[b], floor)
    guess_ratio = _log(hue[a], floor) - _log(hue[b], floor)
    rest = m[a] + m[b]
    top = _log(m[c], floor)
    short_white = max(top - _log(rest / np.float32(2.0), floor), np.float32(0.0))
    guess = max(hue[c], floor) * rest / max(hue[a] + hue[b], floor)
    short_hue = max(top - _log(guess, floor), np.float32(0.0))
    miss_white = seen_ratio * seen_ratio + short_white * short_white
    miss_hue = (seen_ratio - guess_ratio) ** 2 + short_hue * short_hue
    z = (miss_white - miss_hue) / (np.float32(2.0) * sigma * sigma)
    return np.float32(1.0) / (np.float32(1.0) + np.exp(-z))


@njit(parallel=True, **_JIT)
def _estimates(
    means, flags, level, sat, r0, r1, scales, lam, neutral, margin, floor, sigma, shares, lows
):
    """Each clipped block's hue into ``shares`` (3, band, Wb) and the least level its
    clipped colours allow into ``lows`` (band, Wb) (see :func:`_site_value`);
    ``level``: each colour's clip level, ``margin``: ``HIGHLIGHT_WHITE_MARGIN``."""
    hb, wb = flags.shape
    third = np.float32(1.0 / 3.0)
    for i in prange(r1 - r0):
        y = r0 + i
        share = np.empty(3, np.float32)
        hue = np.empty(3, np.float32)
        seen = np.empty(3, np.float32)
        m = np.empty(3, np.float32)
        for j in range(wb):
            f = flags[y, j]
            if f == 0:
                continue
            acc = np.zeros(4, np.float64)
            weight = 1.0
            for s in scales:
                i0, i1 = max(y - s, r0) - r0, min(y + s + 1, r1) - r0
                j0, j1 = max(j - s, 0), min(j + s + 1, wb)
                area = np.float64((2 * s + 1) * (2 * s + 1))
                for k in range(4):
                    acc[k] += _box(sat, k, i0, i1, j0, j1) / area * weight
                weight *= lam
            s = neutral
            i0, i1 = max(y - s, r0) - r0, min(y + s + 1, r1) - r0
            j0, j1 = max(j - s, 0), min(j + s + 1, wb)
            inside = (min(y + s + 1, hb) - max(y - s, 0)) * (j1 - j0)
            free = (inside - _box(sat, 4, i0, i1, j0, j1)) / np.float64((2 * s + 1) * (2 * s + 1))
            kappa = np.float32(min(2.0 * free, 1.0))
            blown = f == 3 or f >= 5  # two or three colours clipped
            if f == 3 or f == 5 or f == 6:  # two: is white light ruled out?
                u = 2 if f == 3 else (1 if f == 5 else 0)
                need = max(level[(u + 1) % 3], level[(u + 2) % 3])
                rho = min(max(means[u, y, j] / max(need, floor), np.float32(0.0)), np.float32(1.0))
                refuted = (np.float32(1.0) - rho) / margin
                kappa = max(kappa, min(max(refuted, np.float32(0.0)), np.float32(1.0)))
            for c in range(3):
                hue[c] = np.float32(acc[c] / acc[3]) if acc[3] > 0 else third
            trust = np.float32(1.0)
            if f == 1 or f == 2 or f == 4:  # one colour clipped: test the hue
                c = 0 if f == 1 else (1 if f == 2 else 2)
                total = means[0, y, j] + means[1, y, j] + means[2, y, j]
                for k in range(3):
                    m[k] = means[k, y, j]
                    seen[k] = m[k] / (total if total > 0 else np.float32(1.0))
                trust = _hue_or_white(m, seen, hue, c, floor, sigma)
            for c in range(3):
                h = hue[c]
                if blown:
                    h = kappa * h + (np.float32(1.0) - kappa) / np.float32(3.0)
                elif trust < 1:
                    h = trust * h + (np.float32(1.0) - trust) / np.float32(3.0)
                share[c] = max(h, floor)
            low = np.float32(0.0)
            for c in range(3):
                shares[c, i, j] = share[c]
                if f >> c & 1:
                    low = max(low, means[c, y, j] / share[c])
            lows[i, j] = low


@njit(inline="always", **_JIT)
def _site_value(raw, cmap, slots, table, y, x, c, f, share, low, headroom, gain):
    """The rebuilt value of colour ``c`` at site (y, x) of a block with clip flags ``f``,
    hue ``share`` (3) and least level ``low``: the block's hue at the brightness of
    the site's 3 × 3 neighbourhood, the means there of the colours the block did not
    clip over their shares (float64), raised to ``low``, at most ``headroom`` × the
    colour's clip level ``gain`` (the reference's ``_site_estimates``)."""
    h, w = raw.shape
    ph, pw = cmap.shape
    y0, y1, x0, x1 = max(y - 1, 0), min(y + 2, h), max(x - 1, 0), min(x + 2, w)
    s0 = s1 = s2 = 0.0  # each colour's sum and count over the neighbourhood
    n0 = n1 = n2 = 0.0
    p = y0 % ph
    for yy in range(y0, y1):
        q = x0 % pw
        for xx in range(x0, x1):
            k = cmap[p, q]
            v = np.float64(table[slots[p, q], raw[yy, xx]])
            if k == 0:
                s0 += v
                n0 += 1.0
            elif k == 1:
                s1 += v
                n1 += 1.0
            else:
                s2 += v
                n2 += 1.0
            q = q + 1 if q + 1 < pw else 0
        p = p + 1 if p + 1 < ph else 0
    num, den = 0.0, 0.0
    if not f & 1 and n0 > 0:
        num += s0 / n0
        den += np.float64(share[0])
    if not f >> 1 & 1 and n1 > 0:
        num += s1 / n1
        den += np.float64(share[1])
    if not f >> 2 & 1 and n2 > 0:
        num += s2 / n2
        den += np.float64(share[2])
    level = num / den if den > 0 else 0.0
    level = max(level, np.float64(low))
    return np.float32(min(np.float64(share[c]) * level, np.float64(headroom * gain)))


@njit(parallel=True, **_JIT)
def _write(raw, out, site, scale, black, span, applied):
    """Rebuilt sites into ``out`` (DN, rounded): each site of a clipped colour of a
    clipped block takes max(its value, its rebuilt value, :func:`_site_value`).
    ``site``: (cmap, slots, table, flags, shares, lows, r0, r1, b, headroom, gains), as
    :func:`reconstruct_mosaic` builds it. ``scale`` < 1: every site is first scaled
    about its black level (``span``: the levels' divisor per slot). Returns the largest
    code a rebuilt value needs, unscaled: above 65535, the caller writes again with a
    scale that fits it."""
    h, w = raw.shape
    cmap, slots, table, flags, shares, lows, r0, r1, b, headroom, gains = site
    ph, pw = cmap.shape
    hb, wb = flags.shape
    tops = np.zeros(h, np.float64)
    for y in prange(h):
        top = 0.0
        p, by = y % ph, min(y // b, hb - 1)
        band = r0 <= by < r1
        q, bx, bq = 0, 0, 0  # x % pw, the block column, x % b
        for x in range(w):
            slot, c = slots[p, q], cmap[p, q]
            dn = np.float32(raw[y, x])
            if scale != 1.0:
                dn = black[slot] + (dn - black[slot]) * scale
            f = flags[by, bx] if band else 0
            if f >> c & 1:
                share, low = shares[:, by - r0, bx], lows[by - r0, bx]
                e = _site_value(raw, cmap, slots, table, y, x, c, f, share, low, headroom, gains[c])
                top = max(top, np.float64(black[slot] + e / applied[c] * span[slot]))
                if e > table[slot, raw[y, x]]:
                    dn = black[slot] + e / applied[c] * span[slot] * scale
            out[y, x] = np.uint16(min(max(np.rint(dn), 0.0), 65535.0))
            q = q + 1 if q + 1 < pw else 0
            bq += 1
            if bq == b:
                bq = 0
                bx = min(bx + 1, wb - 1)
        tops[y] = top
    return tops.max()


def _slots(cfa: CFA) -> np.ndarray:
    """The levels slot (the kernels' table row) of each site of the period: the Bayer
    site for Bayer, the colour otherwise."""
    ph, pw = cfa.period
    if cfa.is_bayer:
        return np.arange(4, dtype=np.int64).reshape(2, 2)
    return np.array(cfa.colors, dtype=np.int64).reshape(ph, pw)


def reconstruct_mosaic(
    data: np.ndarray, cfa: CFA, ops: np.ndarray, opf: np.ndarray, gains
) -> tuple[np.ndarray, np.ndarray]:
    """The (H, W) uint16 mosaic ``data`` of ``cfa`` with its clipped highlights rebuilt,
    and the op numbers ``opf`` to read it with.

    ``ops``/``opf``: the mosaic ops before the highlight stage, levels then white
    balance (:func:`rawsim.engine.process._mosaic_value`); ``gains``: the white
    balance (R, G, B) that sets the clip levels, colour c clipping at ``gains[c]``.
    Returns ``data`` itself and ``opf`` when nothing clipped; else a new mosaic (DN)
    and ``opf`` with the levels' span scaled where the rebuilt values needed more
    codes than 65535.
    """
    ops = np.asarray(ops, dtype=np.int64)
    if ops.tolist() not in ([OP_LEVELS], [OP_LEVELS, OP_WB]):
        raise ValueError("the highlight pre-pass takes levels, then white balance, only")
    g = np.asarray(gains, dtype=np.float32)
    h, w = data.shape
    b = highlight_block(cfa.colors, cfa.period)
    hb, wb = h // b, w // b
    if hb == 0 or wb == 0:
        return data, opf
    ph, pw = cfa.period
    cmap = np.array(cfa.colors, dtype=np.int64).reshape(ph, pw)
    slots = _slots(cfa)
    level = np.float32(HIGHLIGHT_CLIPPED) * g
    data = np.ascontiguousarray(data)
    opf = np.asarray(opf, dtype=np.float64)
    # A site clips at black + 0.99 of the span: below the lowest such code, none can
    # (a margin for float32 rounding), and one max over the codes is all the work.
    used = np.unique(slots)
    lowest = float(np.min(opf[0, used] + (HIGHLIGHT_CLIPPED - 1e-3) * opf[0, 4 + used]))
    if int(data.max()) < lowest:
        return data, opf
    means = np.empty((3, hb, wb), np.float32)
    flags = np.empty((hb, wb), np.uint8)
    slot_colour = np.zeros(4, np.int64)  # the colour of each levels slot (X-Trans: 3)
    slot_colour[slots.ravel()] = cmap.ravel()
    table = mosaic_table(slot_colour, ops, opf)
    if not _blocks(data, cmap, slots, table, level, b, means, flags):
        return data, opf
    rows = np.flatnonzero(flags.any(axis=1))  # the band: clipped rows and their border
    r0 = max(0, int(rows[0]) - HIGHLIGHT_BORDER - 1)
    r1 = min(hb, int(rows[-1]) + HIGHLIGHT_BORDER + 2)
    fields, near = _fields(means, flags, g, r0, r1, HIGHLIGHT_BORDER, HIGHLIGHT_BORDER_POWER)
    sat = _sat(fields, near, r0, r1, hb, wb, HIGHLIGHT_BORDER)
    del fields
    shares = np.zeros((3, r1 - r0, wb), np.float32)
    lows = np.zeros((r1 - r0, wb), np.float32)
    scales = np.array(HIGHLIGHT_SCALES, dtype=np.int64)
    _estimates(
        means,
        flags,
        level,
        sat,
        r0,
        r1,
        scales,
        HIGHLIGHT_SCALE_WEIGHT,
        HIGHLIGHT_NEUTRAL,
        np.float32(HIGHLIGHT_WHITE_MARGIN),
        np.float32(HIGHLIGHT_RATIO_FLOOR),
        np.float32(HIGHLIGHT_HUE_SIGMA),
        shares,
        lows,
    )
    black, span = opf[0, :4].astype(np.float32), opf[0, 4:8].astype(np.float32)
    applied = opf[1, :3].astype(np.float32) if ops.size > 1 else np.ones(3, np.float32)
    headroom = np.float32(HIGHLIGHT_HEADROOM)
    site = (cmap, slots, table, flags, shares, lows, r0, r1, b, headroom, g)
    out = np.empty_like(data)
    top = _write(data, out, site, np.float32(1.0), black, span, applied)
    scale = np.float32(1.0)
    if top > 65535.0:  # rebuilt values need more codes: scale every site to fit them
        bmax = float(black.max())
        scale = np.float32((65535.0 - bmax) / (top - bmax))
        _write(data, out, site, scale, black, span, applied)
    if scale < 1:
        opf = opf.copy()
        opf[0, 4:8] = (span * scale).astype(np.float64)
    return out, opf
