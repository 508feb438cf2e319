"""Sensor noise at a given ISO, in raw digital numbers (DN).

Models (``NOISE_MODELS``):

* ``poisson-gaussian``: ``D = K · Poisson(s / K) + N(0, σ_read²)`` for a clean
  signal ``s`` DN above black and system gain ``K`` (DN/e⁻). The Poisson draw is
  exact below :data:`EXACT_POISSON_BELOW` electrons, where its skew and
  discreteness are visible. Above it the Poisson law is within skewness
  1/√λ < 0.1 (excess kurtosis < 0.01) of a normal one, so shot and read noise
  are drawn together as a single normal of the same variance ``K s + σ_read²``
  (exact sampling of every pixel would be several times slower).
* ``gaussian``: the seed's heteroscedastic model, ``σ_shot = α √s + β``,
  ``g = ISO / ISO_base``, ``σ² = g σ_shot² + g² σ_read²``.
* ``none``: the clean signal.

The output is rounded to integers afterwards (:func:`rawsim.isp.levels.quantize`),
which adds 1/12 DN² of variance; :meth:`NoiseLevels.variance` includes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from rawsim.errors import ParameterError, check_choice

NOISE_MODELS = ("none", "gaussian", "poisson-gaussian")
EXACT_POISSON_BELOW = 100.0
QUANTIZATION_VARIANCE = 1.0 / 12.0


def _interp_loglog(x: float, xs: tuple[float, ...], ys: tuple[float, ...]) -> float:
    """Piecewise-linear interpolation in log-log space, extrapolating the end segments."""
    lx = [math.log(v) for v in xs]
    ly = [math.log(v) for v in ys]
    t = math.log(x)
    i = max(0, min(len(lx) - 2, sum(1 for v in lx[1:-1] if t > v)))
    w = (t - lx[i]) / (lx[i + 1] - lx[i])
    return math.exp(ly[i] + w * (ly[i + 1] - ly[i]))


@dataclass(frozen=True)
class GainCurve:
    """System gain K (DN/e⁻) versus ISO.

    ``linear``: ``K = slope · ISO + intercept``. ``table``: points (``iso``, ``k``)
    interpolated in log-log space (dual-gain sensors break the linear law).
    """

    model: str
    slope: float = 0.0
    intercept: float = 0.0
    iso: tuple[float, ...] = ()
    k: tuple[float, ...] = ()

    def __call__(self, iso: float) -> float:
        if self.model == "linear":
            value = self.slope * iso + self.intercept
        elif self.model == "table":
            value = self.k[0] if len(self.k) == 1 else _interp_loglog(iso, self.iso, self.k)
        else:
            raise ParameterError(f"unknown gain model {self.model!r}; valid: linear, table")
        if not value > 0:
            raise ParameterError(f"system gain K at ISO {iso:g} is {value:g}, not > 0")
        return value


@dataclass(frozen=True)
class SigmaCurve:
    """A noise σ (DN) versus gain or ISO.

    ``loglinear``: ``ln σ = slope · ln K + bias`` (ELD, Wei et al. 2020).
    ``table``: points (``iso``, ``sigma``) interpolated in log-log space.
    """

    model: str
    slope: float = 0.0
    bias: float = 0.0
    iso: tuple[float, ...] = ()
    sigma: tuple[float, ...] = ()

    def __call__(self, iso: float, k: float) -> float:
        if self.model == "loglinear":
            return math.exp(self.slope * math.log(k) + self.bias)
        if self.model == "table":
            return (
                self.sigma[0] if len(self.sigma) == 1 else _interp_loglog(iso, self.iso, self.sigma)
            )
        raise ParameterError(f"unknown sigma model {self.model!r}; valid: loglinear, table")


@dataclass(frozen=True)
class SeedGaussian:
    """The seed's Gaussian noise parameters (DN at ``iso_base``)."""

    iso_base: float
    read_noise_std: float
    shot_noise_std_alpha: float
    shot_noise_std_beta: float = 0.0


@dataclass(frozen=True)
class NoiseSpec:
    """A sensor's noise description: K(ISO) and read σ, and the seed Gaussian model."""

    gain: GainCurve
    read_sigma: SigmaCurve
    gaussian: SeedGaussian

    @classmethod
    def from_seed(cls, g: SeedGaussian) -> NoiseSpec:
        """The Poisson–Gaussian model matching the seed model (β = 0): K = α² g, σ = σ_r g."""
        alpha2 = g.shot_noise_std_alpha**2
        # σ_r g = (σ_r / α²) K, a log-linear law of slope 1 (σ ≈ 0 when σ_r or α is 0).
        ratio = g.read_noise_std / alpha2 if alpha2 > 0 else 0.0
        return cls(
            gain=GainCurve("linear", slope=alpha2 / g.iso_base),
            read_sigma=SigmaCurve(
                "loglinear", slope=1.0, bias=math.log(ratio) if ratio > 0 else -50.0
            ),
            gaussian=g,
        )

    def levels(self, model: str, iso: float) -> NoiseLevels:
        """The noise parameters of ``model`` at ``iso``."""
        check_choice("noise model", model, NOISE_MODELS)
        if not iso > 0:
            raise ParameterError(f"ISO must be > 0, got {iso}")
        if model == "gaussian":
            g = self.gaussian
            return NoiseLevels(
                model,
                iso,
                read_sigma=g.read_noise_std * iso / g.iso_base,
                shot_alpha=g.shot_noise_std_alpha,
                shot_beta=g.shot_noise_std_beta,
                iso_gain=iso / g.iso_base,
            )
        k = self.gain(iso)
        return NoiseLevels(model, iso, gain=k, read_sigma=self.read_sigma(iso, k))


