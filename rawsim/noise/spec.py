"""Noise parameters of a sensor, torch-free: the curves a profile holds (K, σ, λ
versus ISO or gain), :class:`NoiseSpec` and the :class:`NoiseLevels` at one ISO.

Split from :mod:`rawsim.noise.models` (which re-exports every name) so that
loading a profile (:mod:`rawsim.cameras.profiles`) and the command line's checks of
one need no torch; torch is imported only to draw random levels
(:meth:`NoiseSpec.sample_levels`, given a ``torch.Generator``) and for
:meth:`NoiseLevels.variance` of a tensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rawsim.errors import ParameterError, check_choice
from rawsim.noise.dark_shading import BlackLevelError, DarkShading
from rawsim.noise.exact_math import LOGISTIC_LAMBDA

if TYPE_CHECKING:
    import torch

NOISE_MODELS = ("none", "gaussian", "poisson-gaussian", "physics")
#: Default spread (σ of ln σ) of sampled noise levels when a profile gives none.
DEFAULT_SPREAD = 0.1
QUANTIZATION_VARIANCE = 1.0 / 12.0


def _interp(t: float, xs: list[float], ys: list[float]) -> float:
    """Piecewise-linear interpolation through (xs, ys), extrapolating the end segments."""
    i = max(0, min(len(xs) - 2, sum(1 for v in xs[1:-1] if t > v)))
    w = (t - xs[i]) / (xs[i + 1] - xs[i])
    return ys[i] + w * (ys[i + 1] - ys[i])


def _interp_loglog(x: float, xs: tuple[float, ...], ys: tuple[float, ...]) -> float:
    """Piecewise-linear interpolation in log-log space, extrapolating the end segments."""
    lx = [math.log(v) for v in xs]
    return math.exp(_interp(math.log(x), lx, [math.log(v) for v in ys]))


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
class LambdaCurve:
    """Tukey-lambda shape λ versus gain: linear in ln K between (k, lam) points, held flat
    outside them. ``bounds`` is the range a randomised draw is taken from."""

    k: tuple[float, ...]
    lam: tuple[float, ...]

    def __call__(self, k: float) -> float:
        if len(self.k) == 1:
            return self.lam[0]
        logs = [math.log(v) for v in self.k]
        return _interp(min(max(math.log(k), logs[0]), logs[-1]), logs, list(self.lam))

    @property
    def bounds(self) -> tuple[float, float]:
        return min(self.lam), max(self.lam)


@dataclass(frozen=True)
class NoiseSpec:
    """A sensor's noise description.

    ``gain`` K(ISO) and the Gaussian ``read_sigma`` serve ``poisson-gaussian``; the
    physics model adds ``tukey_sigma`` (scale of the Tukey-lambda read noise),
    ``tukey_lambda``, ``row_sigma`` and ``channel_bias`` (DN, R, Gr, Gb, B; the G
    sites of a non-Bayer layout take the mean of Gr and Gb, see :func:`bias_tile`);
    ``gaussian`` holds the seed model. ``spread`` is the σ of ln σ when noise
    levels are sampled (:meth:`sample_levels`). ``dark_shading`` (the maps) and
    ``black_level_error`` (σ of the per-file offset), optional, serve the physics
    model only; :meth:`sample_levels` keeps them as they are.
    """

    gain: GainCurve
    read_sigma: SigmaCurve
    gaussian: SeedGaussian
    tukey_sigma: SigmaCurve | None = None
    tukey_lambda: LambdaCurve | None = None
    row_sigma: SigmaCurve | None = None
    channel_bias: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    spread: float = DEFAULT_SPREAD
    dark_shading: DarkShading | None = None
    black_level_error: BlackLevelError | None = None

    @property
    def has_physics(self) -> bool:
        """Whether the physics model's parameters are all known."""
        return None not in (self.tukey_sigma, self.tukey_lambda, self.row_sigma)

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
        """The nominal noise parameters of ``model`` at ``iso`` (the fitted laws)."""
        return self._levels(model, iso, None)

    def sample_levels(self, model: str, iso: float, generator: torch.Generator) -> NoiseLevels:
        """Noise parameters at ``iso`` drawn around the fits, for augmentation (ELD).

        Each σ is multiplied by ``exp(N(0, spread²))`` and λ is uniform over the
        profile's λ range; K stays on its curve (the ISO is what varies). The
        seed's ``gaussian`` model has no such spread and is returned as is.
        """
        return self._levels(model, iso, generator)

    def _levels(self, model: str, iso: float, g: torch.Generator | None) -> NoiseLevels:
        check_choice("noise model", model, NOISE_MODELS)
        if not iso > 0:
            raise ParameterError(f"ISO must be > 0, got {iso}")
        if model == "gaussian":
            gs = self.gaussian
            return NoiseLevels(
                model,
                iso,
                read_sigma=gs.read_noise_std * iso / gs.iso_base,
                shot_alpha=gs.shot_noise_std_alpha,
                shot_beta=gs.shot_noise_std_beta,
                iso_gain=iso / gs.iso_base,
            )

        def jitter(sigma: float) -> float:
            if g is None:
                return sigma
            import torch  # g is a torch.Generator: torch is loaded already

            return sigma * math.exp(self.spread * float(torch.randn((), generator=g)))

        k = self.gain(iso)
        if model != "physics":
            return NoiseLevels(model, iso, gain=k, read_sigma=jitter(self.read_sigma(iso, k)))
        if not self.has_physics:
            raise ParameterError(
                "this profile has no physics noise parameters "
                "(noise.tukey_sigma, noise.tukey_lambda, noise.row_sigma)"
            )
        if g is None:
            lam = self.tukey_lambda(k)
        else:
            import torch

            lo, hi = self.tukey_lambda.bounds
            lam = lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))
        return NoiseLevels(
            model,
            iso,
            gain=k,
            read_sigma=jitter(self.tukey_sigma(iso, k)),
            tukey_lambda=lam,
            row_sigma=jitter(self.row_sigma(iso, k)),
            channel_bias=self.channel_bias,
            dark_shading=self.dark_shading,
            black_level_sigma=0.0
            if self.black_level_error is None
            else self.black_level_error(iso),
        )


