"""Sensor noise at a given ISO, in raw digital numbers (DN).

Models (``NOISE_MODELS``):

* ``poisson-gaussian``: ``D = K · Poisson(s / K) + N(0, σ_read²)`` for a clean
  signal ``s`` DN above black and system gain ``K`` (DN/e⁻). The Poisson draw is
  exact below :data:`EXACT_POISSON_BELOW` electrons, where its skew and
  discreteness are visible. Above it the Poisson law is within skewness
  1/√λ < 0.1 (excess kurtosis < 0.01) of a normal one, so shot and read noise
  are drawn together as a single normal of the same variance ``K s + σ_read²``
  (exact sampling of every pixel would be several times slower).
* ``physics``: the ELD model (Wei et al. 2020),
  ``D = K · Poisson(s / K) + N_read + N_row + bias_c``: read noise Tukey-lambda
  with shape λ and scale σ_TL, one normal offset per sensor row (σ_row), a
  per-channel DC bias. Shot noise is drawn as for ``poisson-gaussian``. Where the
  profile has them (PMN, Feng et al. 2022; :mod:`rawsim.noise.dark_shading`), it
  adds dark shading ``k(x, y) · ISO + b(x, y)`` (a crop of the profile's maps at a
  CFA-aligned offset drawn per file) and one black-level offset per file, normal
  with σ_BLE(ISO), both after the channel bias (:func:`dark_draw`).
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
from rawsim.noise.dark_shading import BlackLevelError, DarkShading, check_fits, crop_offset
from rawsim.noise.exact_math import LOGISTIC_LAMBDA
from rawsim.noise.poisson_table import POISSON_MEANS
from rawsim.noise.reference import (
    ieee_sqrt,
    normal,
    poisson,
    split_key,
    tukey_lambda,
    tukey_table,
    uniforms,
)

NOISE_MODELS = ("none", "gaussian", "poisson-gaussian", "physics")
#: Default spread (σ of ln σ) of sampled noise levels when a profile gives none.
DEFAULT_SPREAD = 0.1
EXACT_POISSON_BELOW = float(POISSON_MEANS)
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


def tukey_lambda_quantile(u: torch.Tensor, lam: float) -> torch.Tensor:
    """Quantile function of the standard Tukey-lambda law at ``u`` in (0, 1).

    ``Q(u) = (u^λ − (1 − u)^λ) / λ``, and the logistic ``ln(u / (1 − u))`` at λ = 0.
    """
    return _tukey_numerator(u.clone(), lam).div_(_tukey_divisor(lam))


def _tukey_numerator(u: torch.Tensor, lam: float) -> torch.Tensor:
    """``u^λ − (1 − u)^λ`` (``ln u − ln(1 − u)`` at λ = 0), overwriting ``u``."""
    low = u.log()
    high = u.neg_().log1p_()
    if abs(lam) < LOGISTIC_LAMBDA:
        return low.sub_(high)
    return low.mul_(lam).exp_().sub_(high.mul_(lam).exp_())


def _tukey_divisor(lam: float) -> float:
    """What divides :func:`_tukey_numerator` to give the quantile: λ, or 1 in the limit."""
    return 1.0 if abs(lam) < LOGISTIC_LAMBDA else lam


def _uniform(shape, generator, device, dtype) -> torch.Tensor:
    """Uniform draws in (0, 1): ``torch.rand``'s 0 becomes half its smallest step."""
    u = torch.rand(shape, generator=generator, device=device, dtype=dtype)
    return u.clamp_min_(torch.finfo(dtype).eps / 4)


def sample_tukey_lambda(shape, lam: float, generator=None, device=None, dtype=torch.float32):
    """Standard Tukey-lambda draws (scale 1) of ``shape`` by inverse transform sampling."""
    return tukey_lambda_quantile(_uniform(shape, generator, device, dtype), lam)


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


