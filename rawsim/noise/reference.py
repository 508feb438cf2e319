"""Counter-based random numbers (Philox4x32-10) and the noise draws made from them:
the torch reference, for any device.

Every draw is a pure function of (key, site, stream, iteration): the key is the
file's 64-bit seed, the site its pixel index ``y · W + x`` (or the row index for
row noise), the stream names what is drawn (:data:`STREAMS`), the iteration
tells repeated draws of one site apart (an event stream's steps). So the noise
of a pixel does not depend on how the image is split into strips, threads, jobs
or batches, nor on the device or the backend: :mod:`rawsim.noise.kernels`
is the same generator compiled with numba, and the two are tested bit-equal.

Philox4x32-10 is Salmon et al., "Parallel random numbers: as easy as 1, 2, 3"
(SC 2011): ten rounds of two 32×32→64-bit multiplies and a Weyl key schedule.
Integers are carried in int64 tensors (torch has no full uint32 arithmetic);
products are split in 16-bit halves so nothing overflows.

Distributions, each from :mod:`rawsim.noise.exact_math` so the bits match:

* uniform: ``(n + ½) · 2⁻⁵²`` from 52 bits of two words, in (0, 1) exactly;
* normal: Box–Muller, both branches, from one block (two uniforms) per two sites;
* Tukey-lambda: inverse transform of one uniform per site (two sites per block),
  the quantile read from a per-λ table of cubics (:func:`tukey_table`);
* Poisson: exact, for means below :data:`~rawsim.noise.poisson_table.POISSON_MEANS`:
  Poisson(⌊λ⌋) from Walker's alias table of that integer mean plus Poisson(λ − ⌊λ⌋)
  by a short inverse-CDF search, from one block per site
  (:mod:`rawsim.noise.poisson_table`).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

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
    log_combine,
    log_mantissa,
    sin_reduced,
)
from rawsim.noise.philox import (  # noqa: F401 - the generator's constants, also from here
    MASK32,
    PHILOX_M0,
    PHILOX_M1,
    PHILOX_W0,
    PHILOX_W1,
    STREAMS,
    split_key,
)
from rawsim.noise.poisson_table import BUCKETS, COUNT_BITS, LOW_BITS, RESIDUAL_TERMS, poisson_table


def _mulhilo(m: int, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(hi, lo) 32-bit words of ``m · c`` for m, c < 2³², in int64 without overflow."""
    a = c.bitwise_right_shift(16).mul(m)  # < 2⁴⁸
    b = c.bitwise_and(0xFFFF).mul(m)  # < 2⁴⁸
    mid = a.bitwise_and(0xFFFF).bitwise_left_shift(16).add_(b)  # < 2⁴⁹
    lo = mid.bitwise_and(MASK32)
    hi = a.bitwise_right_shift(16).add_(mid.bitwise_right_shift(32)).bitwise_and_(MASK32)
    return hi, lo


def philox4x32(counter: tuple, key: tuple[int, int]) -> tuple[torch.Tensor, ...]:
    """Philox4x32-10 of int64 tensors (or ints) holding 32-bit counter words.

    Returns the four output words, int64 tensors in [0, 2³²).
    """
    ref = next(c for c in counter if isinstance(c, torch.Tensor))
    c0, c1, c2, c3 = (torch.as_tensor(c, dtype=torch.int64, device=ref.device) for c in counter)
    c0, c1, c2, c3 = torch.broadcast_tensors(c0, c1, c2, c3)
    k0, k1 = key
    for round_ in range(10):
        if round_:
            k0, k1 = (k0 + PHILOX_W0) & MASK32, (k1 + PHILOX_W1) & MASK32
        hi0, lo0 = _mulhilo(PHILOX_M0, c0)
        hi1, lo1 = _mulhilo(PHILOX_M1, c2)
        c0, c1, c2, c3 = (
            hi1.bitwise_xor_(c1).bitwise_xor_(k0),
            lo1,
            hi0.bitwise_xor_(c3).bitwise_xor_(k1),
            lo0,
        )
    return c0, c1, c2, c3


