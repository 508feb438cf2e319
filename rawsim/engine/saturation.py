"""Each colour's saturation level, read from a raw's data.

A file's white level is a promise its data do not always keep. Some sensors
saturate a colour below it: an old Canon's red tops out at 96 % of the white
level while its green and blue reach it; a soft knee leaves every colour a
fraction of a percent short; a maker scales a colour before the file is written.
Highlights that clipped in every colour then keep a cast: the colour that
saturated low stays below the others after white balance.

LibRaw finds the white from the data (its ``data_maximum``, ``adjust_maximum``) for
all colours at once. This does it per colour. A colour's sites pile up where it
saturates: many sites within a narrow band, as dense as or denser than the band
below it, where a highlight that did not saturate thins out towards its brightest
site. :func:`find_saturation` looks for that pile in each colour's brightest codes:

* scanning down from its brightest code, the first band of
  ``PILE_BAND`` × (white − black) codes that holds at least ``PILE_SITES`` sites
  (and ``PILE_SHARE`` of the colour's) at ``PILE_DENSITY`` times the density of the
  two bands below it, with at most ``PILE_ABOVE`` of its count in the two bands
  above it and its mean within ``PILE_TOP`` × (white − black) of its top, is a pile
  (an unsaturated highlight spreads its noise on both sides of its mode): the
  colour saturates at the top of that band, or the white level if that is lower
  (sites within
  ``PILE_BAND`` below it count as saturated, as
  :data:`~rawsim.isp.config.HIGHLIGHT_CLIPPED` counts them);
  the scan goes ``PILE_REACH`` × (white − black) below the brightest code, so a
  few hot pixels above the pile do not hide it;
* a colour without a pile, or whose pile lies below ``PILE_LEAST`` of the span,
  saturates at the white level, as the file says (also where a few of its sites
  reach it: hot pixels, or a lossy codec's overshoot).

Raws whose codec spreads saturated values over hundreds of codes (GoPro's VC-5:
±150 DN around a level 5 % below white) hold no pile this narrow, and keep the
white level, as LibRaw does.

A flat patch without noise (a synthetic render) at the top of a colour's range
piles up as saturation does and is taken for it, as LibRaw's ``adjust_maximum`` takes
the brightest value for white; real sensors' noise spreads a patch into a peak
with its upper tail above it, which is not a pile.

Two passes over the data, both parallel: each position's maximum over the rows
of its phase and each row's maximum (vectorised); then, in the rows that reach
the bands, a histogram of each colour's brightest codes. 24 MP take a few
milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from rawsim.engine import configure

configure()

_JIT = {"cache": True, "error_model": "numpy"}
#: A pile is at least this many sites, and this share of the colour's sites...
PILE_SITES = 64
PILE_SHARE = 1e-4
#: ... in a band of this share of (white − black) below its top...
PILE_BAND = 0.01
#: ... at this many times the density (sites per code) of the two bands below it.
PILE_DENSITY = 1.0
#: ... with at most this share of its count in the two bands above it, and its mean
#: within this share of (white − black) below its top: a pile leans on its top, where
#: the sensor stopped counting, as a patch that did not saturate, its mode a few
#: standard deviations of its noise below its brightest site, does not.
PILE_ABOVE = 0.05
PILE_TOP = 0.004
#: The scan for a pile reaches this share of (white − black) below a colour's brightest code.
PILE_REACH = 0.08
#: A pile below this share of (white − black) above black is not taken for saturation
#: (LibRaw's ``adjust_maximum_thr``: a data maximum above it becomes the white level).
PILE_LEAST = 0.75


@dataclass(frozen=True)
class Saturation:
    """Where each colour (R, G, B) saturates.

    ``levels``: DN, each at most the white level. ``notes``: how each was found, in
    words, for ``rawsim info`` and the sidecar."""

    levels: tuple[float, float, float]
    notes: tuple[str, str, str]

    def fractions(self, black, white: float) -> tuple[float, float, float]:
        """Each level as a share of its colour's span: (level − black) / (white − black),
        at most 1; ``black`` per colour (R, G, B)."""
        return tuple(
            float(min((lv - b) / (white - b), 1.0))
            for lv, b in zip(self.levels, black, strict=True)
        )


@njit(parallel=True, nogil=True, **_JIT)
def _maxima(data, ph, threads):
    """Each position's maximum over the rows of its phase (ph, W) and each row's
    maximum (H,), of ``data`` (H, W) uint16."""
    h, w = data.shape
    each = np.zeros((threads, ph, w), np.uint16)
    rows = np.zeros(h, np.uint16)
    per = -(-h // threads)
    for t in prange(threads):
        for y in range(t * per, min(h, (t + 1) * per)):
            row = data[y]
            top = each[t, y % ph]
            most = np.uint16(0)
            for x in range(w):
                v = row[x]
                top[x] = max(top[x], v)
                most = max(most, v)
            rows[y] = most
    out = each[0].copy()
    for t in range(1, threads):
        for p in range(ph):
            for x in range(w):
                out[p, x] = max(out[p, x], each[t, p, x])
    return out, rows


@njit(parallel=True, nogil=True, **_JIT)
def _histograms(data, rows, colour, low, size, threads):
    """Each colour's sites at codes low[c] … low[c] + size − 1 (3, size) int64 (no
    site of colour c lies above: low[c] + size − 1 is at least its brightest), over
    the rows whose maximum reaches the least of ``low``; ``colour`` (ph, W) gives
    each position's colour. The comparison with each position's low code vectorises;
    only the sites at or above it are counted."""
    h, w = data.shape
    ph = colour.shape[0]
    least = min(low[0], low[1], low[2])
    floor = np.empty((ph, w), np.int32)  # each position's low code
    for p in range(ph):
        for x in range(w):
            floor[p, x] = low[colour[p, x]]
    counts = np.zeros((threads, 3, size), np.int64)
    per = -(-h // threads)
    for t in prange(threads):
        over = np.empty(w, np.int32)
        for y in range(t * per, min(h, (t + 1) * per)):
            if np.int64(rows[y]) < least:
                continue
            row, fl, cr = data[y], floor[y % ph], colour[y % ph]
            n = 0
            for x in range(w):
                over[n] = x
                n += np.int32(row[x]) >= fl[x]
            for i in range(n):
                x = over[i]
                counts[t, cr[x], np.int32(row[x]) - fl[x]] += 1
    return counts.sum(0)


def find_saturation(data: np.ndarray, colours: np.ndarray, black, white: float) -> Saturation:
    """Where each colour of ``data`` saturates (module docstring).

    ``data``: (H, W) uint16 mosaic, or (H, W, 3) per-pixel colours; ``colours``: the
    colour (0, 1, 2) of each site of one period, (ph, pw), for a mosaic (ignored for
    3-channel data); ``black``: each colour's black level (DN, R, G, B); ``white``: the
    white level (DN)."""
    if data.ndim == 3:
        h, w, c = data.shape
        data = data.reshape(h, w * c)
        colours = np.arange(c, dtype=np.int64).reshape(1, c)
    data = np.ascontiguousarray(data, dtype=np.uint16)
    colours = np.asarray(colours, dtype=np.int64)
    ph, pw = colours.shape
    threads = numba.get_num_threads()
    tops, rows = _maxima(data, ph, threads)
    w = data.shape[1]
    cover = np.tile(colours, (1, -(-w // pw)))[:, :w]  # (ph, W)
    black = np.asarray(black, dtype=np.float64).reshape(3)
    brightest = np.array([tops[cover == c].max(initial=0) for c in range(3)], np.int64)
    span = float(white) - black
    band = np.maximum(np.ceil(PILE_BAND * span), 1).astype(np.int64)
    reach = np.ceil(PILE_REACH * span).astype(np.int64) + 3 * band
    low = np.maximum(brightest - reach, 0)
    size = int(max(reach.max() + 1, 1))
    counts = _histograms(data, rows, np.ascontiguousarray(cover), low, size, threads)
    sites = np.array([(cover == c).sum() for c in range(3)]) * (data.shape[0] / ph)
    least = np.maximum(PILE_SITES, np.ceil(PILE_SHARE * sites)).astype(np.int64)
    levels, notes = [], []
    for c in range(3):
        level, note = _level(
            counts[c], int(low[c]), int(brightest[c]), int(band[c]), int(least[c]), black[c], white
        )
        levels.append(level)
        notes.append(note)
    return Saturation(tuple(levels), tuple(notes))


def _level(
    counts: np.ndarray, low: int, top: int, band: int, least: int, black: float, white: float
):
    """One colour's level (DN) and how it was found, from its sites' ``counts`` at
    codes ``low`` … (its brightest code ``top``; ``band``: :data:`PILE_BAND` in codes;
    ``least``: the fewest sites a pile holds)."""
    white = float(white)
    span = white - black
    if top - black < PILE_LEAST * span:
        return white, f"none: its brightest site is at {100 * (top - black) / span:.0f} % of white"
    cum = np.concatenate([[0], np.cumsum(counts)])  # cum[i]: sites below code low + i
    moment = np.concatenate([[0], np.cumsum(counts * np.arange(counts.size))])

    def window(lo, hi):  # sites and code sums at codes lo … hi − 1 (arrays of codes)
        lo = np.clip(lo - low, 0, cum.size - 1)
        hi = np.clip(hi - low, 0, cum.size - 1)
        return cum[hi] - cum[lo], moment[hi] - moment[lo]

    floor = max(low + 3 * band, int(np.ceil(black + PILE_LEAST * span)))
    k = np.arange(top, floor - 1, -1)  # each candidate top, scanning down
    k = k[counts[k - low] > 0]
    pile, sums = window(k - band + 1, k + 1)
    below, _ = window(k - 3 * band + 1, k - band + 1)
    above, _ = window(k + 1, k + 2 * band + 1)
    mean = low + sums / np.maximum(pile, 1)
    ok = (
        (pile >= least)
        & (pile >= PILE_DENSITY * below / 2)
        & (above <= PILE_ABOVE * pile)
        & (k - mean <= PILE_TOP * span)
    )
    if ok.any():
        first = int(np.argmax(ok))
        k, pile = int(k[first]), int(pile[first])
        level = min(float(k), white)
        where = "the white level" if level >= white else f"{k}"
        return level, (
            f"{pile} sites pile up within {band} DN below {where} "
            f"({100 * (level - black) / span:.1f} % of white)"
        )
    if top >= white:
        return white, "reaches the white level"
    share = 100 * (top - black) / span
    return white, f"no pile-up below its brightest site ({share:.1f} % of white)"