def tukey_lambda_variance(lam: float) -> float:
    """Variance of the standard Tukey-lambda law (scale 1); infinite for λ ≤ −1/2."""
    if lam <= -0.5:
        return math.inf
    if abs(lam) < LOGISTIC_LAMBDA:
        return math.pi**2 / 3
    return (2 / lam**2) * (
        1 / (1 + 2 * lam) - math.exp(2 * math.lgamma(lam + 1) - math.lgamma(2 * lam + 2))
    )


@dataclass(frozen=True)
class NoiseLevels:
    """Noise parameters at one ISO. All in DN; ``gain`` K in DN/e⁻.

    For ``gaussian`` the read σ already includes the ISO factor g. For ``physics``
    ``read_sigma`` is the Tukey-lambda scale (its standard deviation is
    ``read_sigma · √var_TL(λ)``), ``row_sigma`` the σ of each row's offset,
    ``channel_bias`` the mean offset of the R, Gr, Gb and B sites,
    ``dark_shading`` the maps whose k · ISO + b is added (None: none) and
    ``black_level_sigma`` the σ of the per-file black-level offset. The last two
    are fixed pattern and per-file offset, not part of the variance of a pixel
    (:meth:`variance`, the DNG NoiseProfile).
    """

    model: str
    iso: float
    gain: float | None = None
    read_sigma: float = 0.0
    shot_alpha: float = 0.0
    shot_beta: float = 0.0
    iso_gain: float = 1.0
    tukey_lambda: float = 0.0
    row_sigma: float = 0.0
    channel_bias: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    dark_shading: DarkShading | None = None
    black_level_sigma: float = 0.0

    @property
    def has_dark(self) -> bool:
        """Whether the levels add dark shading or a black-level offset."""
        return self.model == "physics" and (
            self.dark_shading is not None or self.black_level_sigma > 0
        )

    @property
    def read_variance(self) -> float:
        """Variance (DN²) of the signal-independent read noise, row noise included."""
        if self.model == "physics":
            return self.read_sigma**2 * tukey_lambda_variance(self.tukey_lambda) + self.row_sigma**2
        return self.read_sigma**2

    def variance(self, signal):
        """Variance (DN²) of the rounded output at clean ``signal`` DN above black (≥ 0)."""
        import torch

        s = torch.as_tensor(signal, dtype=torch.float64).clamp_min(0)
        if self.model == "none":
            return torch.zeros_like(s)
        if self.model == "gaussian":
            shot = self.shot_alpha * s.sqrt() + self.shot_beta
            var = self.iso_gain * shot**2 + self.read_sigma**2
        else:
            var = self.gain * s + self.read_variance
        return var + QUANTIZATION_VARIANCE

    def affine_variance(self, span: float) -> tuple[float, float]:
        """(a, b) with variance ≈ a · s + b DN² for s in [0, span].

        Exact for ``poisson-gaussian`` and ``physics`` (b holds the read, row and
        quantisation variance) and for ``gaussian`` with β = 0; otherwise the
        least-squares line over 1025 points of the range. Computed in float64 with
        correctly rounded sums (``math.fsum``), so the figures (and the DNG
        NoiseProfile made from them) are the same bits on every run and machine.
        """
        if self.model == "none":
            return 0.0, 0.0
        if self.model in ("poisson-gaussian", "physics"):
            return float(self.gain), self.read_variance + QUANTIZATION_VARIANCE
        n = 1025
        s = [span * i / (n - 1) for i in range(n)]
        import torch

        v = [float(x) for x in self.variance(torch.tensor(s, dtype=torch.float64))]
        s_mean, v_mean = math.fsum(s) / n, math.fsum(v) / n
        sxx = math.fsum((x - s_mean) ** 2 for x in s)
        a = math.fsum((x - s_mean) * (y - v_mean) for x, y in zip(s, v, strict=True)) / sxx
        return a, v_mean - a * s_mean

    def noise_profile(self, black: float, white: float) -> tuple[float, float]:
        """DNG NoiseProfile (S, O): σ(x) = √(S x + O) for x normalised to [0, 1]."""
        span = float(white) - float(black)
        a, b = self.affine_variance(span)
        return a / span, b / span**2

    def to_dict(self) -> dict:
        """The levels as the sidecars write them. ``read_std_dn`` is the standard
        deviation of the read noise in every model (what ``rawsim calibrate`` fits);
        ``read_sigma_dn``, kept for the Gaussian models, is the same figure; the
        physics model's Tukey-lambda scale is ``tukey_scale_dn``."""
        out = {"model": self.model, "iso": self.iso}
        if self.model == "physics":
            out["read_std_dn"] = math.sqrt(self.read_variance - self.row_sigma**2)
        else:
            out |= {"read_std_dn": self.read_sigma, "read_sigma_dn": self.read_sigma}
        if self.model in ("poisson-gaussian", "physics"):
            out["gain_dn_per_electron"] = self.gain
        if self.model == "physics":
            out |= {
                "tukey_scale_dn": self.read_sigma,
                "tukey_lambda": self.tukey_lambda,
                "row_sigma_dn": self.row_sigma,
                "channel_bias_dn": list(self.channel_bias),
            }
            if self.dark_shading is not None:  # absent without: sidecars as before
                out["dark_shading"] = self.dark_shading.to_dict()
            if self.black_level_sigma > 0:
                out["black_level_error_sigma_dn"] = self.black_level_sigma
        elif self.model == "gaussian":
            out |= {
                "shot_alpha": self.shot_alpha,
                "shot_beta": self.shot_beta,
                "iso_gain": self.iso_gain,
            }
        return out


def bias_tile(levels: NoiseLevels, cfa) -> np.ndarray | float | None:
    """The channel bias of each site of one CFA period: (ph, pw) float64, or None when
    there is none, or a number for a monochrome sensor (``cfa`` None: the mean of the
    four biases). Both backends lay it out from here.

    ``channel_bias`` is (R, Gr, Gb, B) DN. A Bayer pattern places the four at its
    R, Gr, Gb and B sites (:attr:`~rawsim.cfa.CFA.packed_sites`); any other layout
    (X-Trans) has no Gr/Gb distinction, so its R and B sites get those biases and
    every G site the mean of Gr and Gb.
    """
    if levels.model != "physics" or not any(levels.channel_bias):
        return None
    if cfa is None:  # monochrome: one mean offset
        return sum(levels.channel_bias) / len(levels.channel_bias)
    if cfa.is_bayer:
        return cfa.unpack_array(np.array(levels.channel_bias, np.float64).reshape(4, 1, 1))
    r, gr, gb, b = levels.channel_bias
    per_colour = np.array([r, (gr + gb) / 2, b], np.float64)
    return per_colour[np.array(cfa.colors)].reshape(cfa.period)