def _uniform(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Two 32-bit words → float64 uniform ``(n + ½) · 2⁻⁵²`` with n their top 52 bits."""
    n = a.bitwise_left_shift(20).bitwise_or_(b.bitwise_right_shift(12))
    return (n.double() + 0.5) * UNIFORM_STEP


def uniforms(index: torch.Tensor, stream: str, key, iteration=0) -> tuple[torch.Tensor, ...]:
    """Two independent uniforms in (0, 1) (float64) per ``index`` (int64, ≥ 0)."""
    w = philox4x32(
        (index.bitwise_and(MASK32), index.bitwise_right_shift(32), STREAMS[stream], iteration), key
    )
    return _uniform(w[0], w[1]), _uniform(w[2], w[3])


def exact_log(x: torch.Tensor) -> torch.Tensor:
    """ln x for float64 x > 0, the same bits as the engine's (:mod:`rawsim.noise.exact_math`)."""
    m, e = torch.frexp(x)
    low = m < SQRT_HALF
    m = torch.where(low, m * 2.0, m)
    e = (e - low.to(e.dtype)).double()
    return log_combine(log_mantissa(m), e)


def exact_exp(x: torch.Tensor) -> torch.Tensor:
    """eˣ for float64 x (|x| < 700), the same bits as the engine's."""
    k = torch.floor(x * INV_LN2 + 0.5)
    return torch.ldexp(exp_reduced(exp_reduce(x, k)), k.to(torch.int32))


def ieee_sqrt(x: torch.Tensor) -> torch.Tensor:
    """√x correctly rounded, as IEEE 754 and the engine's ``math.sqrt`` give it.

    torch's vectorised float64 ``sqrt`` on the CPU is off by one ulp for about 1 %
    of values; numpy's uses the hardware instruction. CUDA's double ``sqrt`` is
    correctly rounded.
    """
    if x.device.type == "cpu":
        return torch.from_numpy(np.sqrt(x.detach().numpy()))
    return torch.sqrt(x)


def exact_cos_sin_2pi(u: torch.Tensor, sine: torch.Tensor) -> torch.Tensor:
    """cos(2π u), or sin(2π u) where ``sine`` (bool), for u in [0, 1): by quadrant (an
    exact reduction) and :func:`cos_reduced` / :func:`sin_reduced`.

    In quadrant q, cos(2πu) is c, −s, −c, s and sin(2πu) is s, c, −s, −c.
    """
    quarter = torch.floor(u * 4.0)
    a = (u * 4.0 - quarter) * HALF_PI
    c, s = cos_reduced(a), sin_reduced(a)
    odd_quarter = (quarter == 1.0) | (quarter == 3.0)
    value = torch.where(odd_quarter ^ sine, s, c)
    negative = (quarter == 2.0) | (quarter == torch.where(sine, 3.0, 1.0))
    return torch.where(negative, -value, value)


def normal(index: torch.Tensor, key, stream: str = "normal") -> torch.Tensor:
    """Standard normal draws (float64) by Box–Muller, both branches: the sites 2i and
    2i + 1 share block i, √(−2 ln u₁) times cos(2π u₂) for the even site and
    sin(2π u₂) for the odd one."""
    u1, u2 = uniforms(index.bitwise_right_shift(1), stream, key)
    odd = index.bitwise_and(1).bool()
    return ieee_sqrt(-2.0 * exact_log(u1)) * exact_cos_sin_2pi(u2, odd)


def tukey_quantile(u: torch.Tensor, lam: float) -> torch.Tensor:
    """The standard Tukey-lambda quantile ``(u^λ − (1 − u)^λ) / λ`` of u in (0, 1)
    (float64; the logistic ``ln u − ln(1 − u)`` for |λ| below ``LOGISTIC_LAMBDA``)."""
    lo, hi = exact_log(u), exact_log(1.0 - u)
    if abs(lam) < LOGISTIC_LAMBDA:
        return lo - hi
    return (exact_exp(lo * lam) - exact_exp(hi * lam)) / lam


@functools.lru_cache(maxsize=8)
def tukey_table(lam: float, device=None) -> torch.Tensor:
    """(TUKEY_OCTAVES · TUKEY_SEGMENTS, 4) float64 coefficients of the cubic through
    :func:`tukey_quantile` at the thirds of each segment of v in [2⁻⁵³, ½): octave j
    is [2⁻ʲ⁻², 2⁻ʲ⁻¹) in equal segments (:data:`rawsim.noise.exact_math.TUKEY_OCTAVES`).

    Kept for the last few (λ, device): every strip of a sample draws from the same
    table (do not modify it)."""
    octave = torch.ldexp(
        torch.ones(TUKEY_OCTAVES, dtype=torch.float64, device=device),
        -2 - torch.arange(TUKEY_OCTAVES, device=device),
    )[:, None]
    h = octave / TUKEY_SEGMENTS
    start = octave + torch.arange(TUKEY_SEGMENTS, device=device, dtype=torch.float64) * h
    f = [tukey_quantile(start + step, lam) for step in (0.0, h / 3.0, (2.0 * h) / 3.0, h)]
    return torch.stack(cubic_through_thirds(*f), -1).reshape(-1, 4)


def tukey_from_table(u: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
    """The Tukey-lambda quantile of uniforms ``u`` (float64, (0, 1)) from
    :func:`tukey_table`: the segment from the bits of v = min(u, 1 − u), the cubic at
    the remaining mantissa bits, negated above ½ (Q(u) = −Q(1 − u); 1 − u is exact)."""
    upper = u > 0.5
    b = torch.where(upper, 1.0 - u, u).view(torch.int64)
    row = (TUKEY_TOP_EXPONENT - b.bitwise_right_shift(52)) * TUKEY_SEGMENTS + b.bitwise_right_shift(
        TUKEY_FRACTION_BITS
    ).bitwise_and(TUKEY_SEGMENTS - 1)
    t = b.bitwise_and((1 << TUKEY_FRACTION_BITS) - 1).double() * 2.0**-TUKEY_FRACTION_BITS
    c = table[row]
    q = cubic(t, c[..., 0], c[..., 1], c[..., 2], c[..., 3])
    return torch.where(upper, -q, q)


def tukey_lambda(index: torch.Tensor, key, table: torch.Tensor) -> torch.Tensor:
    """Standard Tukey-lambda draws by inverse transform, through ``table``
    (:func:`tukey_table` of λ): the sites 2i and 2i + 1 take the two uniforms of block i."""
    u1, u2 = uniforms(index.bitwise_right_shift(1), "tukey", key)
    return tukey_from_table(torch.where(index.bitwise_and(1).bool(), u2, u1), table)


def poisson(lam: torch.Tensor, index: torch.Tensor, key) -> torch.Tensor:
    """Exact Poisson draws (float64 counts) of means ``lam`` in [0, POISSON_MEANS)
    (float64), one per ``index``: Poisson(⌊λ⌋) from its alias table plus
    Poisson(λ − ⌊λ⌋) by inversion, from block (index, poisson, 0)."""
    table = _poisson_table_on(lam.device)
    w0, w1, w2, w3 = philox4x32(
        (index.bitwise_and(MASK32), index.bitwise_right_shift(32), STREAMS["poisson"], 0), key
    )
    a = w0.bitwise_left_shift(20).bitwise_or_(w1.bitwise_right_shift(12))
    u = _uniform(w2, w3)
    m = torch.floor(lam)
    delta = lam - m
    p = exact_exp(-delta)
    cdf = p.clone()
    residual = torch.zeros_like(lam)
    for k in range(1, RESIDUAL_TERMS + 1):
        p = p * delta / float(k)
        residual += ((u > cdf) & (p > 0.0)).double()
        cdf = cdf + p
    word = table[m.long() * BUCKETS + a.bitwise_right_shift(LOW_BITS)]
    low = (1 << LOW_BITS) - 1
    own = a.bitwise_and(low) < word.bitwise_and(low)
    counts = torch.where(
        own,
        word.bitwise_right_shift(LOW_BITS).bitwise_and((1 << COUNT_BITS) - 1),
        word.bitwise_right_shift(LOW_BITS + COUNT_BITS),
    )
    return residual + counts.double()


@functools.lru_cache(maxsize=4)
def _poisson_table_on(device: torch.device) -> torch.Tensor:
    """:func:`rawsim.noise.poisson_table.poisson_table` on ``device``, copied there once."""
    return torch.from_numpy(poisson_table()).to(device)
