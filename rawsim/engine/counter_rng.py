"""Philox4x32-10 and the noise draws made from it, compiled: the engine's backend of
:mod:`rawsim.counter_rng` (the torch reference), bit-equal to it.

Scalar functions for use inside the engine's kernels. Words are uint64 holding
32-bit values; every constant is typed so numba never mixes signed and
unsigned integers (which would turn them into floats).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import overload

from rawsim.counter_rng import (
    INVERSION_BELOW,
    MAX_ITERATIONS,
    PHILOX_M0,
    PHILOX_M1,
    PHILOX_W0,
    PHILOX_W1,
    STREAMS,
    split_key,
)
from rawsim.exact_math import (
    HALF_PI,
    INV_LN2,
    LOG_FACTORIAL,
    LOGISTIC_LAMBDA,
    SQRT_HALF,
    UNIFORM_STEP,
    cos_reduced,
    exp_reduce,
    exp_reduced,
    horner,
    log_combine,
    log_mantissa,
    sin_reduced,
    stirling_tail,
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


_log_mantissa = njit(log_mantissa)
_log_combine = njit(log_combine)
_exp_reduced = njit(exp_reduced)
_exp_reduce = njit(exp_reduce)
_cos_reduced = njit(cos_reduced)
_sin_reduced = njit(sin_reduced)
_stirling_tail = njit(stirling_tail)


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


@njit(inline="always")
def _uniform(a, b):
    n = (a << _S20) | (b >> _S12)
    # n < 2⁵²: through int64, whose conversion to float64 is one instruction.
    return (np.float64(np.int64(n)) + 0.5) * UNIFORM_STEP


@njit(inline="always")
def uniforms(index, stream, k0, k1, iteration):
    """Two uniforms in (0, 1) for a site ``index`` (uint64), as the reference draws them."""
    w0, w1, w2, w3 = philox4x32(index & _MASK, index >> _S32, stream, iteration, k0, k1)
    return _uniform(w0, w1), _uniform(w2, w3)


@njit
def exact_log(x):
    m, e = math.frexp(x)
    if m < SQRT_HALF:
        m = m * 2.0
        e -= 1
    return _log_combine(_log_mantissa(m), np.float64(e))


@njit
def exact_exp(x):
    k = math.floor(x * INV_LN2 + 0.5)
    return math.ldexp(_exp_reduced(_exp_reduce(x, k)), int(k))


@njit
def exact_cos_2pi(u):
    quarter = math.floor(u * 4.0)
    a = (u * 4.0 - quarter) * HALF_PI
    if quarter == 0:
        return _cos_reduced(a)
    if quarter == 1:
        return -_sin_reduced(a)
    if quarter == 2:
        return -_cos_reduced(a)
    return _sin_reduced(a)


@njit
def normal(index, stream, k0, k1):
    """A standard normal draw (Box–Muller cosine branch)."""
    u1, u2 = uniforms(index, stream, k0, k1, np.uint64(0))
    return math.sqrt(-2.0 * exact_log(u1)) * exact_cos_2pi(u2)


@njit
def tukey_lambda(index, k0, k1, lam):
    """A standard Tukey-lambda draw by inverse transform (logistic for |λ| ≈ 0)."""
    u, _ = uniforms(index, TUKEY, k0, k1, np.uint64(0))
    lo = exact_log(u)
    hi = exact_log(1.0 - u)
    if abs(lam) < LOGISTIC_LAMBDA:
        return lo - hi
    return (exact_exp(lo * lam) - exact_exp(hi * lam)) / lam


@njit
def _log_factorial(k):
    if k < _LOG_FACTORIAL.shape[0]:
        return _LOG_FACTORIAL[int(k)]
    k1 = k + 1.0
    return _stirling_tail(k1, exact_log(k1))


@njit
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
    slam = math.sqrt(lam)
    loglam = exact_log(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    log_inv_alpha = exact_log(1.1239 + 1.1328 / (b - 3.4))
    vr = 0.9277 - 3.6224 / (b - 2.0)
    for j in range(MAX_ITERATIONS):
        u, v = uniforms(index, POISSON, k0, k1, np.uint64(j))
        u = u - 0.5
        us = 0.5 - abs(u)
        k = math.floor((2.0 * a / us + b) * u + lam + 0.43)
        if us >= 0.07 and v <= vr:
            return k
        if k < 0 or (us < 0.013 and v > us):
            continue
        lhs = exact_log(v) + log_inv_alpha - exact_log(a / (us * us) + b)
        if lhs <= -lam + k * loglam - _log_factorial(k):
            return k
    return math.floor(lam)
