"""Philox4x32-10 and the noise draws made from it, compiled: the engine's backend of
:mod:`rawsim.counter_rng` (the torch reference), bit-equal to it.

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

from rawsim.exact_math import (
    HALF_PI,
    INV_LN2,
    LOG_FACTORIAL,
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
    stirling_tail,
)
from rawsim.philox import (
    INVERSION_BELOW,
    MAX_ITERATIONS,
    PHILOX_M0,
    PHILOX_M1,
    PHILOX_W0,
    PHILOX_W1,
    STREAMS,
    split_key,
)

_MASK = np.uint64(0xFFFFFFFF)
_M0, _M1 = np.uint64(PHILOX_M0), np.uint64(PHILOX_M1)
_W0, _W1 = np.uint64(PHILOX_W0), np.uint64(PHILOX_W1)
_S32, _S20, _S12 = np.uint64(32), np.uint64(20), np.uint64(12)
NORMAL, TUKEY, POISSON, ROW = (np.uint64(STREAMS[k]) for k in ("normal", "tukey", "poisson", "row"))
_LOG_FACTORIAL = np.array(LOG_FACTORIAL, dtype=np.float64)


@overload(horner)
def _horner(x, coefficients):
    """Compiled calls of :func:`rawsim.exact_math.horner` run that same function."""
    return horner


_log_mantissa = njit(inline="always")(log_mantissa)
_log_combine = njit(inline="always")(log_combine)
_exp_reduced = njit(inline="always")(exp_reduced)
_exp_reduce = njit(inline="always")(exp_reduce)
_cos_reduced = njit(inline="always")(cos_reduced)
_sin_reduced = njit(inline="always")(sin_reduced)
_stirling_tail = njit(inline="always")(stirling_tail)
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
    (the layout is :data:`rawsim.exact_math.TUKEY_OCTAVES`'s)."""
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
_SIGN = np.uint64(1 << 63)


@njit(inline="always")
def tukey_from_table(u, table):
    """The Tukey-lambda quantile of a uniform u in (0, 1) from :func:`tukey_table`:
    Q(u) = −Q(1 − u) above ½ (1 − u is exact there). Branch-free (the side of ½ is
    a bit mask), as a coin-flip branch would be mispredicted half the time."""
    upper = np.uint64(0) - np.uint64(u > 0.5)
    b = (_bits(1.0 - u) & upper) | (_bits(u) & ~upper)
    i = np.intp(
        (_OCTAVE_TOP - (b >> _S52)) * np.uint64(TUKEY_SEGMENTS)
        + ((b >> _FRACTION_SHIFT) & _SEGMENT_MASK)
    )
    t = (_float(_TWO52_BITS | (b & _FRACTION_MASK)) - _TWO52) * _FRACTION_STEP
    q = _cubic(t, table[i, 0], table[i, 1], table[i, 2], table[i, 3])
    return _float(_bits(q) ^ (upper & _SIGN))


@njit(inline="always")
def tukey_lambda(index, k0, k1, table):
    """A standard Tukey-lambda draw by inverse transform, through ``table``
    (:func:`tukey_table` of λ): sites 2i and 2i + 1 take the two uniforms of block i."""
    u1, u2 = uniforms(index >> np.uint64(1), TUKEY, k0, k1, np.uint64(0))
    return tukey_from_table(u2 if index & np.uint64(1) else u1, table)


@njit(error_model="numpy")
def normal_row(first, k0, k1, out):
    """:func:`normal` of sites ``first``, ``first + 1``, … into ``out`` (n,): one
    branch-free loop over the row's blocks, each giving two sites, which LLVM
    vectorises."""
    start = first & np.uint64(1)  # an odd first site is its block's second
    pairs = (out.size + int(start) + 1) // 2
    both = np.empty(2 * pairs)
    block = first >> np.uint64(1)
    for q in range(pairs):
        u1, u2 = uniforms(block + np.uint64(q), NORMAL, k0, k1, np.uint64(0))
        r = math.sqrt(-2.0 * exact_log(u1))
        cos, sin = exact_cos_and_sin_2pi(u2)
        both[2 * q] = r * cos
        both[2 * q + 1] = r * sin
    out[:] = both[int(start) : int(start) + out.size]


