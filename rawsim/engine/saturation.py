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
  above it, is a pile if it is flat: the median step from its sites to the same
  colour's next site along the row (itself in the pile) is at most ``PILE_FLAT``
  of the span, where a bright patch that did not saturate steps by its noise. The
  colour saturates at the lower quartile of the pile's sites, or the white level if
  that is lower: a clip's one code, or below the middle of a codec's spread of it
  (sites within ``PILE_BAND`` below it count as saturated, as
  :data:`~rawsim.isp.config.HIGHLIGHT_CLIPPED` counts them); the scan goes
  ``PILE_REACH`` × (white − black) below the brightest code, so a few hot pixels
  above the pile do not hide it;
* a colour without a pile, or whose pile lies below ``PILE_LEAST`` of the span,
  saturates at the white level, as the file says (also where a few of its sites
  reach it: hot pixels, or a lossy codec's overshoot).

A GoPro raw's codec spreads saturated values ±150 DN around a level 5 % below
white, from one plateau to the next, but leaves each plateau flat: its pile is found.

Three passes over the data, all parallel: each position's maximum over the rows
of its phase and each row's maximum (vectorised); then, in the rows that reach
the bands, a histogram of each colour's brightest codes; then, in the same rows,
the steps of each pile's sites.

A flat patch without noise (a synthetic render) at the top of a colour's range
piles up as saturation does and is taken for it, as LibRaw's ``adjust_maximum`` takes
the brightest value for white; a real sensor's noise makes a patch step from site
to site, which no clip does.

24 MP take about 10 ms.
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
#: ... with at most this share of its count in the two bands above it (a lossy codec
#: spreads a clip over both sides of it)...
PILE_ABOVE = 0.5
#: ... and flat: its sites' median step to the same colour's next site along the row,
#: itself in the pile, at most this share of (white − black), and at least
#: PILE_FLAT_LEAST DN. A saturated plateau holds one code, or steps of a few DN
#: (0 DN on GoPro's VC-5, 2 DN on a Canon D30's soft knee and a Nikon D1's greens),
#: where a bright patch that did not saturate steps by its photon noise (50–250 DN
#: on 14-bit raws at 50–95 % of white).
PILE_FLAT = 0.001
PILE_FLAT_LEAST = 2
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
    each position's colour. Each row's sites are compared with their positions' low
    codes in one vectorised pass (uint16 against uint16, a byte per site); its bytes
    are then read 8 at a time, and only the 8 sites of a nonzero word (a few percent:
    the brightest codes) are counted: 24 MP in 6 ms where a pass that gathered the
    positions above took 12."""
    h, w = data.shape
    ph = colour.shape[0]
    least = min(low[0], low[1], low[2])
    floor = np.empty((ph, w), np.uint16)  # each position's low code (≤ its brightest)
    for p in range(ph):
        for x in range(w):
            floor[p, x] = low[colour[p, x]]
    counts = np.zeros((threads, 3, size), np.int64)
    per = -(-h // threads)
    words = -(-w // 8)
    for t in prange(threads):
        hit = np.zeros(8 * words, np.uint8)  # whether each site reaches its low code
        eights = hit.view(np.uint64)
        for y in range(t * per, min(h, (t + 1) * per)):
            if np.int64(rows[y]) < least:
                continue
            row, fl, cr = data[y], floor[y % ph], colour[y % ph]
            for x in range(w):
                hit[x] = row[x] >= fl[x]
            for k in range(words):
                if eights[k] == 0:
                    continue
                for x in range(8 * k, min(w, 8 * k + 8)):
                    if hit[x]:
                        counts[t, cr[x], np.int32(row[x]) - np.int32(fl[x])] += 1
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
    found = [
        _candidate(
            counts[c], int(low[c]), int(brightest[c]), int(band[c]), int(least[c]), black[c], white
        )
        for c in range(3)
    ]
    # each pile's sites against their neighbour one period on: flat where saturated
    lo = np.array([k - band[c] + 1 if k else 65536 for c, (k, _) in enumerate(_tops(found))])
    hi = np.array([k if k else 65535 for k, _ in _tops(found)])
    steps = _steps(data, rows, np.ascontiguousarray(cover), lo, hi, pw, threads)
    levels, notes = [], []
    for c, (pile, why) in enumerate(found):
        if pile is None:
            levels.append(float(white))
            notes.append(why)
            continue
        k, n, quartile = pile
        step = _median(steps[c])
        most = max(PILE_FLAT * span[c], PILE_FLAT_LEAST)
        if step > most:
            share = 100 * (min(k, white) - black[c]) / span[c]
            levels.append(float(white))
            notes.append(
                f"none: {n} sites near {k} ({share:.1f} % of white) step {step} DN from their "
                f"neighbours, more than saturation leaves (a bright patch, not a clip)"
            )
            continue
        level = min(float(quartile), float(white))
        share = 100 * (level - black[c]) / span[c]
        where = "the white level" if k >= white else f"{k}"
        levels.append(level)
        notes.append(
            f"{n} sites pile up within {band[c]} DN below {where}, a quarter of them below "
            f"{level:g} ({share:.1f} % of white)"
        )
    return Saturation(tuple(levels), tuple(notes))


def _tops(found):
    """(top code, sites) of each colour's pile, (0, 0) where it has none."""
    return [pile[:2] if pile is not None else (0, 0) for pile, _ in found]


#: The steps :func:`_steps` counts: 0 … FLAT_BINS − 1 DN (larger ones in the last).
FLAT_BINS = 1024


@njit(parallel=True, nogil=True, **_JIT)
def _steps(data, rows, colour, lo, hi, pw, threads):
    """Each colour's steps (3, FLAT_BINS) int64: how many sites at codes lo[c] … hi[c]
    differ from the site one period on along their row (the same colour), itself in
    that range, by each |Δ| in DN (the last bin holds the larger ones), over the rows
    that reach the least of ``lo``. As :func:`_histograms`, each row's sites are
    tested against their positions' range in one vectorised pass, and only the words
    of eight with a site in it are read site by site (24 MP: 3–6 → 1–2 ms)."""
    h, w = data.shape
    ph = colour.shape[0]
    least = min(lo[0], lo[1], lo[2])
    low = np.empty((ph, w), np.uint16)  # each position's range, empty (1, 0) for none
    high = np.empty((ph, w), np.uint16)
    for p in range(ph):
        for x in range(w):
            c = colour[p, x]
            a, b = max(lo[c], 0), min(hi[c], 65535)
            low[p, x], high[p, x] = (a, b) if a <= b else (1, 0)
    counts = np.zeros((threads, 3, FLAT_BINS), np.int64)
    per = -(-h // threads)
    words = -(-w // 8)
    for t in prange(threads):
        hit = np.zeros(8 * words, np.uint8)  # whether each site is in its range
        eights = hit.view(np.uint64)
        for y in range(t * per, min(h, (t + 1) * per)):
            if np.int64(rows[y]) < least:
                continue
            row, lw, hg, cr = data[y], low[y % ph], high[y % ph], colour[y % ph]
            for x in range(w):
                hit[x] = (row[x] >= lw[x]) & (row[x] <= hg[x])
            for k in range(words):
                if eights[k] == 0:
                    continue
                for x in range(8 * k, min(w - pw, 8 * k + 8)):
                    if hit[x] and hit[x + pw]:  # the same colour: one period on
                        d = abs(np.int64(row[x]) - np.int64(row[x + pw]))
                        counts[t, cr[x], min(d, FLAT_BINS - 1)] += 1
    return counts.sum(0)


def _median(counts: np.ndarray) -> int:
    """The median step (DN) of :func:`_steps`' counts for one colour (0 where none)."""
    total = int(counts.sum())
    if total == 0:
        return 0
    return int(np.searchsorted(np.cumsum(counts), (total + 1) // 2))


def _candidate(
    counts: np.ndarray, low: int, top: int, band: int, least: int, black: float, white: float
):
    """One colour's pile, from its sites' ``counts`` at codes ``low`` … (its brightest
    code ``top``; ``band``: :data:`PILE_BAND` in codes; ``least``: the fewest sites a
    pile holds): (the top code of the first band, scanning down, that holds a pile, its
    sites), or (None, why not, in words)."""
    white = float(white)
    span = white - black
    if top - black < PILE_LEAST * span:
        return None, f"none: its brightest site is at {100 * (top - black) / span:.0f} % of white"
    cum = np.concatenate([[0], np.cumsum(counts)])  # cum[i]: sites below code low + i

    def sites(lo, hi):  # at codes lo … hi − 1 (arrays of codes)
        return cum[np.clip(hi - low, 0, cum.size - 1)] - cum[np.clip(lo - low, 0, cum.size - 1)]

    floor = max(low + 3 * band, int(np.ceil(black + PILE_LEAST * span)))
    k = np.arange(top, floor - 1, -1)  # each candidate top, scanning down
    k = k[counts[k - low] > 0]
    pile = sites(k - band + 1, k + 1)
    below = sites(k - 3 * band + 1, k - band + 1)
    above = sites(k + 1, k + 2 * band + 1)
    ok = (pile >= least) & (pile >= PILE_DENSITY * below / 2) & (above <= PILE_ABOVE * pile)
    if ok.any():
        first = int(np.argmax(ok))
        top, n = int(k[first]), int(pile[first])
        # where it saturates: the lower quartile of its sites (a clip is one code; a
        # codec spreads it, and the sites below its top saturated too)
        lo = max(top - band + 1, low)
        within = np.cumsum(counts[lo - low : top - low + 1])
        return (top, n, lo + int(np.searchsorted(within, within[-1] / 4))), ""
    if top >= white:
        return None, "reaches the white level"
    share = 100 * (top - black) / span
    return None, f"no pile-up below its brightest site ({share:.1f} % of white)"
