"""Alias tables of the Poisson laws of integer means, shared by both backends' exact
Poisson draws (:func:`rawsim.noise.reference.poisson` and its compiled twin).

A draw of mean λ in [0, :data:`POISSON_MEANS`) is Poisson(m) + Poisson(δ), with
m = ⌊λ⌋ and δ = λ − m: independent Poisson counts add, so the sum is exactly
Poisson(λ). Poisson(m) comes from Walker's alias table of m, indexed by a 52-bit
uniform integer A: its top 8 bits pick one of :data:`BUCKETS` buckets, the other
44 are compared with the bucket's threshold; a bucket is one packed 64-bit word,
so a draw reads one word. Poisson(δ), δ < 1, is a short inverse-CDF search.

The tables are built from integer weights: each count's probability rounded to a
multiple of 2⁻⁵² (:func:`poisson_weights`, by ``decimal``, correctly rounded, so
the same on every machine), the weights summing to 2⁵² exactly. The alias
method then reproduces those weights exactly: P(count = k) is the probability
rounded to the resolution of a 52-bit uniform, no coarser than an inverse-CDF
search with the same uniform. Counts whose probability rounds to 0 (below 2⁻⁵³,
the far tails) are not drawn.
"""

from __future__ import annotations

import decimal
from functools import cache

import numpy as np

#: Tables for means 0 … POISSON_MEANS − 1; draws take λ < POISSON_MEANS.
POISSON_MEANS = 100
#: Shot noise is drawn exactly (Poisson) below this many electrons, as one normal above
#: (:mod:`rawsim.noise.models`).
EXACT_POISSON_BELOW = float(POISSON_MEANS)
#: Bits of a draw's uniform integer A (the engine's and the reference's 52-bit uniforms).
UNIFORM_BITS = 52
#: Terms of the residual Poisson(δ) search: P(count > 20 | δ < 1) < 1/21! ≈ 2·10⁻²⁰.
RESIDUAL_TERMS = 20
#: Buckets of each mean's alias table, picked by A's top 8 bits.
BUCKETS = 256
#: A's bits below the bucket's, compared with its threshold; and the shift of the
#: counts packed above the threshold, 8 bits each (every count drawn is < 256).
LOW_BITS = UNIFORM_BITS - 8
COUNT_BITS = 8


def poisson_weights(m: int) -> tuple[int, list[int]]:
    """(first count, weights): Poisson(m)'s probabilities as integers out of 2⁵².

    Each probability e⁻ᵐ mᵏ / k! is computed to 40 significant digits and rounded
    to an integer multiple of 2⁻⁵²; counts outside the returned run weigh 0. The
    rounding residue (a few units) goes to the mode, so the weights sum to 2⁵².
    """
    ctx = decimal.Context(prec=40, rounding=decimal.ROUND_HALF_EVEN)
    scale = decimal.Decimal(2**UNIFORM_BITS)
    mean = decimal.Decimal(m)
    weights = {}
    p = ctx.exp(-mean)  # P(0)
    k = 0
    while True:
        w = int(ctx.multiply(p, scale).to_integral_value(rounding=decimal.ROUND_HALF_EVEN))
        if w:
            weights[k] = w
        elif k > m:  # past the mode and negligible: the rest is smaller still
            break
        k += 1
        p = ctx.divide(ctx.multiply(p, mean), decimal.Decimal(k))
    first, last = min(weights), max(weights)
    run = [weights.get(k, 0) for k in range(first, last + 1)]
    run[m - first] += 2**UNIFORM_BITS - sum(run)
    return first, run


def _alias(weights: list[int]) -> tuple[list[int], list[int]]:
    """Walker's alias table of integer ``weights`` over :data:`BUCKETS` buckets (the
    weights padded with zeros): (thresholds, aliases), bucket j giving entry j when
    A's low bits are below its threshold, else its alias. Exact in integers."""
    capacity = 1 << LOW_BITS
    left = list(weights) + [0] * (BUCKETS - len(weights))
    threshold, alias = [capacity] * BUCKETS, list(range(BUCKETS))
    small = [j for j in range(BUCKETS) if left[j] < capacity]
    large = [j for j in range(BUCKETS) if left[j] > capacity]
    while small and large:
        s, g = small.pop(), large[-1]
        threshold[s], alias[s] = left[s], g
        left[g] -= capacity - left[s]
        if left[g] <= capacity:
            large.pop()
            if left[g] < capacity:
                small.append(g)
    if small or large:  # the weights sum to BUCKETS · capacity, so both empty together
        raise AssertionError("alias table construction did not balance")
    return threshold, alias


@cache
def poisson_table() -> np.ndarray:
    """The alias tables of means 0 … POISSON_MEANS − 1, built once per process:
    (POISSON_MEANS · BUCKETS,) int64, bucket j of mean m at m · BUCKETS + j.

    A bucket packs its threshold (the low :data:`LOW_BITS` bits), the count it
    gives when A's low bits are below the threshold (the next 8 bits) and its
    alias count (the 8 above).
    """
    table = np.empty(POISSON_MEANS * BUCKETS, np.int64)
    for m in range(POISSON_MEANS):
        first, weights = poisson_weights(m)
        if first + len(weights) > 1 << COUNT_BITS:
            raise AssertionError(f"Poisson({m}) draws counts beyond {COUNT_BITS} bits")
        thresholds, alias = _alias(weights)
        for j, threshold in enumerate(thresholds):
            # A full bucket (threshold 2⁴⁴, which the field cannot hold) is its own
            # alias: threshold 0 gives it. A bucket of threshold 0 never gives its own.
            threshold %= 1 << LOW_BITS
            own = first + j if threshold else 0
            table[m * BUCKETS + j] = (
                threshold | own << LOW_BITS | (first + alias[j]) << (LOW_BITS + COUNT_BITS)
            )
    return table
