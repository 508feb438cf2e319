"""The event-stream simulator's compiled kernels (see :mod:`rawsim.events.sensor`).

Per pixel and frame step, the effective log intensity runs linearly from the
previous frame's value to this one's (``s`` from 0 to 1 over the step), while
the leak lowers the pixel's reference at a constant rate. Their difference D
is then linear in s, so the crossings of the thresholds, and their times, are
exact: an ON event each time D reaches θ+ (the reference then steps up by θ+),
an OFF event each time it reaches −θ−. Crossings within the refractory period
after the pixel's last event are absorbed (the reference follows, no event).
Shot noise adds at most one event per pixel and step, ON or OFF with
probability rate·dt/2 each, at a uniform time; it leaves the reference alone.

Two passes over the rows (``prange``): :func:`count_events` counts what each
pixel emits (the count maps), :func:`emit_events` writes the events at offsets
from those counts and advances the state. Both compute the same thing from the
same state and counter-based draws, so they agree whatever the thread count.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rawsim.engine import configure
from rawsim.noise.kernels import normal, uniforms
from rawsim.noise.philox import STREAMS

configure()  # a fork-safe threading layer, as every kernel module

SHOT = np.uint64(STREAMS["shot"])
THRESHOLD = np.uint64(STREAMS["threshold"])


@njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def threshold_normals(k0, k1, out):
    """Standard normals for the thresholds, (H, W, 2): site 2·(i·W + j) + c."""
    h, w, _ = out.shape
    for i in prange(h):
        for j in range(w):
            for c in range(2):
                out[i, j, c] = normal(np.uint64(2 * (i * w + j) + c), THRESHOLD, k0, k1)


@njit(cache=True, nogil=True, error_model="numpy")
def log_luma(frame, lut, luma, eps, out):
    """``log(Σ_c luma[c] · lut[c, frame[…, c]] + eps)`` per pixel of an integer frame
    (H, W, C) with C = 1 or 3; ``lut`` (C, codes) maps codes to linear light.

    Serial and without the GIL: it runs in the frame-reading thread beside the
    parallel kernels, and numba's thread pool takes one parallel launch at a time."""
    h, w, c = frame.shape
    for i in prange(h):
        for j in range(w):
            if c == 1:
                v = lut[0, frame[i, j, 0]]
            else:
                v = luma[0] * lut[0, frame[i, j, 0]]
                v += luma[1] * lut[1, frame[i, j, 1]] + luma[2] * lut[2, frame[i, j, 2]]
            out[i, j] = math.log(v + eps)


@njit(cache=True, nogil=True, error_model="numpy")
def log_luma_float(frame, luma, eps, out):
    """The same for linear float frames (H, W, C)."""
    h, w, c = frame.shape
    for i in prange(h):
        for j in range(w):
            if c == 1:
                v = frame[i, j, 0]
            else:
                v = luma[0] * frame[i, j, 0] + luma[1] * frame[i, j, 1]
                v += luma[2] * frame[i, j, 2]
            out[i, j] = math.log(max(v, 0.0) + eps)


@njit(inline="always")
def _pixel(d0, m, on, off, last, refractory, t0, dt, u, p_half, ts, ps, at, write):
    """Events of one pixel over one step: (emitted, ON among them, reference step, last
    event time). ``d0`` = log intensity − reference at the step's start, ``m`` its change
    over the step (leak included). Writes times and polarities from ``at`` if ``write``."""
    if m > 0.0:
        crossings = math.floor((d0 + m) / on) if d0 + m >= on else 0.0
        level, sign, polarity = on, 1.0, 1
    else:
        crossings = math.floor((-d0 - m) / off) if -d0 - m >= off else 0.0
        level, sign, polarity = off, -1.0, 0
    n = 0
    k = 1.0
    while k <= crossings:
        t = t0 + dt * (sign * k * level - d0) / m
        if t - last >= refractory:
            if write:
                ts[at + n] = t
                ps[at + n] = polarity
            n += 1
            last = t
        k += 1.0
    n_on = n if polarity == 1 else 0
    noise = -1
    if u[0] < p_half:
        noise = 1
    elif u[0] > 1.0 - p_half:
        noise = 0
    if noise >= 0:
        if write:
            ts[at + n] = t0 + dt * u[1]
            ps[at + n] = noise
        n += 1
        n_on += noise
    return n, n_on, sign * crossings * level, last


