"""Highlight handling on a raw mosaic, compiled: the engine's form of ``unclip`` and
``reconstruct`` (:func:`rawsim.isp.highlights.unclip_highlights`,
:func:`rawsim.isp.highlights.reconstruct_highlights`: the torch reference, which
defines the methods).

:func:`reconstruct_mosaic` and :func:`unclip_mosaic` are pre-passes, as raw
denoising is: each turns the uint16 mosaic (DN) into one whose clipped sites hold
their rebuilt values (DN, rounded), which the render kernels of
:mod:`rawsim.engine.process` then take as any raw, with no highlight op of their
own. The mosaic stages before the highlight stage (levels, white balance: the
kernels' own arithmetic, tabulated once for every code at each levels slot by
:func:`~rawsim.engine.process.mosaic_table`) give the linear values the methods
read; rebuilt values go back through their inverse. Values above the white level
fit the uint16 codes above it; where they would not (a white level near 65535) the
whole mosaic is scaled down, and the levels' span with it, so the kernels read the
same linear values to rounding (:func:`_rewrite`).

Work goes by tiles of ``TILE`` × ``TILE`` blocks, in proportion to what clipped:
one integer comparison per site finds the tiles that hold a clipped site (nothing
else when none does). ``unclip`` reads only the blocks of those tiles: each block's
clipped sites are raised to the largest value of its colours that did not clip.
``reconstruct`` reads block means and clip flags in those tiles and their
neighbours only, and keeps them per tile (no array the size of the mosaic but the
copy that takes the rebuilt sites); the hue fields of their border blocks go into
a summed-area table per tile (float64), and the box sums at clipped blocks add up
the tables of the tiles a box covers. Each clipped block keeps its hue and least
level, and its clipped sites are rebuilt from their 3 × 3 neighbourhoods into a
copy of the mosaic. The reference fits each site twice, the second time with its
rebuilt neighbours at their first values; the engine writes once, recomputing a
neighbour's first value where the fit reads it (:func:`_site_value`).
Threads take tiles as they finish one (:mod:`rawsim.engine.tiles`), and the
kernels release the GIL.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from rawsim.cfa import CFA
from rawsim.engine import configure
from rawsim.engine.process import OP_LEVELS, OP_WB, mosaic_table
from rawsim.engine.tiles import next_tile
from rawsim.io.spare import Spare
from rawsim.isp.config import (
    HIGHLIGHT_BORDER,
    HIGHLIGHT_BORDER_POWER,
    HIGHLIGHT_CLIPPED,
    HIGHLIGHT_HEADROOM,
    HIGHLIGHT_HUE_PRIOR,
    HIGHLIGHT_HUE_REACH,
    HIGHLIGHT_HUE_SIGMA,
    HIGHLIGHT_HUE_SPREAD,
    HIGHLIGHT_RATIO_FLOOR,
    HIGHLIGHT_SCALE_WEIGHT,
    HIGHLIGHT_SCALES,
    HIGHLIGHT_UNCLIP_CLIPPED,
    HIGHLIGHT_WHITE_MARGIN,
    highlight_block,
)

configure()

_JIT = {"cache": True, "error_model": "numpy"}
#: Fields of the border tables: weight × share of R, G, B; weight; weight × each share
#: squared.
FIELDS = 7


#: Blocks per side of the tiles the pre-pass works in: only tiles with a clipped site
#: and their neighbours are read (at least HIGHLIGHT_BORDER + 2 blocks).
TILE = 32


@njit(inline="always", **_JIT)
def _at(flags, slot, i, j):
    """Block (i, j)'s clip flags from the tiles' ``flags`` (n, TILE, TILE), ``slot``
    (Th, Tw) giving each tile's index there (−1: none, no clip)."""
    s = slot[i // TILE, j // TILE]
    return flags[s, i % TILE, j % TILE] if s >= 0 else np.uint8(0)


@njit(inline="always", **_JIT)
def _mean(means, slot, c, i, j):
    """Block (i, j)'s mean of colour c from the tiles' ``means`` (n, 3, TILE, TILE)
    (only read in tiles that have them)."""
    return means[slot[i // TILE, j // TILE], c, i % TILE, j % TILE]


@njit(parallel=True, nogil=True, **_JIT)
def _clipped_tiles(raw, lines, b, hb, wb, threads):
    """(Th, Tw) uint8: whether each tile of TILE × TILE whole b × b blocks holds a site at or
    above its clip code (``lines``: (period rows, W) int32, the least code that clips at
    each column of each row of the CFA's period; 65536 where none does). An integer
    comparison per site, so a mosaic with nothing clipped costs one read."""
    t = TILE
    ph = lines.shape[0]
    th, tw = -(-hb // t), -(-wb // t)
    tiles = np.zeros((th, tw), np.uint8)
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        while True:
            ti = next_tile(counter)
            if ti >= th:
                break
            hit = np.zeros(wb * b, np.uint8)  # any clipped site in each column of the tile row
            for y in range(ti * t * b, min(ti * t + t, hb) * b):
                line = lines[y % ph]
                for x in range(wb * b):
                    hit[x] |= np.int32(raw[y, x]) >= line[x]
            for tj in range(tw):
                tiles[ti, tj] = hit[tj * t * b : min(tj * t + t, wb) * b].max()
    return tiles


@njit(inline="always", **_JIT)
def _block_row(src, i, ja, jb, k, i0, j0, out):
    """:func:`_blocks` for blocks [ja, jb) of block row ``i`` of tile ``k`` (its first
    block (i0, j0)): ``src`` (raw, cmap, slots, table, level, b) and ``out`` (means,
    flags, then scratch of a tile row: sums, counts, flags) as it takes them."""
    raw, cmap, slots, table, level, b = src
    means, flags, sums, n, f = out
    ph, pw = cmap.shape
    sums[:] = 0.0
    n[:] = 0.0
    f[:] = 0
    for y in range(i * b, i * b + b):  # a row at a time, each block's sites in order
        p = y % ph
        q, j, bq = (ja * b) % pw, ja - j0, 0  # x % pw, the block column in the tile, x % b
        for x in range(ja * b, jb * b):
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
    for j in range(ja - j0, jb - j0):
        for c in range(3):
            means[k, c, i - i0, j] = sums[c, j] / n[c, j]
        flags[k, i - i0, j] = f[j]


@njit(inline="always", **_JIT)
def _marked(clipped, ti, tj):
    """Whether ``clipped`` (Th, Tw) marks tile (ti, tj); False beyond it."""
    th, tw = clipped.shape
    return 0 <= ti < th and 0 <= tj < tw and clipped[ti, tj] != 0


@njit(inline="always", **_JIT)
def _beside(clipped, ti, tj, top, bottom):
    """Whether a row lies near clipped tile (ti, tj), or, where the row is near its
    tile's ``top`` or ``bottom``, near the one above or below (ti ± 1, tj): for a row
    of tile (ti, tj ± 1), a clipped tile at its side or corner; of tile (ti, tj)
    itself, unmarked, one across its top or bottom edge."""
    return (
        _marked(clipped, ti, tj)
        or (top and _marked(clipped, ti - 1, tj))
        or (bottom and _marked(clipped, ti + 1, tj))
    )


@njit(parallel=True, nogil=True, **_JIT)
def _blocks(src, tiles, clipped, reach, hb, wb, means, flags, threads):
    """Each whole b × b block's colour means (n, 3, TILE, TILE) and clip flags (n, TILE,
    TILE; bit c: colour c has a site ≥ ``level[c]``) in the n tiles listed in
    ``tiles`` (n, 2) of the Hb × Wb blocks; ``src``: (raw, cmap, slots, table, level, b),
    the sites' values read from ``table`` (:func:`~rawsim.engine.process.mosaic_table`,
    a row per levels slot).

    A tile that ``clipped`` (Th, Tw) does not mark holds no clipped site: its flags are
    zeros, and its means are read only within ``reach`` blocks of a clipped tile (a
    border block's 3 × 3, :func:`_tile_sats`), so only those are written: the rows
    along an edge it shares with a clipped tile, and the ends of rows beside one (or
    near a clipped corner)."""
    t = TILE
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        out = (
            means,
            flags,
            np.zeros((3, t), np.float32),
            np.zeros((3, t), np.float32),
            np.zeros(t, np.uint8),
        )
        while True:
            k = next_tile(counter)
            if k >= tiles.shape[0]:
                break
            ti, tj = tiles[k, 0], tiles[k, 1]
            i0, j0 = ti * t, tj * t
            i1, j1 = min(i0 + t, hb), min(j0 + t, wb)
            whole = clipped[ti, tj] != 0
            if not whole:
                flags[k] = 0
            for i in range(i0, i1):
                # the blocks [j0, left) and [right, j1) of this row
                left, right = j1, j1
                if not whole:
                    top, bottom = i < i0 + reach, i >= i0 + t - reach
                    if not _beside(clipped, ti, tj, top, bottom):  # not the whole row
                        near = _beside(clipped, ti, tj - 1, top, bottom)
                        left = min(j0 + reach, j1) if near else j0
                        near = _beside(clipped, ti, tj + 1, top, bottom)
                        right = max(j1 - reach, left) if near else j1
                if left > j0:
                    _block_row(src, i, j0, left, k, i0, j0, out)
                if right < j1:
                    _block_row(src, i, right, j1, k, i0, j0, out)


@njit(parallel=True, nogil=True, **_JIT)
def _tile_sats(means, flags, slot, clips, tiles, hb, wb, border, power, fields, sats, threads):
    """Summed-area tables of each listed tile into ``sats`` (n, TILE + 1, TILE + 1,
    FIELDS) float64, of its first ``fields`` fields (the others are left as they were;
    the squared shares are read only where two colours clipped: :func:`_agreement`)
    (``tiles``: (n, 2) tile rows and columns; means and flags as
    :func:`_blocks` gives them for these tiles, ``slot`` each tile's index in them):
    the border blocks' hue fields (weight × share of R, G, B; weight; weight × each
    share squared, for the border's spread of hue), read over each block's 3 × 3
    blocks and weighted by their brightness to ``power`` (float32 products, as the
    reference forms them). Border blocks lie within ``border`` blocks of a clipped one
    but not next to one; the fields are zero elsewhere. Entries of blocks beyond the
    image (a tile at the last row or column) are left as they were: no box reads them."""
    t = TILE
    # a table's first row and column are zeros; the rest is written where a box may
    # read it (the tile's blocks inside the image): no pass to zero it first
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        while True:
            k = next_tile(counter)
            if k >= tiles.shape[0]:
                break
            sats[k, 0, :, :] = 0.0
            sats[k, :, 0, :] = 0.0
            i0, j0 = tiles[k, 0] * t, tiles[k, 1] * t
            i1, j1 = min(i0 + t, hb), min(j0 + t, wb)
            # Clipped blocks within 1 and within ``border`` columns, for the tile's rows and
            # ``border`` rows each side (running counts along each row of the blocks'
            # clip flags): then the same down the columns.
            a0, a1 = max(i0 - border, 0), min(i1 + border, hb)
            c0, c1 = max(j0 - border, 0), min(j1 + border, wb)
            wide = np.zeros((a1 - a0, j1 - j0), np.uint8)
            run = np.zeros(c1 - c0 + 1, np.int32)
            for i in range(a0, a1):
                for jj in range(c0, c1):
                    run[jj - c0 + 1] = run[jj - c0] + (_at(flags, slot, i, jj) != 0)
                for j in range(j0, j1):
                    lo, hi = max(j - border, 0) - c0, min(j + border + 1, wb) - c0
                    near_lo, near_hi = max(j - 1, 0) - c0, min(j + 2, wb) - c0
                    v = np.uint8(1 if run[hi] > run[lo] else 0)
                    wide[i - a0, j - j0] = v | (2 if run[near_hi] > run[near_lo] else 0)
            # running counts down each column: any within ``border`` rows, and within 1
            down = np.zeros((a1 - a0 + 1, j1 - j0, 2), np.int32)
            for ii in range(a1 - a0):
                for j in range(j1 - j0):
                    v = wide[ii, j]
                    down[ii + 1, j, 0] = down[ii, j, 0] + (v != 0)
                    down[ii + 1, j, 1] = down[ii, j, 1] + (v >= 2)
            sat = sats[k]
            around = np.empty(3, np.float32)  # the block's 3 × 3 blocks' colour means
            field = np.zeros(FIELDS, np.float64)
            for i in range(i0, i1):
                lo, hi = max(i - border, 0) - a0, min(i + border + 1, hb) - a0
                near_lo, near_hi = max(i - 1, 0) - a0, min(i + 2, hb) - a0
                for j in range(j0, j1):
                    inside = down[hi, j - j0, 0] > down[lo, j - j0, 0]
                    close = down[near_hi, j - j0, 1] > down[near_lo, j - j0, 1]
                    field[:] = 0.0
                    if inside and not close:
                        # the block's 3 × 3 blocks (in the image), summed as avg_pool2d sums them
                        ya, yb, ja, jb = (
                            max(i - 1, 0),
                            min(i + 2, hb),
                            max(j - 1, 0),
                            min(j + 2, wb),
                        )
                        count = np.float32((yb - ya) * (jb - ja))
                        for c in range(3):
                            acc = np.float32(0.0)
                            for yy in range(ya, yb):
                                for jj in range(ja, jb):
                                    acc += _mean(means, slot, c, yy, jj)
                            around[c] = acc / count
                        total = around[0] + around[1] + around[2]
                        if total > 0:
                            bright = max(
                                around[0] / clips[0], around[1] / clips[1], around[2] / clips[2]
                            )
                            bright = np.float32(
                                min(max(bright, np.float32(0.0)), np.float32(1.0)) ** power
                            )
                            for c in range(3):
                                share = around[c] / total
                                field[c] = np.float64(bright * share)
                                field[4 + c] = np.float64(bright * (share * share))
                            field[3] = np.float64(bright)
                    li, lj = i - i0 + 1, j - j0 + 1
                    for f in range(fields):
                        sat[li, lj, f] = (
                            field[f]
                            + sat[li - 1, lj, f]
                            + sat[li, lj - 1, f]
                            - sat[li - 1, lj - 1, f]
                        )


@njit(inline="always", **_JIT)
def _box(sats, slot, i0, i1, j0, j1, out, first, last):
    """Sums of the fields [``first``, ``last``) over blocks [i0, i1) × [j0, j1) (inside
    the image) into those of ``out`` (the others are left), from the tables of the tiles
    the box covers (``slot``: each tile's table, −1 where none: zero)."""
    t = TILE
    out[first:last] = 0.0
    for ti in range(i0 // t, (i1 - 1) // t + 1):
        a0, a1 = max(i0 - ti * t, 0), min(i1 - ti * t, t)
        for tj in range(j0 // t, (j1 - 1) // t + 1):
            s = slot[ti, tj]
            if s < 0:
                continue
            c0, c1 = max(j0 - tj * t, 0), min(j1 - tj * t, t)
            # a table's first row and column are zeros: read only the corners that are
            # not (1 read for a whole tile, 2 along the box's edges; the same sums)
            if a0 == 0 and c0 == 0:
                for f in range(first, last):
                    out[f] += sats[s, a1, c1, f]
            elif a0 == 0:
                for f in range(first, last):
                    out[f] += sats[s, a1, c1, f] - sats[s, a1, c0, f]
            elif c0 == 0:
                for f in range(first, last):
                    out[f] += sats[s, a1, c1, f] - sats[s, a0, c1, f]
            else:
                for f in range(first, last):
                    out[f] += (
                        sats[s, a1, c1, f]
                        - sats[s, a0, c1, f]
                        - sats[s, a1, c0, f]
                        + sats[s, a0, c0, f]
                    )


@njit(inline="always", **_JIT)
def _scale_sums(sats, slot, y, j, hb, wb, scales, lam, acc, box, first, last):
    """Fields [``first``, ``last``) of block (y, j)'s border into ``acc`` (same indices):
    their box means over ``scales`` (half-widths in blocks), each ``lam`` times the one
    before, summed in the reference's order (``box``: scratch of :data:`FIELDS`)."""
    acc[first:last] = 0.0
    weight = 1.0
    for s in scales:
        i0, i1 = max(y - s, 0), min(y + s + 1, hb)
        j0, j1 = max(j - s, 0), min(j + s + 1, wb)
        area = np.float64((2 * s + 1) * (2 * s + 1))
        _box(sats, slot, i0, i1, j0, j1, box, first, last)
        for f in range(first, last):
            acc[f] += box[f] / area * weight
        weight *= lam


@njit(inline="always", **_JIT)
def _agreement(sats, slot, y, j, hb, wb, scales, lam, acc, box, spread_limit):
    """How well the border of block (y, j) agrees on its hue (0–1, float32): 1 − the
    root of its shares' summed variances over ``spread_limit``. ``acc`` holds the
    block's hue fields and weight (:func:`_estimates`); the squared shares are summed
    here, over the same boxes, into ``acc[4:7]``."""
    _scale_sums(sats, slot, y, j, hb, wb, scales, lam, acc, box, 4, FIELDS)
    spread = 0.0
    for c in range(3):
        centre = acc[c] / acc[3]
        spread += max(acc[4 + c] / acc[3] - centre * centre, 0.0)
    return np.float32(min(max(1.0 - np.sqrt(spread) / spread_limit, 0.0), 1.0))


@njit(inline="always", **_JIT)
def _log(v, floor):
    return np.log(max(v, floor))


@njit(inline="always", **_JIT)
def _hue_or_white(m, seen, hue, c, floor, sigma, prior):
    """Colour ``c`` alone clipped: the odds of ``hue`` over white light (the reference's
    ``_hue_or_white``), ``m`` the block's means, ``seen`` its shares, ``prior`` the
    hue's log odds before the test."""
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
    z = (miss_white - miss_hue) / (np.float32(2.0) * sigma * sigma) + prior
    return np.float32(1.0) / (np.float32(1.0) + np.exp(-z))


@njit(inline="always", **_JIT)
def _hue_reach(m, hue, c, floor, reach):
    """Colour ``c`` alone clipped: how far (0–1) ``hue`` is kept, by the value it gives
    ``c`` over white light's (the reference's ``_hue_reach``); ``reach``: (whole up to,
    none from)."""
    a, b = (1, 2) if c == 0 else ((0, 2) if c == 1 else (0, 1))
    rest = m[a] + m[b]
    guess = hue[c] * rest / max(hue[a] + hue[b], floor)
    white = max(max(m[c], rest / np.float32(2.0)), floor)
    lo, hi = np.float32(reach[0]), np.float32(reach[1])
    return min(max((hi - guess / white) / (hi - lo), np.float32(0.0)), np.float32(1.0))


@njit(inline="always", **_JIT)
def _refuted(rho, margin):
    """How surely (0–1) a guess is refuted, from what it predicts over what was
    measured (``rho``, clamped to 0–1): full at (1 − ``margin``) or below."""
    rho = min(max(rho, np.float32(0.0)), np.float32(1.0))
    return min(max((np.float32(1.0) - rho) / margin, np.float32(0.0)), np.float32(1.0))


@njit(parallel=True, nogil=True, **_JIT)
def _estimates(
    means,
    flags,
    level,
    sats,
    slot,
    sat_slot,
    tiles,
    hb,
    wb,
    scales,
    lam,
    margin,
    floor,
    sigma,
    prior,
    reach,
    spread_limit,
    shares,
    lows,
    threads,
):
    """Each clipped block's hue into ``shares`` (n, 3, TILE, TILE) and the least level
    its clipped colours allow into ``lows`` (n, TILE, TILE), for the n tiles listed in
    ``tiles`` (those that hold clipped sites; see :func:`_site_value`) of the Hb × Wb
    blocks; ``slot``: each tile's index in ``means`` and ``flags``; ``sats``/``sat_slot``:
    the fields' tables and each tile's index there (:func:`_tile_sats`, :func:`_box`);
    ``level``: each colour's clip threshold (``HIGHLIGHT_CLIPPED`` × its level),
    ``margin``: ``HIGHLIGHT_WHITE_MARGIN``,
    ``prior``: ``HIGHLIGHT_HUE_PRIOR``, ``reach``: ``HIGHLIGHT_HUE_REACH``,
    ``spread_limit``: ``HIGHLIGHT_HUE_SPREAD``."""
    t = TILE
    third = np.float32(1.0 / 3.0)
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        while True:
            n = next_tile(counter)
            if n >= tiles.shape[0]:
                break
            share = np.empty(3, np.float32)
            hue = np.empty(3, np.float32)
            seen = np.empty(3, np.float32)
            m = np.empty(3, np.float32)
            acc = np.zeros(FIELDS, np.float64)  # hue fields, weight, shares squared
            box = np.zeros(FIELDS, np.float64)
            y0, x0 = tiles[n, 0] * t, tiles[n, 1] * t
            for y in range(y0, min(y0 + t, hb)):
                for j in range(x0, min(x0 + t, wb)):
                    f = _at(flags, slot, y, j)
                    if f == 0:
                        continue
                    if f == 7:  # three clipped: nothing measured the light, white
                        low = np.float32(0.0)
                        for c in range(3):
                            shares[n, c, y - y0, j - x0] = third
                            low = max(low, _mean(means, slot, c, y, j) / third)
                        lows[n, y - y0, j - x0] = low
                        continue
                    _scale_sums(sats, sat_slot, y, j, hb, wb, scales, lam, acc, box, 0, 4)
                    blown = f == 3 or f >= 5  # two colours clipped
                    for c in range(3):
                        hue[c] = np.float32(acc[c] / acc[3]) if acc[3] > 0 else third
                    kappa = np.float32(1.0)  # read only where blown
                    if blown:  # two: are white light and the hue ruled out?
                        u = 2 if f == 3 else (1 if f == 5 else 0)
                        mu = _mean(means, slot, u, y, j)
                        need = max(level[(u + 1) % 3], level[(u + 2) % 3])
                        white = _refuted(mu / max(need, floor), margin)
                        rho = np.float32(1.0)
                        for c in ((u + 1) % 3, (u + 2) % 3):
                            made = mu * hue[c] / max(hue[u], floor)
                            rho = min(rho, made / max(_mean(means, slot, c, y, j), floor))
                        kept = np.float32(1.0) - _refuted(rho, margin)
                        kappa = white * kept  # at any depth
                    if blown and acc[3] > 0 and hue[1] <= min(hue[0], hue[2]):
                        # least green: a purple mixed from a border that disagrees?
                        kappa = kappa * _agreement(
                            sats, sat_slot, y, j, hb, wb, scales, lam, acc, box, spread_limit
                        )
                    trust = np.float32(1.0)
                    if f == 1 or f == 2 or f == 4:  # one colour clipped: test the hue
                        c = 0 if f == 1 else (1 if f == 2 else 2)
                        total = (
                            _mean(means, slot, 0, y, j)
                            + _mean(means, slot, 1, y, j)
                            + _mean(means, slot, 2, y, j)
                        )
                        for k in range(3):
                            m[k] = _mean(means, slot, k, y, j)
                            seen[k] = m[k] / (total if total > 0 else np.float32(1.0))
                        trust = _hue_or_white(m, seen, hue, c, floor, sigma, prior)
                        trust = trust * _hue_reach(m, hue, c, floor, reach)
                    for c in range(3):
                        h = hue[c]
                        if blown:
                            h = kappa * h + (np.float32(1.0) - kappa) / np.float32(3.0)
                        elif trust < 1:
                            h = trust * h + (np.float32(1.0) - trust) / np.float32(3.0)
                        share[c] = h
                    if f == 1 or f == 2 or f == 4:  # one clipped: at least white's share
                        c = 0 if f == 1 else (1 if f == 2 else 2)
                        own = share[c]
                        lifted = max(own, third)
                        rest = (np.float32(1.0) - lifted) / max(np.float32(1.0) - own, floor)
                        for k in range(3):
                            share[k] = lifted if k == c else share[k] * rest
                    for c in range(3):
                        share[c] = max(share[c], floor)
                    low = np.float32(0.0)
                    for c in range(3):
                        shares[n, c, y - y0, j - x0] = share[c]
                        if f >> c & 1:
                            low = max(low, _mean(means, slot, c, y, j) / share[c])
                    lows[n, y - y0, j - x0] = low


@njit(inline="always", **_JIT)
def _add(sums, k, v):
    """Site value ``v`` of colour ``k`` into ``sums`` (:func:`_sums`' layout): its square
    and itself (below 0 taken as 0), and one to the count."""
    lit = max(np.float64(v), 0.0)
    sums[k] += lit * lit
    sums[3 + k] += lit
    sums[6 + k] += 1.0


@njit(inline="always", **_JIT)
def _sums(raw, cmap, slots, table, y, x, sums):
    """Each colour's sums over the 3 × 3 neighbourhood of site (y, x), into ``sums`` (9,
    float64: R, G, B sums of squares, sums, then counts; values below 0 taken as 0),
    for the brightness-weighted means of :func:`_value`."""
    h, w = raw.shape
    ph, pw = cmap.shape
    sums[:] = 0.0
    y0, y1, x0, x1 = max(y - 1, 0), min(y + 2, h), max(x - 1, 0), min(x + 2, w)
    p = y0 % ph
    for yy in range(y0, y1):
        q = x0 % pw
        for xx in range(x0, x1):
            _add(sums, cmap[p, q], table[slots[p, q], raw[yy, xx]])
            q = q + 1 if q + 1 < pw else 0
        p = p + 1 if p + 1 < ph else 0


@njit(inline="always", **_JIT)
def _value(sums, c, f, share, low, headroom, gain):
    """The rebuilt value of colour ``c`` in a block with clip flags ``f``, hue ``share``
    (3) and least level ``low``: the block's hue at the brightness of the site's
    neighbourhood (``sums``, :func:`_sums`), the brightness-weighted means there (Σ v²
    / Σ v, 0 where all are 0) of the colours the block did not clip over their shares
    (float64), raised to ``low``, at most ``headroom`` × the colour's clip level
    ``gain`` (the reference's ``_level_estimates`` of its ``_local_levels``)."""
    num, den = 0.0, 0.0
    for k in range(3):
        if not f >> k & 1 and sums[6 + k] > 0:
            if sums[3 + k] > 0:
                num += sums[k] / sums[3 + k]
            den += np.float64(share[k])
    level = num / den if den > 0 else 0.0
    level = max(level, np.float64(low))
    return np.float32(min(np.float64(share[c]) * level, np.float64(headroom * gain)))


@njit(inline="always", **_JIT)
def _site_value(raw, y, x, c, f, by, bx, site, sums, first):
    """The second fit's value of colour ``c`` at site (y, x) of block (by, bx), whose
    clip flags are ``f`` (``site``: as :func:`_write` takes it): :func:`_value` over
    the site's neighbourhood, where each neighbour of a colour the block did not clip
    that is itself a rebuilt site counts at its first fit's value (a clipped value is
    only a lower bound). ``sums``, ``first``: scratch (9,) float64."""
    cmap, slots, table, flags, slot, shares, lows, _, hb, wb, b, headroom, clips, level, index = (
        site
    )
    h, w = raw.shape
    ph, pw = cmap.shape
    t = TILE
    sums[:] = 0.0
    p = max(y - 1, 0) % ph
    for yy in range(max(y - 1, 0), min(y + 2, h)):
        q = max(x - 1, 0) % pw
        for xx in range(max(x - 1, 0), min(x + 2, w)):
            k = cmap[p, q]
            v = table[slots[p, q], raw[yy, xx]]
            q = q + 1 if q + 1 < pw else 0
            if not f >> k & 1 and v >= level[k]:  # read by the fit, and clipped
                ny, nx = min(yy // b, hb - 1), min(xx // b, wb - 1)
                g = _at(flags, slot, ny, nx)
                if g >> k & 1:  # its block clipped its colour: rebuilt
                    n = index[ny // t, nx // t]
                    _sums(raw, cmap, slots, table, yy, xx, first)
                    share, low = shares[n, :, ny % t, nx % t], lows[n, ny % t, nx % t]
                    v = max(v, _value(first, k, g, share, low, headroom, clips[k]))
            _add(sums, k, v)
        p = p + 1 if p + 1 < ph else 0
    n = index[by // t, bx // t]
    return _value(
        sums, c, f, shares[n, :, by % t, bx % t], lows[n, by % t, bx % t], headroom, clips[c]
    )


@njit(parallel=True, nogil=True, **_JIT)
def _copy(raw, out, slots, black, scale, threads):
    """Every site into ``out``, scaled by ``scale`` about its black level (DN, rounded):
    a plain copy at scale 1."""
    h, w = raw.shape
    ph, pw = slots.shape
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        while True:
            y = next_tile(counter)
            if y >= h:
                break
            if scale == 1.0:
                for x in range(w):  # a loop: a slice assignment compiles seconds longer
                    out[y, x] = raw[y, x]
                continue
            for x in range(w):
                k = black[slots[y % ph, x % pw]]
                dn = k + (np.float32(raw[y, x]) - k) * scale
                out[y, x] = np.uint16(min(max(np.rint(dn), 0.0), 65535.0))


@njit(parallel=True, nogil=True, **_JIT)
def _apply(patch, data, tiles, b, hb, wb, threads):
    """Every nonzero site of ``patch`` into ``data`` (the rebuilt codes: never 0), and
    ``patch`` back to zeros, read where sites are rebuilt: the tiles listed in
    ``tiles`` (n, 2) of the Hb × Wb whole b × b blocks and the sites beyond the last
    whole block row and column (:func:`_tile_sites`)."""
    h, w = data.shape
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        while True:
            k = next_tile(counter)
            if k >= tiles.shape[0] + 2:
                break
            y0, y1, x0, x1 = _tile_sites(tiles, k, b, hb, wb, h, w)
            for y in range(y0, y1):
                row = patch[y]
                for x in range(x0, x1):
                    if row[x]:
                        data[y, x] = row[x]
                        row[x] = 0


@njit(parallel=True, nogil=True, **_JIT)
def _write(raw, out, site, scale, black, span, applied, threads):
    """Rebuilt sites into ``out`` (DN, rounded; it already holds every site, scaled by
    ``scale`` about its black level): each site that clipped, in a block where its
    colour clipped, takes max(its value, its rebuilt value, :func:`_site_value`); sites
    beyond the last whole block row or column go with that block (and clip at the
    same levels). ``site``: (cmap, slots, table, flags, slot, shares, lows, tiles,
    Hb, Wb, b, headroom, the colours' clip levels, the sites' clip thresholds, each
    clipped tile's index in ``tiles``),
    as :func:`reconstruct_mosaic` builds it
    (``span``: the levels' divisor per levels slot). Returns the largest code a
    rebuilt value needs, unscaled: above 65535, the caller writes again with a scale
    that fits it."""
    h, w = raw.shape
    cmap, slots, table, flags, slot, shares, lows, tiles, hb, wb, b, headroom, clips, level, _ = (
        site
    )
    ph, pw = cmap.shape
    t = TILE
    tops = np.zeros(tiles.shape[0], np.float64)
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        while True:
            n = next_tile(counter)
            if n >= tiles.shape[0]:
                break
            top = 0.0
            sums, first = np.empty(9, np.float64), np.empty(9, np.float64)
            i0, j0 = tiles[n, 0] * t, tiles[n, 1] * t
            for by in range(i0, min(i0 + t, hb)):
                for bx in range(j0, min(j0 + t, wb)):
                    f = _at(flags, slot, by, bx)
                    if f == 0:
                        continue
                    y1 = h if by == hb - 1 else by * b + b
                    x1 = w if bx == wb - 1 else bx * b + b
                    for y in range(by * b, y1):
                        p, q = y % ph, (bx * b) % pw
                        for x in range(bx * b, x1):
                            k, c = slots[p, q], cmap[p, q]
                            q = q + 1 if q + 1 < pw else 0
                            v = table[k, raw[y, x]]
                            if not f >> c & 1 or v < level[c]:
                                continue  # only sites that clipped, of colours that clipped
                            e = _site_value(raw, y, x, c, f, by, bx, site, sums, first)
                            top = max(top, np.float64(black[k] + e / applied[c] * span[k]))
                            if e > v:
                                dn = black[k] + e / applied[c] * span[k] * scale
                                out[y, x] = np.uint16(min(max(np.rint(dn), 0.0), 65535.0))
            tops[n] = top
    return tops.max()


def _clipped_flags(flags, slot, tiles, hb: int, wb: int) -> np.ndarray:
    """(m, TILE, TILE) uint8: the clip flags of the m tiles ``tiles`` (m, 2) (``flags``,
    ``slot`` as :func:`_blocks` gives them), zeros for blocks beyond Hb × Wb (which it
    leaves unwritten)."""
    t = TILE
    inside = ((tiles[:, :1] * t + np.arange(t)) < hb)[:, :, None] & (
        (tiles[:, 1:] * t + np.arange(t)) < wb
    )[:, None, :]
    return np.where(inside, flags[slot[tiles[:, 0], tiles[:, 1]]], 0)


def _bordered(kept, clipped, border: int) -> np.ndarray:
    """(Th, Tw) bool: the tiles that may hold a border block (:func:`_tile_sats`), those
    with a clipped block within ``border`` blocks of theirs (``border`` < ``TILE``, so
    of their own or their eight neighbours'); the others' tables would be zeros. From
    the extent of each clipped tile's clipped blocks: ``kept`` (m, TILE, TILE), the
    flags of the m tiles ``clipped`` (Th, Tw) marks, in :func:`_tile_list`'s order
    (:func:`_clipped_flags`)."""
    t = TILE
    th, tw = clipped.shape
    at = np.argwhere(clipped)
    hit = kept != 0  # (m, TILE, TILE)
    rows, cols = hit.any(2), hit.any(1)
    some = rows.any(1)
    # each tile's first and last clipped block row and column, padded by a tile of
    # none (first beyond every tile, last before every one) on each side
    far = np.iinfo(np.int64).max // 4
    first = np.full((2, th + 2, tw + 2), far, np.int64)
    last = np.full((2, th + 2, tw + 2), -far, np.int64)
    at0, at1 = at[:, 0] * t, at[:, 1] * t
    first[:, at[:, 0] + 1, at[:, 1] + 1] = np.where(
        some, np.stack([at0 + rows.argmax(1), at1 + cols.argmax(1)]), far
    )
    last[:, at[:, 0] + 1, at[:, 1] + 1] = np.where(
        some,
        np.stack([at0 + t - 1 - rows[:, ::-1].argmax(1), at1 + t - 1 - cols[:, ::-1].argmax(1)]),
        -far,
    )
    ti, tj = np.meshgrid(np.arange(th) * t, np.arange(tw) * t, indexing="ij")  # first blocks
    out = np.zeros((th, tw), bool)
    for dy in range(3):
        for dx in range(3):
            (first_r, first_c), (last_r, last_c) = (
                a[:, dy : dy + th, dx : dx + tw] for a in (first, last)
            )
            out |= (
                (first_r <= ti + t - 1 + border)
                & (last_r >= ti - border)
                & (first_c <= tj + t - 1 + border)
                & (last_c >= tj - border)
            )
    return out


def _around(tiles: np.ndarray) -> np.ndarray:
    """The tiles marked in ``tiles`` (Th, Tw) and their eight neighbours: all that lies
    within the border (and its 3 × 3 reads) of a clipped block."""
    out = np.zeros((tiles.shape[0] + 2, tiles.shape[1] + 2), np.uint8)
    for dy in range(3):
        for dx in range(3):
            out[dy : dy + tiles.shape[0], dx : dx + tiles.shape[1]] |= tiles
    return np.ascontiguousarray(out[1:-1, 1:-1])


def _clip_lines(table, slots, level, cmap, w: int) -> np.ndarray:
    """(period rows, ``w``) int32: the least code (DN) at which the site in each column
    of each row of the CFA's period clips (its ``table`` value ≥ ``level`` of its
    colour), 65536 where none does; 0 (every code: the block pass decides) where its
    table row is not monotonic, which levels and white balance never make."""
    ph, pw = cmap.shape
    least = np.zeros((ph, pw), np.int32)
    for p in range(ph):
        for q in range(pw):
            row = table[slots[p, q]]
            if bool(np.all(row[1:] >= row[:-1])):
                least[p, q] = np.searchsorted(row, level[cmap[p, q]], side="left")
    return np.ascontiguousarray(np.tile(least, (1, -(-w // pw)))[:, :w])


def _slots(cfa: CFA) -> np.ndarray:
    """The levels slot (the kernels' table row) of each site of the period: the Bayer
    site for Bayer, the colour otherwise."""
    ph, pw = cfa.period
    if cfa.is_bayer:
        return np.arange(4, dtype=np.int64).reshape(2, 2)
    return np.array(cfa.colors, dtype=np.int64).reshape(ph, pw)


def _clip_codes(data, cfa: CFA, ops, opf, g, clipped: float = HIGHLIGHT_CLIPPED):
    """What tells a clipped site (at ``clipped`` × its colour's level or above) in the
    uint16 mosaic ``data``: (cmap, slots, table, level, lines) (:func:`_clip_lines`),
    or None where no site reaches its clip code."""
    ph, pw = cfa.period
    cmap = np.array(cfa.colors, dtype=np.int64).reshape(ph, pw)
    slots = _slots(cfa)
    level = np.float32(clipped) * g
    # A site clips at black + ``clipped`` × its colour's saturation share of the span
    # (its level over its white-balance gain): below the lowest such code, none can (a
    # margin for float32 rounding), and one max over the codes is all the work.
    applied = opf[1, :3] if len(ops) > 1 else np.ones(3)
    share = float(np.min(np.asarray(g, np.float64) / applied))
    used = np.unique(slots)
    lowest = float(np.min(opf[0, used] + (clipped * share - 1e-3) * opf[0, 4 + used]))
    if int(data.max()) < lowest:
        return None
    slot_colour = np.zeros(4, np.int64)  # the colour of each levels slot (X-Trans: 3)
    slot_colour[slots.ravel()] = cmap.ravel()
    table = mosaic_table(slot_colour, ops, opf)
    lines = _clip_lines(table, slots, level, cmap, data.shape[1])
    return cmap, slots, table, level, lines


@njit(inline="always", **_JIT)
def _tile_sites(tiles, k, b, hb, wb, h, w):
    """The sites (y0, y1, x0, x1) of item ``k``: the whole blocks of tile ``tiles[k]``
    (k < n, the tiles listed), the sites below the last whole block row (k = n), or
    those right of the last whole block column (k = n + 1)."""
    t = TILE
    n = tiles.shape[0]
    if k == n:
        return hb * b, h, 0, w
    if k == n + 1:
        return 0, hb * b, wb * b, w
    i0, j0 = tiles[k, 0] * t, tiles[k, 1] * t
    return i0 * b, min(i0 + t, hb) * b, j0 * b, min(j0 + t, wb) * b


@njit(parallel=True, nogil=True, **_JIT)
def _green_near(raw, lines, tiles, b, hb, wb, near, rows, threads):
    """Marks 1 in ``near`` (H, W) uint8 within 1 px (3 × 3, inside the image) of each
    site at or above its code in ``lines`` (:func:`_clip_codes`), and in ``rows`` (H,)
    uint8 the rows that have any mark; both zeros before. Read only in the tiles listed
    in ``tiles`` (n, 2; those with a clipped site, :func:`_clipped_tiles`) and the sites
    beyond the last whole block row and column: no site elsewhere reaches its code.
    Each tile's sites mark the pixels around them, 1 px into the next tiles: a byte
    may be written by two threads, always 1."""
    h, w = raw.shape
    ph = lines.shape[0]
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        hit = np.zeros(w + 4, np.uint8)
        while True:
            k = next_tile(counter)
            if k >= tiles.shape[0] + 2:
                break
            y0, y1, x0, x1 = _tile_sites(tiles, k, b, hb, wb, h, w)
            xa, xb = max(x0 - 1, 0), min(x1 + 1, w)
            for y in range(y0, y1):
                line, src = lines[y % ph], raw[y]
                # hit[x + 2]: whether site x reached its code; none beyond the tile's
                hit[x0], hit[x0 + 1], hit[x1 + 2], hit[x1 + 3] = 0, 0, 0, 0
                any_ = np.uint8(0)
                for x in range(x0, x1):
                    v = np.uint8(np.int32(src[x]) >= line[x])
                    hit[x + 2] = v
                    any_ |= v
                if not any_:
                    continue
                for yy in range(max(y - 1, 0), min(y + 2, h)):
                    rows[yy] = 1
                    row = near[yy]
                    for x in range(xa, xb):
                        if hit[x + 1] | hit[x + 2] | hit[x + 3]:  # sites x − 1, x, x + 1
                            row[x] = 1


def _clipped_green(data, cmap, lines, tiles, b: int, hb: int, wb: int, marks=None):
    """The magenta guard's pixels (:mod:`rawsim.engine.magenta_guard`) from the clip
    codes ``lines`` of every site: (H, W) uint8, 1 within 1 px of a green site at or
    above its code, and (H,) uint8, whether each row has any (into ``marks``, zeros of
    those shapes, where given; :func:`unmark` makes them zeros again); or None where
    none is. ``tiles``: the tiles with a clipped site (:func:`_tile_list` of
    :func:`_clipped_tiles`), of b × b blocks, Hb × Wb whole."""
    h, w = data.shape
    green = lines.copy()
    green[np.tile(cmap, (1, -(-w // cmap.shape[1])))[:, :w] != 1] = 65536  # others never
    near, rows = new_marks(data.shape) if marks is None else marks
    _green_near(data, green, tiles, b, hb, wb, near, rows, numba.get_num_threads())
    return (near, rows) if rows.any() else None


def new_marks(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Zeros for the magenta guard's pixels of an (H, W) mosaic: (H, W) and (H,) uint8.
    A batch keeps them (:func:`unmark`): new ones cost a page fault per 4 KiB marked."""
    return np.zeros(shape, np.uint8), np.zeros(shape[0], np.uint8)


def unmark(marks: tuple[np.ndarray, np.ndarray]) -> None:
    """The guard's pixels ``marks`` (:func:`new_marks`) back to zeros: the rows marked."""
    near, rows = marks
    near[rows.view(bool)] = 0
    rows.fill(0)


def _start(data, cfa: CFA, ops, opf, levels, clipped: float = HIGHLIGHT_CLIPPED):
    """What the pre-passes share: the checked mosaic (C-contiguous), ``ops``/``opf`` as
    arrays, the clip levels ``g`` (float32), the block side b, the whole blocks Hb ×
    Wb, and the clip codes (:func:`_clip_codes` at ``clipped``; None where the mosaic
    holds no whole block or no site reaches its code)."""
    ops = np.asarray(ops, dtype=np.int64)
    if ops.tolist() not in ([OP_LEVELS], [OP_LEVELS, OP_WB]):
        raise ValueError("the highlight pre-pass takes levels, then white balance, only")
    g = np.asarray(levels, dtype=np.float32)
    h, w = data.shape
    b = highlight_block(cfa.colors, cfa.period)
    hb, wb = h // b, w // b
    data = np.ascontiguousarray(data)
    opf = np.asarray(opf, dtype=np.float64)
    codes = _clip_codes(data, cfa, ops, opf, g, clipped) if hb and wb else None
    return data, ops, opf, g, b, hb, wb, codes


def _dn_numbers(ops, opf):
    """(black, span, applied): each levels slot's black level and span (DN, float32) and
    each colour's white-balance gain (1 without it), to turn linear values into DN."""
    black, span = opf[0, :4].astype(np.float32), opf[0, 4:8].astype(np.float32)
    applied = opf[1, :3].astype(np.float32) if ops.size > 1 else np.ones(3, np.float32)
    return black, span, applied


def _rewrite(data, out, opf, slots, black, span, write, where, patch=None):
    """``data`` into ``out`` (a new array where None; ``data`` itself: rebuilt in place)
    with the rebuilt sites that ``write(out, scale)`` writes (over every site, copied
    scaled by ``scale`` about its black level; it returns the largest code a rebuilt
    value needs, unscaled). Where that is above 65535 (a white level near it), every
    site is scaled down to fit it, and the levels' span with it, so the kernels read
    the same linear values to rounding. Returns the mosaic and ``opf`` (with the span
    scaled, if it was).

    In place, the rebuilt sites go to ``patch`` first (zeros of ``data``'s shape, left
    zeros again; a new one where None), then onto ``data`` once every fit has read the
    sites as they were: no copy of the mosaic (48 MB for 24 MP). ``where``: (tiles, b,
    Hb, Wb), where ``write`` writes (:func:`_apply`)."""
    threads = numba.get_num_threads()
    if out is data:
        patch = np.zeros(data.shape, data.dtype) if patch is None else patch
        if write(patch, np.float32(1.0)) <= 65535.0:
            _apply(patch, data, *where, threads)
            return data, opf
        patch.fill(0)
        out = np.empty_like(data)  # codes run out: scaled, into a copy
    out = np.empty_like(data) if out is None else out
    scale = np.float32(1.0)
    _copy(data, out, slots, black, scale, threads)
    top = write(out, scale)
    if top > 65535.0:  # rebuilt values need more codes: scale every site to fit them
        bmax = float(black.max())
        scale = np.float32((65535.0 - bmax) / (top - bmax))
        _copy(data, out, slots, black, scale, threads)
        write(out, scale)
    if scale < 1:
        opf = opf.copy()
        opf[0, 4:8] = (span * scale).astype(np.float64)
    return out, opf


#: The summed-area tables of the last mosaic, kept for the next one's (below
#: ``KEEP_TABLES`` bytes): a new 37 MB of them (24 MP, 1.5 % clipped) costs its page faults.
_kept = Spare()
KEEP_TABLES = 64 * 2**20


def _tables(n: int) -> np.ndarray:
    """(n, TILE + 1, TILE + 1, FIELDS) float64, values undefined: a view of the first
    n of the tables kept (:data:`_kept`) where they are enough, else of new ones."""
    shape = (TILE + 1, TILE + 1, FIELDS)
    kept = _kept.take("tables", lambda: None)
    if kept is None or kept.shape[0] < n:
        kept = np.empty((n, *shape), np.float64)
    return kept[:n]


def _tile_list(tiles: np.ndarray) -> np.ndarray:
    """(n, 2) int64: the rows and columns of the tiles marked in ``tiles`` (Th, Tw).
    np.argwhere gives an F-ordered array of two or more rows, a C one of one: made C
    always, so that the kernels have one signature whatever clipped."""
    return np.ascontiguousarray(np.argwhere(tiles))


def reconstruct_mosaic(
    data: np.ndarray,
    cfa: CFA,
    ops: np.ndarray,
    opf: np.ndarray,
    levels,
    out=None,
    guard=False,
    patch=None,
    marks=None,
) -> tuple[np.ndarray, np.ndarray, tuple | None]:
    """The (H, W) uint16 mosaic ``data`` of ``cfa`` with its clipped highlights rebuilt
    (into ``out``, uint16 of its shape, where given: ``data`` itself rebuilds it in
    place, through ``patch``, zeros of its shape left zeros, where given; see
    :func:`_rewrite`), the op numbers ``opf`` to read it with; and where ``guard``, the
    magenta guard's pixels, read with the same clip codes
    (:mod:`rawsim.engine.magenta_guard`; :func:`_clipped_green`, into ``marks`` where
    given), else None.

    ``ops``/``opf``: the mosaic ops before the highlight stage, levels then white
    balance (:func:`rawsim.engine.process._mosaic_value`); ``levels``: where each
    colour (R, G, B) clips after them (:attr:`~rawsim.isp.config.ResolvedIsp.clip_levels`).
    Returns ``data`` itself and ``opf`` when nothing clipped; else a new mosaic (DN)
    and ``opf`` with the levels' span scaled where the rebuilt values needed more
    codes than 65535.
    """
    data, ops, opf, g, b, hb, wb, codes = _start(data, cfa, ops, opf, levels)
    if codes is None:
        return data, opf, None
    cmap, slots, table, level, lines = codes
    t = TILE
    threads = numba.get_num_threads()
    clipped = _clipped_tiles(data, lines, b, hb, wb, threads)
    tiles = _tile_list(clipped)
    # the guard's pixels also where no whole block clipped (the rows and columns
    # beyond the last whole block)
    near = _clipped_green(data, cmap, lines, tiles, b, hb, wb, marks) if guard else None
    if not len(tiles):
        return data, opf, near
    listed = _tile_list(_around(clipped))  # the tiles read
    slot = np.full(clipped.shape, -1, np.int64)
    slot[listed[:, 0], listed[:, 1]] = np.arange(len(listed))
    means = np.empty((len(listed), 3, t, t), np.float32)
    flags = np.empty((len(listed), t, t), np.uint8)
    reach = HIGHLIGHT_BORDER + 1  # a border block's 3 × 3 means
    src = (data, cmap, slots, table, level, b)
    _blocks(src, listed, clipped, reach, hb, wb, means, flags, threads)
    kept = _clipped_flags(flags, slot, tiles, hb, wb)
    # tables only where a border block may lie: elsewhere they would be zeros
    bordered = _tile_list(_bordered(kept, clipped, HIGHLIGHT_BORDER) & (slot >= 0))
    sat_slot = np.full(clipped.shape, -1, np.int64)
    sat_slot[bordered[:, 0], bordered[:, 1]] = np.arange(len(bordered))
    sats = _tables(len(bordered))
    # the squared shares' tables only where a block has two colours clipped (_agreement)
    blown = bool(((kept == 3) | (kept == 5) | (kept == 6)).any())
    _tile_sats(
        means,
        flags,
        slot,
        g,
        bordered,
        hb,
        wb,
        HIGHLIGHT_BORDER,
        HIGHLIGHT_BORDER_POWER,
        FIELDS if blown else 4,
        sats,
        threads,
    )
    shares = np.zeros((len(tiles), 3, t, t), np.float32)
    lows = np.zeros((len(tiles), t, t), np.float32)
    _estimates(
        means,
        flags,
        level,
        sats,
        slot,
        sat_slot,
        tiles,
        hb,
        wb,
        np.array(HIGHLIGHT_SCALES, dtype=np.int64),
        HIGHLIGHT_SCALE_WEIGHT,
        np.float32(HIGHLIGHT_WHITE_MARGIN),
        np.float32(HIGHLIGHT_RATIO_FLOOR),
        np.float32(HIGHLIGHT_HUE_SIGMA),
        np.float32(HIGHLIGHT_HUE_PRIOR),
        np.array(HIGHLIGHT_HUE_REACH, dtype=np.float32),
        float(HIGHLIGHT_HUE_SPREAD),
        shares,
        lows,
        threads,
    )
    black, span, applied = _dn_numbers(ops, opf)
    headroom = np.float32(HIGHLIGHT_HEADROOM)
    index = np.full(clipped.shape, -1, np.int64)  # each clipped tile's row in ``tiles``
    index[tiles[:, 0], tiles[:, 1]] = np.arange(len(tiles))
    site = (
        cmap,
        slots,
        table,
        flags,
        slot,
        shares,
        lows,
        tiles,
        hb,
        wb,
        b,
        headroom,
        g,
        level,
        index,
    )

    def write(out, scale):
        return _write(data, out, site, scale, black, span, applied, threads)

    out, opf = _rewrite(data, out, opf, slots, black, span, write, (tiles, b, hb, wb), patch)
    if sats.base.nbytes <= KEEP_TABLES:
        _kept.keep("tables", sats.base)
    return out, opf, near


@njit(parallel=True, nogil=True, **_JIT)
def _unclip(raw, out, codes, b, hb, wb, tiles, scale, dn, threads):
    """``unclip``'s raised sites into ``out`` (DN, rounded; it already holds every site,
    scaled by ``scale`` about its black level), in the n tiles listed in ``tiles`` (n,
    2) of the Hb × Wb whole b × b blocks. ``codes``: (cmap, slots, table, level) of
    :func:`_clip_codes` (at ``HIGHLIGHT_UNCLIP_CLIPPED``), the sites' values read from
    ``table`` (a row per levels slot); ``dn``: (black, span, applied) of
    :func:`_dn_numbers`. In each block the colours with a site at or above ``level``
    clipped; each of their sites at or above it takes max(its value, T), T the largest
    value of the block's sites of the colours that did not clip (of all, where all did);
    sites beyond the last whole block row or column go with that block. Returns the
    largest code a raised value needs, unscaled: above 65535, the caller writes again
    with a scale that fits it."""
    cmap, slots, table, level = codes
    black, span, applied = dn
    h, w = raw.shape
    ph, pw = cmap.shape
    t = TILE
    tops = np.zeros(tiles.shape[0], np.float64)
    counter = np.zeros(1, np.int64)  # the next item (rawsim.engine.tiles)
    for _ in prange(threads):  # each thread takes items while any are left
        peak = np.empty(3, np.float32)
        while True:
            n = next_tile(counter)
            if n >= tiles.shape[0]:
                break
            top = 0.0
            i0, j0 = tiles[n, 0] * t, tiles[n, 1] * t
            for by in range(i0, min(i0 + t, hb)):
                for bx in range(j0, min(j0 + t, wb)):
                    f = 0
                    peak[:] = -np.inf
                    for y in range(by * b, by * b + b):
                        p, q = y % ph, (bx * b) % pw
                        for x in range(bx * b, bx * b + b):
                            c = cmap[p, q]
                            v = table[slots[p, q], raw[y, x]]
                            q = q + 1 if q + 1 < pw else 0
                            peak[c] = max(peak[c], v)
                            if v >= level[c]:
                                f |= 1 << c
                    if f == 0:
                        continue
                    lift = np.float32(-np.inf)  # T
                    for c in range(3):
                        if f == 7 or not f >> c & 1:
                            lift = max(lift, peak[c])
                    y1 = h if by == hb - 1 else by * b + b
                    x1 = w if bx == wb - 1 else bx * b + b
                    for y in range(by * b, y1):
                        p, q = y % ph, (bx * b) % pw
                        for x in range(bx * b, x1):
                            k, c = slots[p, q], cmap[p, q]
                            q = q + 1 if q + 1 < pw else 0
                            v = table[k, raw[y, x]]
                            if not f >> c & 1 or v < level[c] or lift <= v:
                                continue  # only clipped sites of clipped colours, raised
                            code = black[k] + lift / applied[c] * span[k]
                            top = max(top, np.float64(code))
                            code = black[k] + lift / applied[c] * span[k] * scale
                            out[y, x] = np.uint16(min(max(np.rint(code), 0.0), 65535.0))
            tops[n] = top
    return tops.max()


def unclip_mosaic(
    data: np.ndarray, cfa: CFA, ops: np.ndarray, opf: np.ndarray, levels, out=None, patch=None
) -> tuple[np.ndarray, np.ndarray]:
    """The (H, W) uint16 mosaic ``data`` of ``cfa`` with ``unclip`` applied (into
    ``out``, uint16 of its shape, where given; ``data`` itself, in place through
    ``patch``, as :func:`reconstruct_mosaic`), and the op numbers ``opf`` to read it
    with: the engine's form of :func:`rawsim.isp.highlights.unclip_highlights` on a
    mosaic, to the rounding of raised values to whole DN.

    ``ops``/``opf``/``levels`` as :func:`reconstruct_mosaic` takes them. Returns
    ``data`` itself and ``opf`` when nothing clipped (one integer comparison per
    site finds that); else a new mosaic (DN) and ``opf`` with the levels' span scaled
    where raised values needed more codes than 65535.
    """
    data, ops, opf, _, b, hb, wb, codes = _start(
        data, cfa, ops, opf, levels, HIGHLIGHT_UNCLIP_CLIPPED
    )
    if codes is None:
        return data, opf
    slots, lines = codes[1], codes[4]
    threads = numba.get_num_threads()
    clipped = _clipped_tiles(data, lines, b, hb, wb, threads)
    if not clipped.any():
        return data, opf
    tiles = _tile_list(clipped)
    dn = _dn_numbers(ops, opf)  # black, span, applied

    def write(out, scale):
        return _unclip(data, out, codes[:4], b, hb, wb, tiles, scale, dn, threads)

    return _rewrite(data, out, opf, slots, *dn[:2], write, (tiles, b, hb, wb), patch)
