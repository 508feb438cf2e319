"""Elementary functions built from +, −, ×, ÷ alone, shared by every backend.

The noise generator must give the same bits in the torch reference (any device)
and in the compiled engine. IEEE 754 makes +, −, ×, ÷ and √ correctly rounded,
but ``log``, ``exp`` and ``cos`` come from different libraries (libm, SLEEF,
CUDA's) that disagree in the last bit. So the noise transforms use these
polynomials instead: each is written once, with operators only, and is called
on Python/numba floats by the engine and on float64 tensors by the reference,
which evaluates exactly the same sequence of rounded operations. Neither
backend contracts them into fused multiply-adds (eager torch runs each
operator separately; numba compiles with ``fastmath=False``).

Accuracy: a few ulp in float64 over the reduced ranges stated below; far finer
than noise needs, and the same on every machine.
"""

from __future__ import annotations

import math

#: ln 2 split so that ``e · LN2_HI`` is exact for |e| < 2¹¹ (Cody–Waite).
LN2_HI = 6.93147180369123816490e-01
LN2_LO = 1.90821492927058770002e-10
INV_LN2 = 1.44269504088896338700e00
SQRT_HALF = 0.70710678118654752440
HALF_PI = 1.57079632679489661923
#: 2⁻⁵²: uniforms are (n + ½) · 2⁻⁵² for a 52-bit integer n, exact in float64, in (0, 1),
#: and so is 1 − u.
UNIFORM_STEP = 2.0**-52


def log_mantissa(m):
    """ln m for m in [√½, √2): ``2 atanh(s)``, s = (m − 1)/(m + 1), |s| ≤ 0.172.

    The series ``2 Σ s^(2i+1)/(2i+1)`` to i = 11 leaves < 1e-18 relative error.
    """
    s = (m - 1.0) / (m + 1.0)
    z = s * s
    p = 1.0 / 23.0
    p = p * z + 1.0 / 21.0
    p = p * z + 1.0 / 19.0
    p = p * z + 1.0 / 17.0
    p = p * z + 1.0 / 15.0
    p = p * z + 1.0 / 13.0
    p = p * z + 1.0 / 11.0
    p = p * z + 1.0 / 9.0
    p = p * z + 1.0 / 7.0
    p = p * z + 1.0 / 5.0
    p = p * z + 1.0 / 3.0
    p = p * z + 1.0
    return 2.0 * s * p


def log_combine(log_m, e):
    """ln(m · 2^e) from ln m (:func:`log_mantissa`) and the exponent e."""
    return e * LN2_HI + (log_m + e * LN2_LO)


def exp_reduced(r):
    """eʳ for |r| ≤ ln2/2 (Taylor to r¹⁴/14!, < 1e-18 relative error)."""
    p = 1.0 / 87178291200.0
    p = p * r + 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    return p * r + 1.0


def exp_reduce(x, k):
    """The remainder r = x − k ln2 for k = round(x / ln2), in two exact-ish steps."""
    return (x - k * LN2_HI) - k * LN2_LO


def cos_reduced(a):
    """cos a for a in [0, π/2] (Taylor in a² to a²²/22!, < 1e-17 absolute error)."""
    z = a * a
    p = 1.0 / 1124000727777607680000.0
    p = -p * z + 1.0 / 2432902008176640000.0
    p = -p * z + 1.0 / 6402373705728000.0
    p = -p * z + 1.0 / 20922789888000.0
    p = -p * z + 1.0 / 87178291200.0
    p = -p * z + 1.0 / 479001600.0
    p = -p * z + 1.0 / 3628800.0
    p = -p * z + 1.0 / 40320.0
    p = -p * z + 1.0 / 720.0
    p = -p * z + 1.0 / 24.0
    p = -p * z + 0.5
    return -p * z + 1.0


def sin_reduced(a):
    """sin a for a in [0, π/2] (Taylor to a²³/23!, < 1e-17 absolute error)."""
    z = a * a
    p = 1.0 / 25852016738884976640000.0
    p = -p * z + 1.0 / 51090942171709440000.0
    p = -p * z + 1.0 / 121645100408832000.0
    p = -p * z + 1.0 / 355687428096000.0
    p = -p * z + 1.0 / 1307674368000.0
    p = -p * z + 1.0 / 6227020800.0
    p = -p * z + 1.0 / 39916800.0
    p = -p * z + 1.0 / 362880.0
    p = -p * z + 1.0 / 5040.0
    p = -p * z + 1.0 / 120.0
    p = -p * z + 1.0 / 6.0
    return (-p * z + 1.0) * a


#: ln k! for k = 0 … 255 (float64, from the C library's lgamma once, at import);
#: a table, so both backends read the same bits. Beyond it: Stirling's series.
LOG_FACTORIAL = tuple(math.lgamma(k + 1.0) for k in range(256))
HALF_LOG_2PI = 0.91893853320467274178


def stirling_tail(k1, log_k1):
    """ln k! for k ≥ 256 from k1 = k + 1 and ln k1 (error < 1e-19 relative)."""
    inv = 1.0 / k1
    inv2 = inv * inv
    series = inv * (1.0 / 12.0 - inv2 * (1.0 / 360.0 - inv2 * (1.0 / 1260.0)))
    return (k1 - 0.5) * log_k1 - k1 + HALF_LOG_2PI + series