@njit(inline="always")
def _draws(index, step, k0, k1, p_half):
    if p_half > 0.0:
        return uniforms(index, SHOT, k0, k1, np.uint64(step))
    return 0.5, 0.0


@njit(inline="always")
def _site(i, j, state, leak, refractory, t0, dt, p_half, k0, k1, step, u, ts, ps, at, write):
    """:func:`_pixel` for pixel (i, j) of ``state`` = (l0, l1, ref, on, off, last): its
    shot-noise draws (site i·W + j, iteration ``step``), start difference and change."""
    l0, l1, ref, on, off, last = state
    u[0], u[1] = _draws(np.uint64(i * l0.shape[1] + j), step, k0, k1, p_half)
    d0 = l0[i, j] - ref[i, j]
    m = l1[i, j] - l0[i, j] + leak * on[i, j] * dt
    return _pixel(
        d0, m, on[i, j], off[i, j], last[i, j], refractory, t0, dt, u, p_half, ts, ps, at, write
    )


@njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def count_events(
    l0, l1, ref, on, off, last, leak, refractory, t0, dt, p_half, k0, k1, step, counts, rows
):
    """Pass 1: events per pixel, (2, H, W) ON/OFF into ``counts``, per row into ``rows``."""
    h, w = l0.shape
    state = (l0, l1, ref, on, off, last)
    ts = np.empty(0)
    ps = np.empty(0, dtype=np.int8)
    for i in prange(h):
        total = 0
        u = np.empty(2)
        for j in range(w):
            n, n_on, _, _ = _site(
                i, j, state, leak, refractory, t0, dt, p_half, k0, k1, step, u, ts, ps, 0, False
            )
            counts[0, i, j] = n_on
            counts[1, i, j] = n - n_on
            total += n
        rows[i] = total


@njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def emit_events(
    l0,
    l1,
    ref,
    on,
    off,
    last,
    leak,
    refractory,
    t0,
    dt,
    p_half,
    k0,
    k1,
    step,
    offsets,
    ts,
    xs,
    ys,
    ps,
):
    """Pass 2: write each pixel's events from ``offsets[row]`` on, advance the state."""
    h, w = l0.shape
    state = (l0, l1, ref, on, off, last)
    for i in prange(h):
        at = offsets[i]
        u = np.empty(2)
        for j in range(w):
            n, _, moved, newest = _site(
                i, j, state, leak, refractory, t0, dt, p_half, k0, k1, step, u, ts, ps, at, True
            )
            for e in range(n):
                xs[at + e] = j
                ys[at + e] = i
            at += n
            ref[i, j] += moved - leak * on[i, j] * dt
            last[i, j] = newest


@njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def time_order(t, x, y, p, t0, dt, buckets, chunks, t_out, x_out, y_out, p_out):
    """A step's events (in row-major pixel order) written into the ``*_out`` arrays in
    time order, ties keeping their row-major order.

    A stable sort in two passes that each stay in cache: ``chunks`` runs of events
    (one per thread) are counted and scattered in parallel into ``buckets`` equal
    slots of [t0, t0 + dt] (each chunk's entries of a slot after the earlier
    chunks'); then each slot (about :data:`SLOT_EVENTS` events) is sorted on its
    own, in parallel: a counting sort into finer slots and an insertion sort of
    each (about two events). A stable sort has one result, whatever the buckets,
    chunks or threads.
    """
    n = t.size
    size = (n + chunks - 1) // chunks
    counts = np.zeros((chunks, buckets), dtype=np.int64)
    for c in prange(chunks):
        for e in range(c * size, min(n, (c + 1) * size)):
            counts[c, _slot(t[e], t0, dt, buckets)] += 1
    slot = np.empty(buckets + 1, dtype=np.int64)
    at = 0
    for k in range(buckets):  # counts become each chunk's first position in each slot
        slot[k] = at
        for c in range(chunks):
            m = counts[c, k]
            counts[c, k] = at
            at += m
    slot[buckets] = at
    for c in prange(chunks):
        for e in range(c * size, min(n, (c + 1) * size)):
            k = _slot(t[e], t0, dt, buckets)
            d = counts[c, k]
            counts[c, k] = d + 1
            t_out[d], x_out[d], y_out[d], p_out[d] = t[e], x[e], y[e], p[e]
    for k in prange(buckets):
        _sort_slot(k, slot[k], slot[k + 1], t0, dt, buckets, t_out, x_out, y_out, p_out)