def add_noise(
    dn: torch.Tensor, black, levels: NoiseLevels, key, cfa=None, top: int = 0, height=None
):
    """Add sensor noise to a clean mosaic (the torch reference of the engine's draws).

    Args:
        dn: (B, 1, h, w) clean DN (float, not rounded; may lie below black): rows
            ``top`` … ``top + h`` of an image ``w`` wide.
        black: black level (a number).
        levels: noise parameters at the ISO (:meth:`NoiseSpec.levels`).
        key: the noise seed (a 64-bit int), or one per sample. Each draw is a
            function of (key, pixel index ``y · w + x``), from
            :mod:`rawsim.noise.reference`, so the result does not depend on how the
            image is cut into strips or batches, nor on the device.
        cfa: the mosaic's :class:`~rawsim.cfa.CFA` (any layout), to place a non-zero
            ``channel_bias`` (physics model; see :func:`bias_tile`); None for a
            monochrome sensor, which gets the mean of the four biases.
        top: the first row's index in the image.
        height: the image's height, when ``dn`` is a strip of it (default ``top + h``):
            it places the crop of a dark-shading map (:func:`dark_draw`).

    Returns:
        Noisy DN in float64, unrounded and unclipped (float64 so that rounding it
        gives the engine's bits). Differentiable with respect to ``dn``; the noise
        itself is held constant.
    """
    if levels.model not in NOISE_MODELS:
        raise ParameterError(
            f"unknown noise model {levels.model!r}; valid: {', '.join(NOISE_MODELS)}"
        )
    if levels.model == "none":
        return dn.double()
    b, _, h, w = dn.shape
    keys = [key] * b if isinstance(key, int) else [int(k) for k in key]
    if len(keys) != b:
        raise ParameterError(f"need one noise key per sample: {len(keys)} for a batch of {b}")
    rows = torch.arange(top, top + h, device=dn.device, dtype=torch.int64)
    sites = rows[:, None] * w + torch.arange(w, device=dn.device, dtype=torch.int64)
    bias = site_bias(levels, cfa, top, h, w, dn.device)
    height = top + h if height is None else height
    with torch.no_grad():
        noise = torch.stack(
            [
                noise_field(
                    dn[i, 0].double() - black,
                    levels,
                    split_key(k),
                    sites,
                    rows,
                    bias,
                    dark_field(levels, dark_draw(levels, k, height, w, cfa), top, h, w, dn.device),
                )
                for i, k in enumerate(keys)
            ]
        )[:, None]
    return dn.double() + noise


@dataclass(frozen=True)
class DarkDraw:
    """A file's draws of the physics model's dark terms: the crop of the dark-shading
    map (its first row ``top`` and column ``left``) and the black-level ``offset`` (DN)."""

    top: int
    left: int
    offset: float

    def to_dict(self) -> dict:
        return {"map_top": self.top, "map_left": self.left, "black_level_offset_dn": self.offset}


def dark_draw(levels: NoiseLevels, key: int, height: int, width: int, cfa=None):
    """The :class:`DarkDraw` of an image ``height`` × ``width`` with noise seed ``key``, or
    None when ``levels`` add no dark terms (:attr:`NoiseLevels.has_dark`).

    The offset is σ_BLE · a normal of stream ``black_level``; the crop's row and
    column come from the two uniforms of stream ``dark_crop`` (both at index 0 of
    the file's Philox key), multiples of the CFA period (``cfa`` None: 1), so each
    site keeps the colour it was measured with. An image larger than the map is
    refused (:func:`~rawsim.noise.dark_shading.check_fits`). Both backends use this.
    """
    if not levels.has_dark:
        return None
    index = torch.zeros(1, dtype=torch.int64)
    offset = levels.black_level_sigma * float(normal(index, split_key(key), "black_level")[0])
    shading = levels.dark_shading
    if shading is None:
        return DarkDraw(0, 0, offset)
    check_fits(shading, height, width)
    u1, u2 = (float(u[0]) for u in uniforms(index, "dark_crop", split_key(key)))
    ph, pw = (1, 1) if cfa is None else cfa.period
    return DarkDraw(
        crop_offset(u1, height, shading.size[0], ph),
        crop_offset(u2, width, shading.size[1], pw),
        offset,
    )


