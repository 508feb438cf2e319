"""Philox4x32-10 and the noise draws made from it, compiled: the engine's backend of
:mod:`rawsim.noise.reference` (the torch reference), bit-equal to it.

Scalar functions for use inside the engine's kernels. Words are uint64 holding
32-bit values; every constant is typed so numba never mixes signed and
unsigned integers (which would turn them into floats).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit
from numba.core import types
from numba.extending import intrinsic, overload

from rawsim.noise.exact_math import (
    HALF_PI,
    INV_LN2,
    LOGISTIC_LAMBDA,
    SQRT_HALF,
    TUKEY_FRACTION_BITS,
    TUKEY_OCTAVES,
    TUKEY_SEGMENTS,
    TUKEY_TOP_EXPONENT,
    UNIFORM_STEP,
    cos_reduced,
    cubic,
    cubic_through_thirds,
    exp_reduce,
    exp_reduced,
    horner,
    log_combine,
    log_mantissa,
    sin_reduced,
)
from rawsim.noise.philox import (
    PHILOX_M0,
    PHILOX_M1,
    PHILOX_W0,
    PHILOX_W1,
    STREAMS,
    split_key,
)
from rawsim.noise.poisson_table import BUCKETS, COUNT_BITS, LOW_BITS, RESIDUAL_TERMS, poisson_table

_MASK = np.uint64(0xFFFFFFFF)
_M0, _M1 = np.uint64(PHILOX_M0), np.uint64(PHILOX_M1)
_W0, _W1 = np.uint64(PHILOX_W0), np.uint64(PHILOX_W1)
_S32, _S20, _S12 = np.uint64(32), np.uint64(20), np.uint64(12)
NORMAL, TUKEY, POISSON, ROW = (np.uint64(STREAMS[k]) for k in ("normal", "tukey", "poisson", "row"))


@overload(horner)
def _horner(x, coefficients):
    """Compiled calls of :func:`rawsim.noise.exact_math.horner` run that same function."""
    return horner


_log_mantissa = njit(inline="always")(log_mantissa)
_log_combine = njit(inline="always")(log_combine)
_exp_reduced = njit(inline="always")(exp_reduced)
_exp_reduce = njit(inline="always")(exp_reduce)
_cos_reduced = njit(inline="always")(cos_reduced)
_sin_reduced = njit(inline="always")(sin_reduced)
_cubic = njit(inline="always")(cubic)
_cubic_through_thirds = njit(inline="always")(cubic_through_thirds)


def np_key(seed: int) -> tuple[np.uint64, np.uint64]:
    """A 64-bit seed → the two Philox key words, typed for the kernels."""
    k0, k1 = split_key(seed)
    return np.uint64(k0), np.uint64(k1)


@njit(inline="always")
def philox4x32(c0, c1, c2, c3, k0, k1):
    """Philox4x32-10 of uint64 words holding 32-bit values; returns four such words."""
    for round_ in range(10):
        if round_:
            k0 = (k0 + _W0) & _MASK
            k1 = (k1 + _W1) & _MASK
        p0 = _M0 * c0
        p1 = _M1 * c2
        c0, c1, c2, c3 = ((p1 >> _S32) ^ c1 ^ k0, p1 & _MASK, (p0 >> _S32) ^ c3 ^ k1, p0 & _MASK)
    return c0, c1, c2, c3


@intrinsic
def _bits(typingctx, x):
    """The IEEE 754 bits of a float64, as a uint64 (a bit cast: one register move)."""
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.uint64(types.float64), codegen


@intrinsic
def _float(typingctx, b):
    """The float64 whose IEEE 754 bits are the uint64 ``b`` (a bit cast)."""
    if b != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.uint64), codegen


# Integer ↔ float conversions by bit patterns: AVX2 has no vector instruction for
# int64 ↔ float64, so LLVM would run them one lane at a time; these are exact.
_TWO52_BITS = np.uint64(0x4330000000000000)  # 2⁵²: its low mantissa bits hold n < 2⁵²
_TWO52 = 2.0**52
_ROUND_BITS = np.uint64(0x4338000000000000)  # 1.5·2⁵²: holds a small signed integer
_ROUND = 1.5 * 2.0**52
_FRACTION = np.uint64(0x000FFFFFFFFFFFFF)
_HALF_EXPONENT = np.uint64(0x3FE0000000000000)  # exponent field of [½, 1)
_EXPONENT_BIAS = np.uint64(1023)
_S52 = np.uint64(52)


@njit(inline="always")
def _small_int_to_float(n):
    """A uint64 holding a signed integer |n| < 2⁵¹ (two's complement) → that float64."""
    return _float(_ROUND_BITS + n) - _ROUND


@njit(inline="always")
def _uniform(a, b):
    n = (a << _S20) | (b >> _S12)  # n < 2⁵²: 2⁵² + n is exact, and so is subtracting 2⁵²
    return ((_float(_TWO52_BITS | n) - _TWO52) + 0.5) * UNIFORM_STEP


@njit(inline="always")
def uniforms(index, stream, k0, k1, iteration):
    """Two uniforms in (0, 1) for a site ``index`` (uint64), as the reference draws them."""
    w0, w1, w2, w3 = philox4x32(index & _MASK, index >> _S32, stream, iteration, k0, k1)
    return _uniform(w0, w1), _uniform(w2, w3)


@njit(inline="always")
def exact_log(x):
    """ln x for a positive normal float64, the reference's bits, without branches.

    The mantissa m in [½, 1) and exponent e are read from the bits (``frexp``'s),
    then m is doubled below √½, as the reference does.
    """
    b = _bits(x)
    e = _small_int_to_float((b >> _S52) - np.uint64(1022))
    m = _float((b & _FRACTION) | _HALF_EXPONENT)
    low = m < SQRT_HALF
    m = m * 2.0 if low else m
    e = e - 1.0 if low else e
    return _log_combine(_log_mantissa(m), e)


@njit(inline="always")
def exact_exp(x):
    """eˣ for |x| < 700, the reference's bits: 2ᵏ · e^r, 2ᵏ built from its bits."""
    k = math.floor(x * INV_LN2 + 0.5)
    k_bits = _bits(k + _ROUND) - _ROUND_BITS  # k as a two's-complement uint64
    return _exp_reduced(_exp_reduce(x, k)) * _float((k_bits + _EXPONENT_BIAS) << _S52)


@njit(inline="always")
def exact_cos_and_sin_2pi(u):
    """(cos 2π u, sin 2π u) for u in [0, 1): the reference's bits, both quadrant
    polynomials computed and the quadrant's pair selected (no branch)."""
    quarter = math.floor(u * 4.0)
    a = (u * 4.0 - quarter) * HALF_PI
    c, s = _cos_reduced(a), _sin_reduced(a)
    odd_quarter = (quarter == 1.0) | (quarter == 3.0)
    cos, sin = (s, c) if odd_quarter else (c, s)
    cos = -cos if (quarter == 1.0) | (quarter == 2.0) else cos
    sin = -sin if (quarter == 2.0) | (quarter == 3.0) else sin
    return cos, sin


@njit(inline="always")
def exact_cos_sin_2pi(u, sine):
    """cos(2π u), or sin(2π u) if ``sine``, for u in [0, 1)."""
    cos, sin = exact_cos_and_sin_2pi(u)
    return sin if sine else cos


@njit(inline="always")
def normal(index, stream, k0, k1):
    """A standard normal draw: Box–Muller, both branches (sites 2i and 2i + 1 share
    block i; cosine for the even site, sine for the odd)."""
    u1, u2 = uniforms(index >> np.uint64(1), stream, k0, k1, np.uint64(0))
    sine = (index & np.uint64(1)) == np.uint64(1)
    return math.sqrt(-2.0 * exact_log(u1)) * exact_cos_sin_2pi(u2, sine)


@njit(inline="always")
def tukey_quantile(u, lam):
    """The standard Tukey-lambda quantile ``(u^λ − (1 − u)^λ) / λ`` of u in (0, 1)
    (the logistic ``ln u − ln(1 − u)`` for |λ| ≈ 0), from exact logs and exps."""
    lo = exact_log(u)
    hi = exact_log(1.0 - u)
    if abs(lam) < LOGISTIC_LAMBDA:
        return lo - hi
    return (exact_exp(lo * lam) - exact_exp(hi * lam)) / lam


@njit(error_model="numpy", cache=True)
def tukey_table(lam):
    """(TUKEY_OCTAVES · TUKEY_SEGMENTS, 4) coefficients of the cubic through
    :func:`tukey_quantile` at the thirds of each segment of v in [2⁻⁵³, ½)
    (the layout is :data:`rawsim.noise.exact_math.TUKEY_OCTAVES`'s)."""
    table = np.empty((TUKEY_OCTAVES * TUKEY_SEGMENTS, 4))
    octave = 0.25
    for j in range(TUKEY_OCTAVES):
        h = octave / TUKEY_SEGMENTS
        for s in range(TUKEY_SEGMENTS):
            start = octave + s * h
            f0 = tukey_quantile(start, lam)
            f1 = tukey_quantile(start + h / 3.0, lam)
            f2 = tukey_quantile(start + (2.0 * h) / 3.0, lam)
            f3 = tukey_quantile(start + h, lam)
            c = _cubic_through_thirds(f0, f1, f2, f3)
            row = j * TUKEY_SEGMENTS + s
            table[row, 0], table[row, 1], table[row, 2], table[row, 3] = c
        octave *= 0.5
    return table


_OCTAVE_TOP = np.uint64(TUKEY_TOP_EXPONENT)
_SEGMENT_MASK = np.uint64(TUKEY_SEGMENTS - 1)
_FRACTION_SHIFT = np.uint64(TUKEY_FRACTION_BITS)
_FRACTION_MASK = np.uint64((1 << TUKEY_FRACTION_BITS) - 1)
_FRACTION_STEP = 2.0**-TUKEY_FRACTION_BITS


@njit(inline="always")
def _tukey_segment(u):
    """The table row of a uniform u in (0, 1) and the position t in [0, 1) within its
    segment; the row is doubled, its lowest bit set above ½, where
    Q(u) = −Q(1 − u) (1 − u is exact there)."""
    upper = np.uint64(u > 0.5)
    b = _bits(1.0 - u) if upper else _bits(u)
    row = (_OCTAVE_TOP - (b >> _S52)) * np.uint64(TUKEY_SEGMENTS) + (
        (b >> _FRACTION_SHIFT) & _SEGMENT_MASK
    )
    t = (_float(_TWO52_BITS | (b & _FRACTION_MASK)) - _TWO52) * _FRACTION_STEP
    return (row << np.uint64(1)) | upper, t


@njit(inline="always")
def _tukey_cubic(segment, t, table):
    """The quantile from :func:`_tukey_segment`'s (segment, t): the row's cubic at t,
    negated above ½."""
    i = np.intp(segment >> np.uint64(1))
    q = _cubic(t, table[i, 0], table[i, 1], table[i, 2], table[i, 3])
    return -q if segment & np.uint64(1) else q


@njit(inline="always")
def tukey_from_table(u, table):
    """The Tukey-lambda quantile of a uniform u in (0, 1) from :func:`tukey_table`."""
    segment, t = _tukey_segment(u)
    return _tukey_cubic(segment, t, table)


@njit(inline="always")
def tukey_lambda(index, k0, k1, table):
    """A standard Tukey-lambda draw by inverse transform, through ``table``
    (:func:`tukey_table` of λ): sites 2i and 2i + 1 take the two uniforms of block i."""
    u1, u2 = uniforms(index >> np.uint64(1), TUKEY, k0, k1, np.uint64(0))
    return tukey_from_table(u2 if index & np.uint64(1) else u1, table)


@njit(error_model="numpy")
def normal_row(first, k0, k1, out):
    """:func:`normal` of sites ``first``, ``first + 1``, … into ``out`` (n,), in two
    branch-free loops over the row's blocks (each block gives two sites), which
    LLVM vectorises: the uniforms, then Box–Muller. One loop doing both ran 30 %
    slower (2.2 against 1.7 ns a site on one core): LLVM vectorises each part
    better alone."""
    start = int(first & np.uint64(1))  # an odd first site is its block's second
    pairs = (out.size + start + 1) // 2
    whole = start == 0 and out.size == 2 * pairs  # whole blocks: written in place
    both = out if whole else np.empty(2 * pairs)
    block = first >> np.uint64(1)
    u = np.empty((2, pairs))
    for q in range(pairs):
        u[0, q], u[1, q] = uniforms(block + np.uint64(q), NORMAL, k0, k1, np.uint64(0))
    for q in range(pairs):
        r = math.sqrt(-2.0 * exact_log(u[0, q]))
        cos, sin = exact_cos_and_sin_2pi(u[1, q])
        both[2 * q] = r * cos
        both[2 * q + 1] = r * sin
    if not whole:
        for k in range(out.size):  # a loop: a slice assignment compiles seconds longer
            out[k] = both[start + k]


@njit(error_model="numpy")
def tukey_lambda_row(first, k0, k1, table, out):
    """:func:`tukey_lambda` of sites ``first``, ``first + 1``, … into ``out`` (n,), in
    three loops: each block's two uniforms, then their segments
    (:func:`_tukey_segment`), which LLVM vectorises (apart, as in :func:`normal_row`);
    then the table reads and cubics, a site at a time (one loop vectorised
    neither, 4–6× slower)."""
    start = int(first & np.uint64(1))  # an odd first site is its block's second
    pairs = (out.size + start + 1) // 2
    segment, t = np.empty(2 * pairs, np.uint64), np.empty(2 * pairs)
    block = first >> np.uint64(1)
    for q in range(pairs):
        t[2 * q], t[2 * q + 1] = uniforms(block + np.uint64(q), TUKEY, k0, k1, np.uint64(0))
    for x in range(2 * pairs):
        segment[x], t[x] = _tukey_segment(t[x])
    for x in range(out.size):
        out[x] = _tukey_cubic(segment[start + x], t[start + x], table)


def poisson_words() -> np.ndarray:
    """:func:`rawsim.noise.poisson_table.poisson_table` as the kernels take it: the same
    words, viewed as uint64."""
    return poisson_table().view(np.uint64)


@njit(inline="always")
def _poisson_block(index, k0, k1):
    """A Poisson draw's block: its 52-bit uniform integer A (for the alias table)
    and a uniform u in (0, 1) (for the residual search)."""
    w0, w1, w2, w3 = philox4x32(index & _MASK, index >> _S32, POISSON, np.uint64(0), k0, k1)
    return (w0 << _S20) | (w1 >> _S12), _uniform(w2, w3)


@njit(inline="always")
def _poisson_residual(delta, u, terms):
    """Poisson(δ) of δ in [0, 1) at the uniform u, searched over its first ``terms``
    terms (branch-free): (the number of counts k ≥ 1 with u > F(k − 1) and
    P(k) > 0, whether u ≤ F(terms) — the search over :data:`RESIDUAL_TERMS` terms
    would find no more)."""
    p = exact_exp(-delta)
    cdf = p
    count = 0.0
    for k in range(1, terms + 1):
        p = p * delta / k
        count += (u > cdf) & (p > 0.0)
        cdf = cdf + p
    return count, u <= cdf


_BUCKETS = np.uint64(BUCKETS)
_LOW_BITS = np.uint64(LOW_BITS)
_LOW_MASK = np.uint64((1 << LOW_BITS) - 1)
_COUNT_MASK = np.uint64((1 << COUNT_BITS) - 1)
_ALIAS_SHIFT = np.uint64(LOW_BITS + COUNT_BITS)


@njit(inline="always")
def _poisson_table(m, a, table):
    """Poisson(m) of an integer mean m (uint64) from its alias table, at A = ``a``:
    bucket A >> 44, its own count if A's low 44 bits are below its threshold."""
    word = table[m * _BUCKETS + (a >> _LOW_BITS)]
    own = (a & _LOW_MASK) < (word & _LOW_MASK)
    count = (word >> _LOW_BITS) & _COUNT_MASK if own else word >> _ALIAS_SHIFT
    return _float(_TWO52_BITS | count) - _TWO52


@njit(inline="always")
def _mean_floor(lam):
    """(⌊λ⌋ as a uint64 table index, λ − ⌊λ⌋) of 0 ≤ λ < 2⁵², exactly."""
    m = math.floor(lam)
    return _bits(m + _TWO52) - _TWO52_BITS, lam - m


@njit(error_model="numpy")
def poisson(lam, index, k0, k1, table):
    """An exact Poisson draw of mean ``lam`` in [0, POISSON_MEANS) (a float count),
    with ``table`` from :func:`poisson_words`: Poisson(⌊λ⌋) from its alias table
    plus Poisson(λ − ⌊λ⌋) by inversion (see :mod:`rawsim.noise.poisson_table`)."""
    a, u = _poisson_block(index, k0, k1)
    m, delta = _mean_floor(lam)
    return _poisson_residual(delta, u, RESIDUAL_TERMS)[0] + _poisson_table(m, a, table)


#: Terms of the residual search that :func:`poisson_sites` runs for every site:
#: they reach u for all but P(Poisson(δ) ≥ 5) < 0.4 % of draws.
_FIRST_TERMS = 4


@njit(error_model="numpy")
def poisson_sites(lam, sites, k0, k1, table, out):
    """:func:`poisson` of means ``lam`` (n,) at ``sites`` (n,) uint64 into ``out`` (n,),
    bit for bit. The blocks, then the residual counts' first :data:`_FIRST_TERMS`
    terms, run in loops that LLVM vectorises (apart, as in :func:`normal_row`); the
    table lookups, and the full search where those terms did not reach u (< 0.4 %
    of draws), one site at a time."""
    n = lam.size
    a = np.empty(n, np.uint64)
    for i in range(n):
        a[i], out[i] = _poisson_block(sites[i], k0, k1)
    for i in range(n):
        _, delta = _mean_floor(lam[i])
        count, done = _poisson_residual(delta, out[i], _FIRST_TERMS)
        out[i] = count if done else -1.0
    for i in range(n):
        m, delta = _mean_floor(lam[i])
        if out[i] < 0.0:
            _, u = _poisson_block(sites[i], k0, k1)
            out[i] = _poisson_residual(delta, u, RESIDUAL_TERMS)[0]
        out[i] += _poisson_table(m, a[i], table)
