"""The resampling kernel of the lens remap: Lanczos-3, tabulated by sub-pixel phase.

A sample at a fractional position takes the 6 × 6 pixels around it, weighted by
``L(t) = sinc(t)·sinc(t/3)`` of each tap's distance t (pixels), per axis. The
weights come from a table of :data:`PHASES` + 1 phases of the fraction, each row
normalised to sum 1 (a flat image stays flat), in float32: the torch reference
(:mod:`rawsim.isp.lens`) and the engine (:mod:`rawsim.engine.lens`) read the same
numbers, so their arithmetic stays identical. Rounding the fraction to the nearest
phase moves a sample by at most 1/(2·PHASES) pixel.

Lanczos-3 against bilinear, measured on a Kodak photo through a barrel distortion
and back (resampling only, central 90 %): 37.4 dB against 28.1 dB.

Both remaps then keep each sample within the range of the 2 × 2 pixels around it,
so no edge rings: Lanczos' negative lobes overshoot by up to a tenth of an edge's
step, and a highlight rebuilt above white (``--highlights reconstruct``) makes
steps of several times white. On the lens round trip of ``bench_lens.py``
(stop 51, with reconstruct the default): Kodak mean 35.12 → 35.66 dB (EF-S 18-55)
and 37.03 → 37.62 dB (EF-S 10-18), worst cases 27.95 → 28.51 and 29.44 → 30.17 dB;
on six other photos (tests/data srgb and srgb16) means 36.39 → 36.63 and 39.81 →
39.90 dB.

NumPy only (the engine imports it).
"""

from __future__ import annotations

from functools import cache

import numpy as np

#: Taps per axis, and the first tap's offset from the sample's floor.
TAPS, FIRST = 6, -2
#: Sub-pixel phases of the table (rows: PHASES + 1, fraction 0 … 1).
PHASES = 1024


@cache
def lanczos_table() -> np.ndarray:
    """(PHASES + 1, TAPS) float32: row p weighs the taps ``floor + FIRST + i`` of a sample
    at fraction ``p / PHASES`` past its floor."""
    frac = np.arange(PHASES + 1, dtype=np.float64)[:, None] / PHASES
    t = frac - (FIRST + np.arange(TAPS, dtype=np.float64))[None, :]
    w = np.sinc(t) * np.sinc(t / 3.0)
    w /= w.sum(axis=1, keepdims=True)
    table = w.astype(np.float32)
    table.setflags(write=False)
    return table