@njit(error_model="numpy")
def tukey_lambda_row(first, k0, k1, table, out):
    """:func:`tukey_lambda` of sites ``first``, ``first + 1``, … into ``out`` (n,),
    a block (two sites) at a time."""
    start = first & np.uint64(1)
    pairs = (out.size + int(start) + 1) // 2
    both = np.empty(2 * pairs)
    block = first >> np.uint64(1)
    for q in range(pairs):  # the uniforms first: this loop vectorises, the lookups not
        both[2 * q], both[2 * q + 1] = uniforms(block + np.uint64(q), TUKEY, k0, k1, np.uint64(0))
    _tukey_from_table_inplace(both, table)
    out[:] = both[int(start) : int(start) + out.size]


@njit(error_model="numpy")
def _tukey_from_table_inplace(u, table):
    """:func:`tukey_from_table` of each uniform of ``u`` (n,), in place. A function
    of its own: inlined into the draws' loop, LLVM compiled it 2.5× slower."""
    for x in range(u.size):
        u[x] = tukey_from_table(u[x], table)


@njit(inline="always")
def _log_factorial(k):
    """ln k! of a count k ≥ 0: the table, else Stirling (both computed, one selected)."""
    table = _LOG_FACTORIAL[min(int(k), _LOG_FACTORIAL.shape[0] - 1)]
    k1 = k + 1.0
    return table if k < _LOG_FACTORIAL.shape[0] else _stirling_tail(k1, exact_log(k1))


@njit(inline="always")
def _ptrs_constants(lam):
    """PTRS's (b, a, vr) for mean ``lam`` ≥ 10."""
    b = 0.931 + 2.53 * math.sqrt(lam)
    a = -0.059 + 0.02483 * b
    vr = 0.9277 - 3.6224 / (b - 2.0)
    return b, a, vr


@njit(inline="always")
def _ptrs_candidate(lam, b, a, u, v):
    """PTRS's candidate count from one block (u, v), its |u| margin, and whether the
    squeeze accepts it outright."""
    u = u - 0.5
    us = 0.5 - abs(u)
    k = math.floor((2.0 * a / us + b) * u + lam + 0.43)
    return k, us, us >= 0.07


@njit(inline="always")
def _ptrs_accepts(lam, b, a, k, us, v):
    """PTRS's full acceptance test of candidate ``k`` (after the squeeze failed)."""
    log_inv_alpha = exact_log(1.1239 + 1.1328 / (b - 3.4))
    lhs = exact_log(v) + log_inv_alpha - exact_log(a / (us * us) + b)
    rhs = -lam + k * exact_log(lam) - _log_factorial(max(k, 0.0))
    return (k >= 0.0) & ((us >= 0.013) | (v <= us)) & (lhs <= rhs)


@njit(error_model="numpy")
def poisson(lam, index, k0, k1):
    """An exact Poisson draw of mean ``lam`` ≥ 0 (a float count)."""
    if lam < INVERSION_BELOW:
        u, _ = uniforms(index, POISSON, k0, k1, np.uint64(0))
        p = exact_exp(-lam)
        cdf = p
        k = 0.0
        while u > cdf and k < 1000.0:
            k += 1.0
            p = p * lam / k
            cdf = cdf + p
        return k
    return _ptrs_from(lam, index, k0, k1, 0)


@njit(error_model="numpy")
def _ptrs_from(lam, index, k0, k1, first):
    """PTRS's draw for mean ``lam`` ≥ 10 from its iteration ``first`` on (the earlier
    ones known rejected)."""
    b, a, vr = _ptrs_constants(lam)
    for j in range(first, MAX_ITERATIONS):
        u, v = uniforms(index, POISSON, k0, k1, np.uint64(j))
        k, us, squeeze = _ptrs_candidate(lam, b, a, u, v)
        if (squeeze and v <= vr) or _ptrs_accepts(lam, b, a, k, us, v):
            return k
    return math.floor(lam)


#: The inversion lanes of :func:`poisson_sites` drop their finished lanes this often.
_COMPACT_EVERY = 4