def dark_field(levels: NoiseLevels, draw, top: int, h: int, w: int, device="cpu"):
    """The dark terms of rows ``top`` … ``top + h`` (``w`` wide): float64 (h, w)
    ``(k · ISO + b) + offset`` over the map's crop, the offset alone (a number)
    without a map, or None without either. The engine's ``noise_row`` adds the same."""
    if draw is None:
        return None
    if levels.dark_shading is None:
        return draw.offset
    k, b = levels.dark_shading.maps(levels.iso)
    rows = slice(draw.top + top, draw.top + top + h)
    cols = slice(draw.left, draw.left + w)
    k = torch.from_numpy(k[rows, cols]).to(device, torch.float64)
    b = torch.from_numpy(b[rows, cols]).to(device, torch.float64)
    return (k * float(levels.iso) + b) + draw.offset


def bias_tile(levels: NoiseLevels, cfa, device="cpu"):
    """The channel bias of each site of one CFA period: (ph, pw) float64, or None when
    there is none, or a number for a monochrome sensor (``cfa`` None: the mean of the
    four biases).

    ``channel_bias`` is (R, Gr, Gb, B) DN. A Bayer pattern places the four at its
    R, Gr, Gb and B sites; any other layout (X-Trans) has no Gr/Gb distinction, so
    its R and B sites get those biases and every G site the mean of Gr and Gb.
    """
    if levels.model != "physics" or not any(levels.channel_bias):
        return None
    if cfa is None:  # monochrome: one mean offset
        return sum(levels.channel_bias) / len(levels.channel_bias)
    r, gr, gb, b = levels.channel_bias
    if cfa.is_bayer:
        bias = torch.tensor(levels.channel_bias, dtype=torch.float64, device=device)
        return cfa.unpack(bias.reshape(1, 4, 1, 1))[0, 0]
    per_colour = torch.tensor([r, (gr + gb) / 2, b], dtype=torch.float64, device=device)
    return cfa.tile(per_colour)[0]


def site_bias(levels: NoiseLevels, cfa, top: int, h: int, w: int, device):
    """(h, w) float64 channel bias of rows ``top`` … ``top + h`` (the tile of
    :func:`bias_tile` laid from the image's top-left site), a number for a
    monochrome sensor, or None when there is none."""
    tile = bias_tile(levels, cfa, device)
    if tile is None or cfa is None:
        return tile
    ph, pw = tile.shape
    return tile.roll(-(top % ph), 0).repeat(-(-h // ph) + 1, -(-w // pw))[:h, :w]


def noise_field(signal, levels: NoiseLevels, key, sites, rows, bias, dark=None) -> torch.Tensor:
    """The noise (float64, (h, w)) added to ``signal`` DN above black; ``bias`` the
    channel bias (:func:`site_bias`), ``dark`` the dark terms (:func:`dark_field`).

    The engine's ``noise_row`` computes the same per site; every step here is
    one rounded float64 operation in the same order, so the two agree bit for bit.
    Shot noise is K·Poisson(s/K) − s below :data:`EXACT_POISSON_BELOW` electrons
    and a normal of the same variance above (joined with the Gaussian read noise
    for ``poisson-gaussian``). At s = 0 (black or below) both are 0 exactly: such
    sites draw no Poisson count (Poisson(0) is 0), which changes no code.
    """
    positive = signal.clamp_min(0.0)
    z = normal(sites, key)
    if levels.model == "gaussian":
        shot = levels.shot_alpha * ieee_sqrt(positive) + levels.shot_beta
        return (
            ieee_sqrt(levels.iso_gain * (shot * shot) + levels.read_sigma * levels.read_sigma) * z
        )
    k = float(levels.gain)
    physics = levels.model == "physics"
    read_var = 0.0 if physics else levels.read_sigma * levels.read_sigma
    small = (positive < EXACT_POISSON_BELOW * k) & (positive > 0.0)
    noise = ieee_sqrt(k * positive + read_var) * z
    if bool(small.any()):
        pos = positive[small]
        shot = k * poisson(pos / k, sites[small], key) - pos
        noise[small] = shot if physics else shot + levels.read_sigma * z[small]
    if not physics:
        return noise
    table = tukey_table(levels.tukey_lambda, signal.device)
    noise = noise + levels.read_sigma * tukey_lambda(sites, key, table)
    noise = noise + levels.row_sigma * normal(rows, key, "row")[:, None]
    noise = noise if bias is None else noise + bias
    return noise if dark is None else noise + dark
