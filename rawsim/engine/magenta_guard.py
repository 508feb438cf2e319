"""``reconstruct``'s magenta guard, compiled: the engine's form of
:mod:`rawsim.isp.magenta_guard` (the torch reference, which defines it).

The render kernels of :mod:`rawsim.engine.process` call :func:`green_raise` on each
demosaicked pixel that :func:`rawsim.engine.highlights.reconstruct_mosaic` marked (within
1 px of a clipped green site), in float64 as the reference, and raise its green by
the result.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rawsim.engine import configure
from rawsim.isp.config import (
    HIGHLIGHT_GUARD_CHROMA,
    HIGHLIGHT_GUARD_REACH,
    HIGHLIGHT_GUARD_STEPS,
    magenta_edges,
)

configure()

_JIT = {"cache": True, "error_model": "numpy"}
(_X1, _Y1), (_X2, _Y2) = magenta_edges()
_REACH = float(HIGHLIGHT_GUARD_REACH)
_CHROMA = float(HIGHLIGHT_GUARD_CHROMA)
_STEPS = int(HIGHLIGHT_GUARD_STEPS)
#: Greys let go without cube roots: in the band x > y < z (over the white), and where
#: x − y ≤ this × y and z − y ≤ _NEAR_Z × y, the cube root's concavity bounds a* by
#: 500/3 · (x − y) / y^(2/3) and |b*| by 200/3 · (z − y) / y^(2/3), so the chroma is at
#: most 0.92 of the grey bound, HIGHLIGHT_GUARD_CHROMA × 116 f(Y): the answer is the
#: reference's.
_NEAR_X, _NEAR_Z = _CHROMA / 2.0, _CHROMA
if math.hypot(500 / 3 * _NEAR_X, 200 / 3 * _NEAR_Z) >= 116 * _CHROMA:
    raise AssertionError("the magenta guard's grey shortcut would let colours go")


@njit(inline="always", **_JIT)
def _in_band(r, g, b, m):
    """Whether camera RGB (r, g, b) has its CIELAB hue strictly inside the band and is
    no grey (``m``: camera → XYZ over the white, (3, 3) float64). The band lies where a > 0
    and b < 0, that is X > Y < Z over the white: colours outside that are let go
    before the cube roots (the reference takes them; the answer is the same)."""
    x = max(m[0, 0] * r + m[0, 1] * g + m[0, 2] * b, 0.0)
    y = max(m[1, 0] * r + m[1, 1] * g + m[1, 2] * b, 0.0)
    z = max(m[2, 0] * r + m[2, 1] * g + m[2, 2] * b, 0.0)
    if not (x > y and y < z):
        return False
    if x - y <= _NEAR_X * y and z - y <= _NEAR_Z * y:
        return False  # a grey: let go before the cube roots (see _NEAR_X)
    fx, fy, fz = np.cbrt(x), np.cbrt(y), np.cbrt(z)
    a, bb = 500.0 * (fx - fy), 200.0 * (fy - fz)
    grey = _CHROMA * 116.0 * fy
    return _X1 * bb - _Y1 * a > 0.0 and _X2 * bb - _Y2 * a < 0.0 and a * a + bb * bb > grey * grey


@njit(inline="always", **_JIT)
def green_raise(r, g, b, m):
    """The least raise of green (float64) that takes (r, g, b) out of the band, found
    by halving as the reference does; 0 where it is outside or nothing is positive."""
    top = max(r, max(g, b))
    if top <= 0.0 or not _in_band(r, g, b, m):
        return 0.0
    lo, hi = 0.0, _REACH * top
    for _ in range(_STEPS):
        mid = (lo + hi) / 2
        if _in_band(r, g + mid, b, m):
            lo = mid
        else:
            hi = mid
    return hi