@njit(error_model="numpy")
def poisson_sites(lam, sites, k0, k1, out):
    """:func:`poisson` of means ``lam`` (n,) at ``sites`` (n,) uint64 into ``out`` (n,),
    bit for bit, with the work spread over lanes that LLVM vectorises.

    Inversion (λ < 10) runs all its lanes a step of the search at a time, each
    lane stopping where the scalar search would, and drops finished lanes every
    few steps. PTRS lanes try their first block together; the few the squeeze
    does not accept run the scalar :func:`poisson`.
    """
    n = lam.size
    small, large = np.empty(n, np.intp), np.empty(n, np.intp)
    m = big = 0
    for i in range(n):
        if lam[i] < INVERSION_BELOW:
            small[m] = i
            m += 1
        else:
            large[big] = i
            big += 1
    mean, site = np.empty(big), np.empty(big, np.uint64)
    for j in range(big):
        mean[j], site[j] = lam[large[j]], sites[large[j]]
    first = np.empty(big)
    _ptrs_first(mean, site, k0, k1, first)
    rest = 0
    for j in range(big):
        out[large[j]] = first[j]
        large[rest] = large[j]
        mean[rest], site[rest] = mean[j], site[j]
        rest += first[j] < 0.0
    _ptrs_first_test(mean[:rest], site[:rest], k0, k1, first[:rest])
    for j in range(rest):
        k = first[j]
        out[large[j]] = k if k >= 0.0 else _ptrs_from(mean[j], site[j], k0, k1, 1)
    lane = small[:m].copy()
    mean, site = np.empty(m), np.empty(m, np.uint64)
    for j in range(m):
        mean[j], site[j] = lam[lane[j]], sites[lane[j]]
    u, p, cdf, count = np.empty(m), np.empty(m), np.empty(m), np.zeros(m)
    _inversion_start(mean, site, k0, k1, u, p, cdf)
    k = 0.0
    while m and k < 1000.0:
        k = _inversion_steps(k, mean[:m], u[:m], p[:m], cdf[:m], count[:m])
        kept = 0
        for j in range(m):
            if u[j] > cdf[j] and count[j] < 1000.0:
                lane[kept], mean[kept], u[kept] = lane[j], mean[j], u[j]
                p[kept], cdf[kept], count[kept] = p[j], cdf[j], count[j]
                kept += 1
            else:
                out[lane[j]] = count[j]
        m = kept


@njit(error_model="numpy")
def _ptrs_first(mean, site, k0, k1, out):
    """PTRS's first block for each lane: the count the squeeze accepts, else −1."""
    for j in range(mean.size):
        b, a, vr = _ptrs_constants(mean[j])
        u, v = uniforms(site[j], POISSON, k0, k1, np.uint64(0))
        k, us, squeeze = _ptrs_candidate(mean[j], b, a, u, v)
        out[j] = k if squeeze & (v <= vr) else -1.0


@njit(error_model="numpy")
def _ptrs_first_test(mean, site, k0, k1, out):
    """PTRS's full test of the first block, for lanes the squeeze did not accept:
    the count it accepts, else −1."""
    for j in range(mean.size):
        b, a, _ = _ptrs_constants(mean[j])
        u, v = uniforms(site[j], POISSON, k0, k1, np.uint64(0))
        k, us, _ = _ptrs_candidate(mean[j], b, a, u, v)
        out[j] = k if _ptrs_accepts(mean[j], b, a, k, us, v) else -1.0


@njit(error_model="numpy")
def _inversion_start(mean, site, k0, k1, u, p, cdf):
    """The inversion's uniform and P(0) = e^−λ of each lane."""
    for j in range(mean.size):
        u[j], _ = uniforms(site[j], POISSON, k0, k1, np.uint64(0))
        p[j] = exact_exp(-mean[j])
        cdf[j] = p[j]


@njit(error_model="numpy")
def _inversion_steps(k, mean, u, p, cdf, count):
    """:data:`_COMPACT_EVERY` steps of the search from count ``k``, on lanes still
    below their uniform; returns the new count."""
    for _ in range(_COMPACT_EVERY):
        k += 1.0
        for j in range(mean.size):
            go = (u[j] > cdf[j]) & (k <= 1000.0)
            q = p[j] * mean[j] / k
            p[j] = q if go else p[j]
            cdf[j] = cdf[j] + q if go else cdf[j]
            count[j] = k if go else count[j]
    return k
