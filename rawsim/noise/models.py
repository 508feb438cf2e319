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

from dataclasses import dataclass

import torch

from rawsim.errors import ParameterError
from rawsim.noise.dark_shading import check_fits, crop_offset
from rawsim.noise.exact_math import LOGISTIC_LAMBDA
from rawsim.noise.poisson_table import EXACT_POISSON_BELOW
from rawsim.noise.reference import (
    ieee_sqrt,
    normal,
    poisson,
    split_key,
    tukey_lambda,
    tukey_table,
    uniforms,
)

# The torch-free parameters, defined in rawsim.noise.spec (profiles load without torch).
from rawsim.noise.spec import (  # noqa: F401  (re-exported)
    DEFAULT_SPREAD,
    NOISE_MODELS,
    QUANTIZATION_VARIANCE,
    GainCurve,
    LambdaCurve,
    NoiseLevels,
    NoiseSpec,
    SeedGaussian,
    SigmaCurve,
    bias_tile,
    tukey_lambda_variance,
)


def tukey_lambda_quantile(u: torch.Tensor, lam: float) -> torch.Tensor:
    """Quantile function of the standard Tukey-lambda law at ``u`` in (0, 1).

    ``Q(u) = (u^λ − (1 − u)^λ) / λ``, and the logistic ``ln(u / (1 − u))`` at λ = 0.
    """
    return tukey_from_logs(u.log(), u.neg().log1p_(), lam)


def tukey_from_logs(low: torch.Tensor, high: torch.Tensor, lam: float) -> torch.Tensor:
    """:func:`tukey_lambda_quantile` from ``low`` = ln u and ``high`` = ln(1 − u) (left
    as they are), for evaluating many λ at the same u: the same arithmetic, in order."""
    if abs(lam) < LOGISTIC_LAMBDA:
        return low - high
    return (low * lam).exp_().sub_((high * lam).exp_()).div_(lam)


def _uniform(shape, generator, device, dtype) -> torch.Tensor:
    """Uniform draws in (0, 1): ``torch.rand``'s 0 becomes half its smallest step."""
    u = torch.rand(shape, generator=generator, device=device, dtype=dtype)
    return u.clamp_min_(torch.finfo(dtype).eps / 4)


def sample_tukey_lambda(shape, lam: float, generator=None, device=None, dtype=torch.float32):
    """Standard Tukey-lambda draws (scale 1) of ``shape`` by inverse transform sampling."""
    return tukey_lambda_quantile(_uniform(shape, generator, device, dtype), lam)


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


def site_bias(levels: NoiseLevels, cfa, top: int, h: int, w: int, device):
    """(h, w) float64 channel bias of rows ``top`` … ``top + h`` (the tile of
    :func:`bias_tile` laid from the image's top-left site), a number for a
    monochrome sensor, or None when there is none."""
    tile = bias_tile(levels, cfa)
    if tile is None or cfa is None:
        return tile
    tile = torch.from_numpy(tile).to(device)
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