@dataclass(frozen=True)
class NoiseLevels:
    """Noise parameters at one ISO. All in DN; ``gain`` K in DN/e⁻.

    For ``gaussian`` the read σ already includes the ISO factor g.
    """

    model: str
    iso: float
    gain: float | None = None
    read_sigma: float = 0.0
    shot_alpha: float = 0.0
    shot_beta: float = 0.0
    iso_gain: float = 1.0

    def variance(self, signal):
        """Variance (DN²) of the rounded output at clean ``signal`` DN above black (≥ 0)."""
        s = torch.as_tensor(signal, dtype=torch.float64).clamp_min(0)
        if self.model == "none":
            return torch.zeros_like(s)
        if self.model == "gaussian":
            shot = self.shot_alpha * s.sqrt() + self.shot_beta
            var = self.iso_gain * shot**2 + self.read_sigma**2
        else:
            var = self.gain * s + self.read_sigma**2
        return var + QUANTIZATION_VARIANCE

    def affine_variance(self, span: float) -> tuple[float, float]:
        """(a, b) with variance ≈ a · s + b DN² for s in [0, span].

        Exact for ``poisson-gaussian`` and for ``gaussian`` with β = 0; otherwise the
        least-squares line over the range.
        """
        s = torch.linspace(0, span, 1025, dtype=torch.float64)
        v = self.variance(s)
        a, b = torch.linalg.lstsq(torch.stack([s, torch.ones_like(s)], 1), v[:, None]).solution[
            :, 0
        ]
        return float(a), float(b)

    def noise_profile(self, black: float, white: float) -> tuple[float, float]:
        """DNG NoiseProfile (S, O): σ(x) = √(S x + O) for x normalised to [0, 1]."""
        span = float(white) - float(black)
        a, b = self.affine_variance(span)
        return a / span, b / span**2

    def to_dict(self) -> dict:
        out = {"model": self.model, "iso": self.iso, "read_sigma_dn": self.read_sigma}
        if self.model == "poisson-gaussian":
            out["gain_dn_per_electron"] = self.gain
        elif self.model == "gaussian":
            out |= {
                "shot_alpha": self.shot_alpha,
                "shot_beta": self.shot_beta,
                "iso_gain": self.iso_gain,
            }
        return out


def add_noise(
    dn: torch.Tensor,
    black,
    levels: NoiseLevels,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Add sensor noise to a clean mosaic.

    Args:
        dn: (B, 1, H, W) clean DN (float, not rounded; may lie below black).
        black: black level, a number or a tensor broadcastable to ``dn``.
        levels: noise parameters at the ISO (:meth:`NoiseSpec.levels`).
        generator: source of randomness (its device must match ``dn``).

    Returns:
        Noisy DN, float, unrounded and unclipped. Differentiable with respect to
        ``dn``: normal terms are reparameterised; the exact Poisson term passes the
        gradient straight through (its mean is the signal).
    """
    if levels.model == "none":
        return dn
    signal = dn - black
    positive = signal.clamp_min(0)
    read = torch.randn(dn.shape, generator=generator, device=dn.device, dtype=dn.dtype)
    if levels.model == "gaussian":
        shot = levels.shot_alpha * positive.sqrt() + levels.shot_beta
        sigma = torch.sqrt(levels.iso_gain * shot**2 + levels.read_sigma**2)
        return torch.addcmul(dn, sigma, read)
    if levels.model == "poisson-gaussian":
        k, read_var = levels.gain, levels.read_sigma**2
        small = positive.detach() < EXACT_POISSON_BELOW * k
        # σ² = K s + σ_read² where the normal law stands in for Poisson, σ_read² elsewhere.
        sigma = (k * positive).masked_fill(small, 0.0).add(read_var).sqrt()
        noisy = torch.addcmul(dn, sigma, read).reshape(-1)
        idx = small.reshape(-1).nonzero().squeeze(1)
        if idx.numel():
            signal = positive.reshape(-1).index_select(0, idx)
            shot = k * torch.poisson(signal.detach() / k, generator=generator) - signal
            noisy = noisy.index_add(0, idx, shot.detach())
        return noisy.reshape(dn.shape)
    raise ParameterError(f"unknown noise model {levels.model!r}; valid: {', '.join(NOISE_MODELS)}")
