"""The exact unbiased inverse of the generalised Anscombe transform, as a table.

The transform f(z) = 2·√(z + 3/8 + σ²) of z = x / gain (counts, σ² = offset /
gain²) makes Poisson-Gaussian noise nearly Gaussian of σ 1. A denoiser in that
domain estimates E[f(z)], not f(E[z]); the unbiased inverse maps E[f(z)] back to
the mean E[z] (Mäkitalo & Foi, IEEE TIP 20(1) 2011 and 22(1) 2013). Their closed
form approximates it well above a few counts and is biased below (by up to a
tenth of the noise σ at a fraction of a count, measured here). So below
:data:`EXACT_COUNTS` counts the inverse is taken from the exact expectation,

    E[f(z) | λ] = Σ_k Poisson(k; λ) · E_n[2·√max(k + σ·n + 3/8 + σ², 0)],  n ~ N(0, 1),

computed on :data:`POINTS` values of λ (the Gaussian's expectation by the
trapezoid rule over ±:data:`TAILS` σ, where the square root's kink at 0 costs a
Gauss–Hermite rule its accuracy), and above it from the closed form. Between
table points the inverse is linear. Torch-free: the engine and the torch
reference read the same table.
"""

from __future__ import annotations

import functools
import math

import numpy as np

#: Counts (x / gain) below which the exact table is used; above, the closed form.
EXACT_COUNTS = 100.0
#: Table points (denser near 0: λ_i = EXACT_COUNTS · (i / (POINTS − 1))²).
POINTS = 256
#: The Gaussian expectation's range (± this many σ) and its trapezoid points.
TAILS = 7.0
NODES = 281


@functools.lru_cache(maxsize=16)
def inverse_table(gain: float, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """(E[f], x): the transform's expectation at :data:`POINTS` means x (white = 1;
    x = λ · gain), both increasing, float64 (POINTS,). Above the last point
    Mäkitalo & Foi's closed form takes over (in :func:`rawsim.denoise.profiled.
    inverse_vst` and the engine's ``_inverse_vst``)."""
    sigma2 = offset / gain**2
    sigma = math.sqrt(sigma2)
    lam = EXACT_COUNTS * (np.arange(POINTS) / (POINTS - 1)) ** 2
    kmax = int(EXACT_COUNTS + 12 * math.sqrt(EXACT_COUNTS) + 30)
    k = np.arange(kmax + 1, dtype=np.float64)
    n = np.linspace(-TAILS, TAILS, NODES)
    w = np.exp(-0.5 * n * n)
    w[[0, -1]] *= 0.5
    w /= w.sum()
    inner = 2 * np.sqrt(np.maximum(k[:, None] + sigma * n[None] + 0.375 + sigma2, 0.0)) @ w
    with np.errstate(divide="ignore", invalid="ignore"):
        logp = k[None] * np.log(lam[:, None]) - lam[:, None] - _log_factorial(k)[None]
    logp[0] = np.where(k == 0, 0.0, -np.inf)  # λ = 0: all mass at k = 0
    p = np.exp(logp)
    expectation = (p * inner[None]).sum(1) / p.sum(1)
    return np.maximum.accumulate(expectation), lam * gain


def _log_factorial(k: np.ndarray) -> np.ndarray:
    return np.array([math.lgamma(v + 1) for v in k])


def tables(gain, offset) -> tuple[np.ndarray, np.ndarray]:
    """:func:`inverse_table` per colour: (E[f] (3, POINTS), x (3, POINTS)), float32."""
    rows = [inverse_table(float(g), float(o)) for g, o in zip(gain, offset, strict=True)]
    return (
        np.stack([d for d, _ in rows]).astype(np.float32),
        np.stack([x for _, x in rows]).astype(np.float32),
    )
