"""Elementary functions built from +, −, ×, ÷ alone, shared by every backend.

The noise generator must give the same bits in the torch reference (any device)
and in the compiled engine. IEEE 754 makes +, −, ×, ÷ and √ correctly rounded,
but ``log``, ``exp`` and ``cos`` come from different libraries (libm, SLEEF,
CUDA's) that disagree in the last bit. So the noise transforms use these
polynomials instead (:func:`horner`): each is written once, with operators only, and is called
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
#: |λ| below this is the Tukey-lambda law's λ → 0 limit, the logistic law.
LOGISTIC_LAMBDA = 1e-6
#: 2⁻⁵²: uniforms are (n + ½) · 2⁻⁵² for a 52-bit integer n, exact in float64, in (0, 1),
#: and so is 1 − u.
UNIFORM_STEP = 2.0**-52


#: Horner coefficients, highest order first. Each is one correctly rounded
#: division, as a literal ``1.0 / n`` would be; the signs of the sine and cosine
#: series are folded into their coefficients (a negation is exact).
_ATANH = tuple(1.0 / (2 * i + 1) for i in range(11, -1, -1))
_EXP = tuple(1.0 / math.factorial(n) for n in range(14, -1, -1))
_COS = tuple((-1.0) ** n / math.factorial(2 * n) for n in range(11, -1, -1))
_SIN = tuple((-1.0) ** n / math.factorial(2 * n + 1) for n in range(11, -1, -1))


def horner(x, coefficients):
    """Σ cᵢ xⁱ by Horner's rule, highest order first: one multiply and one add a step.

    Starts from 0, whose first step gives the leading coefficient exactly. The
    engine compiles this same function (:mod:`rawsim.noise.kernels`).
    """
    p = 0.0
    for c in coefficients:
        p = p * x + c
    return p


def log_mantissa(m):
    """ln m for m in [√½, √2): ``2 atanh(s)``, s = (m − 1)/(m + 1), |s| ≤ 0.172.

    The series ``2 Σ s^(2i+1)/(2i+1)`` to i = 11 leaves < 1e-18 relative error.
    """
    s = (m - 1.0) / (m + 1.0)
    return 2.0 * s * horner(s * s, _ATANH)


def log_combine(log_m, e):
    """ln(m · 2^e) from ln m (:func:`log_mantissa`) and the exponent e."""
    return e * LN2_HI + (log_m + e * LN2_LO)


def exp_reduced(r):
    """eʳ for |r| ≤ ln2/2 (Taylor to r¹⁴/14!, < 1e-18 relative error)."""
    return horner(r, _EXP)


def exp_reduce(x, k):
    """The remainder r = x − k ln2 for k = round(x / ln2), in two exact-ish steps."""
    return (x - k * LN2_HI) - k * LN2_LO


def cos_reduced(a):
    """cos a for a in [0, π/2] (Taylor in a² to a²²/22!, < 1e-17 absolute error)."""
    return horner(a * a, _COS)


def sin_reduced(a):
    """sin a for a in [0, π/2] (Taylor to a²³/23!, < 1e-17 absolute error)."""
    return horner(a * a, _SIN) * a


#: The Tukey-lambda quantile Q(v) for v in [2⁻⁵³, ½) (every uniform's distance from its
#: nearer end) is a table of cubics: octave j holds v in [2⁻ʲ⁻², 2⁻ʲ⁻¹), cut into
#: :data:`TUKEY_SEGMENTS` equal segments. A segment is found from v's bits (exponent
#: and top mantissa bits) and its cubic evaluated at the rest of the mantissa, so a
#: draw costs a table read and three multiply-adds instead of two logarithms and two
#: exponentials. Within an octave v^λ is self-similar, so the cubic's error is the
#: same small fraction of Q everywhere (< 1e-11 relative for |λ| ≤ 1).
TUKEY_OCTAVES = 52
TUKEY_SEGMENTS = 256
#: The biased float64 exponent of octave 0, [¼, ½); octave j has this less j.
TUKEY_TOP_EXPONENT = 1021
#: The mantissa bits below the top 8 (log2 of :data:`TUKEY_SEGMENTS`), which pick the segment.
TUKEY_FRACTION_BITS = 44


def cubic_through_thirds(f0, f1, f2, f3):
    """Coefficients (c0, c1, c2, c3) of the cubic c0 + c1 t + c2 t² + c3 t³ through
    the values ``f0 … f3`` at t = 0, ⅓, ⅔, 1 (Lagrange, in monomial form)."""
    c1 = (((-11.0 * f0 + 18.0 * f1) - 9.0 * f2) + 2.0 * f3) * 0.5
    c2 = (((18.0 * f0 - 45.0 * f1) + 36.0 * f2) - 9.0 * f3) * 0.5
    c3 = (((-9.0 * f0 + 27.0 * f1) - 27.0 * f2) + 9.0 * f3) * 0.5
    return f0, c1, c2, c3


def cubic(t, c0, c1, c2, c3):
    """The cubic of :func:`cubic_through_thirds`'s coefficients at t, by Horner."""
    return ((c3 * t + c2) * t + c1) * t + c0