#: Events per slot of :func:`time_order`'s first pass (the caller's choice of buckets).
SLOT_EVENTS = 2048


@njit(inline="always")
def _position(te, t0, dt, buckets):
    """Where time ``te`` falls in [t0, t0 + dt], in units of 1/``buckets`` of it."""
    return (te - t0) / dt * buckets


@njit(inline="always")
def _slot(te, t0, dt, buckets):
    return min(max(int(_position(te, t0, dt, buckets)), 0), buckets - 1)


@njit(inline="always")
def _sort_slot(k, lo, hi, t0, dt, buckets, t_out, x_out, y_out, p_out):
    """Stable sort of ``*_out[lo:hi]`` (the events of slot ``k``) by time, in place: a
    counting sort into (hi − lo) // 2 finer slots (the fraction of slot k a time lies
    at, which rises with the time), then insertion sorts."""
    m = hi - lo
    if m < 2:
        return
    fine = max(m // 2, 1)
    lt, lx, ly, lp = (
        t_out[lo:hi].copy(),
        x_out[lo:hi].copy(),
        y_out[lo:hi].copy(),
        p_out[lo:hi].copy(),
    )
    key = np.empty(m, dtype=np.int64)
    start = np.zeros(fine + 1, dtype=np.int64)
    for e in range(m):
        f = int((_position(lt[e], t0, dt, buckets) - k) * fine)
        key[e] = min(max(f, 0), fine - 1)
        start[key[e] + 1] += 1
    for f in range(fine):
        start[f + 1] += start[f]
    for e in range(m):
        d = lo + start[key[e]]
        start[key[e]] += 1
        t_out[d], x_out[d], y_out[d], p_out[d] = lt[e], lx[e], ly[e], lp[e]
    first = lo
    for f in range(fine):  # start[f] is now the end of fine slot f
        end = lo + start[f]
        for a in range(first + 1, end):
            te, xe, ye, pe = t_out[a], x_out[a], y_out[a], p_out[a]
            b = a - 1
            while b >= first and t_out[b] > te:
                t_out[b + 1], x_out[b + 1], y_out[b + 1] = t_out[b], x_out[b], y_out[b]
                p_out[b + 1] = p_out[b]
                b -= 1
            t_out[b + 1], x_out[b + 1], y_out[b + 1], p_out[b + 1] = te, xe, ye, pe
        first = end


#: "00" … "99": the two digits of each number below 100, for writing two at a time.
_PAIRS = np.array([ord(c) for k in range(100) for c in f"{k:02d}"], dtype=np.uint8)


@njit(inline="always")
def _width(value):
    """The decimal digits of ``value`` (uint64)."""
    n = 1
    power = np.uint64(10)
    while n < 20 and value >= power:
        n += 1
        power *= np.uint64(10)
    return n


@njit(inline="always")
def _put(value, out, end):
    """Write ``value`` (uint64) in decimal into ``out``, its last digit at ``end`` − 1
    (the caller made room for :func:`_width` digits), two digits a division."""
    hundred = np.uint64(100)
    while value >= hundred:
        q = value // hundred
        r = np.intp(value - q * hundred)
        out[end - 2], out[end - 1] = _PAIRS[2 * r], _PAIRS[2 * r + 1]
        end -= 2
        value = q
    if value >= np.uint64(10):
        r = np.intp(value)
        out[end - 2], out[end - 1] = _PAIRS[2 * r], _PAIRS[2 * r + 1]
    else:
        out[end - 1] = np.uint8(48) + np.uint8(value)


@njit(inline="always")
def _nine(value, out, at):
    """Write ``value`` (< 10⁹) as exactly 9 digits, zero-padded, at ``out[at:]``: a digit
    and four pairs, whose divisions do not wait on each other."""
    v = np.int64(value)
    rest = v % 100_000_000
    out[at] = np.uint8(48 + v // 100_000_000)
    a, b = rest // 1_000_000, (rest // 10_000) % 100
    c, d = (rest // 100) % 100, rest % 100
    out[at + 1], out[at + 2] = _PAIRS[2 * a], _PAIRS[2 * a + 1]
    out[at + 3], out[at + 4] = _PAIRS[2 * b], _PAIRS[2 * b + 1]
    out[at + 5], out[at + 6] = _PAIRS[2 * c], _PAIRS[2 * c + 1]
    out[at + 7], out[at + 8] = _PAIRS[2 * d], _PAIRS[2 * d + 1]


#: Events per block of the parallel writers.
_BLOCK = 65536
#: Events per block of :func:`text_lines` (small: many blocks share the threads evenly).
_TEXT_BLOCK = 8192
#: The most bytes of one text line: seconds < 10¹⁰ with the point and 9 decimals (20),
#: x and y < 65536 (5 each), p, three spaces and the newline.
LINE_BYTES = 40
_GIGA = np.uint64(1_000_000_000)


@njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def text_lines(t, x, y, p, out):
    """Events as ``t x y p`` lines into the uint8 buffer ``out`` (at least
    ``LINE_BYTES`` per event); returns the bytes used. t (s, ≥ 0) is written with
    9 decimals from its integer nanoseconds (``np.round``: half to even).

    Two parallel passes over blocks of events: the bytes of each block's lines
    (their digits counted), then each block's lines written where the blocks before
    it end. (Formatting each block into a slot of ``LINE_BYTES`` per event and moving
    the blocks together after took a serial byte copy of most of the text: 10 → 4 ms
    for 323 k events on two cores.)"""
    n = t.size
    blocks = (n + _TEXT_BLOCK - 1) // _TEXT_BLOCK
    starts = np.zeros(blocks + 1, dtype=np.int64)
    for b in prange(blocks):
        size = 0
        for e in range(b * _TEXT_BLOCK, min(n, (b + 1) * _TEXT_BLOCK)):
            seconds = np.uint64(np.rint(t[e] * 1e9)) // _GIGA
            size += _width(seconds) + _width(np.uint64(x[e])) + _width(np.uint64(y[e])) + 15
        starts[b + 1] = size
    for b in range(blocks):
        starts[b + 1] += starts[b]
    for b in prange(blocks):
        at = starts[b]
        for e in range(b * _TEXT_BLOCK, min(n, (b + 1) * _TEXT_BLOCK)):
            ns = np.uint64(np.rint(t[e] * 1e9))
            seconds = ns // _GIGA
            at += _width(seconds)
            _put(seconds, out, at)
            out[at] = 46  # "."
            _nine(ns % _GIGA, out, at + 1)
            out[at + 10] = 32
            at += 11 + _width(np.uint64(x[e]))
            _put(np.uint64(x[e]), out, at)
            out[at] = 32
            at += 1 + _width(np.uint64(y[e]))
            _put(np.uint64(y[e]), out, at)
            out[at] = 32
            out[at + 1] = 48 + p[e]
            out[at + 2] = 10
            at += 3
    return starts[blocks]


@njit(cache=True, parallel=True, nogil=True)
def v2e_rows(t, x, y, p, out):
    """Events as v2e's (N, 4) uint32 rows ``[t µs, x, y, p]`` into ``out``, t rounded
    half to even (``np.round``); parallel over blocks of rows."""
    n = t.size
    blocks = (n + _BLOCK - 1) // _BLOCK
    for b in prange(blocks):
        for e in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            out[e, 0] = np.uint32(np.rint(t[e] * 1e6))
            out[e, 1], out[e, 2], out[e, 3] = x[e], y[e], p[e]
