"""Spatial filters: anti-aliasing (on the mosaic, per colour) and denoising.

Both act colour by colour on a mosaic (B, 1, H, W) when given its CFA, or
channel by channel on an image (B, C, H, W). Values are linear, any range, and
are not clipped. ``reverse`` is the identity for both.

On a mosaic each site is filtered with its same-colour neighbours
(:mod:`rawsim.isp.planes`). Sizes and σ are in *plane pixels*, the spacing of a
Bayer colour plane: 2 mosaic pixels on every pattern, so a setting blurs the
same image distance on any CFA, and a ``k``×``k`` window reaches ``2·(k // 2)``
mosaic pixels on each side. On a Bayer mosaic the kernels are applied to the
packed R, Gr, Gb, B planes. On any other pattern (X-Trans …) they are sampled
at the offsets (dy, dx), in mosaic pixels, of the site's same-colour
neighbours in that window and normalised to sum 1 per site:

* ``weighted_average``: the separable tent (1 − |dy|/4)(1 − |dx|/4), which at
  the Bayer plane offsets (0, ±2) is the 3×3 binomial [1 2 1]ᵀ[1 2 1] / 16;
* ``gaussian``: exp(−(dy² + dx²) / (2 (2σ)²)), the Gaussian of σ plane pixels;
* ``bilateral`` (denoise): that Gaussian times the range weight
  exp(−(v − v₀)² / (2 σ_color²)) of each neighbour's value v against the
  site's own v₀.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import ParameterError, check_choice, check_image
from rawsim.isp.config import ANTI_ALIAS_METHODS, DENOISE_METHODS
from rawsim.isp.planes import (
    Offsets,
    correlate,
    gaussian_kernel,
    gaussian_size,
    neighbourhood,
    per_plane,
    per_site,
    plane_radius,
    weighted_sum,
)

_WEIGHTED_AVERAGE = torch.tensor([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 16


def _tent(dy: int, dx: int) -> float:
    """The ``weighted_average`` kernel at mosaic offset (dy, dx)."""
    return (1 - abs(dy) / 4) * (1 - abs(dx) / 4)


def _gaussian(sigma: float) -> Callable[[int, int], float]:
    """The Gaussian of σ plane pixels at mosaic offset (dy, dx), unnormalised."""
    return lambda dy, dx: math.exp(-(dy * dy + dx * dx) / (2 * (2 * sigma) ** 2))


def _normalised(weight: Callable[[int, int], float], offsets: Offsets) -> list[float]:
    values = [weight(dy, dx) for dy, dx in offsets]
    total = math.fsum(values)
    return [v / total for v in values]


def _range_weight(values: torch.Tensor, sites: torch.Tensor, sigma_color: float) -> torch.Tensor:
    """The bilateral filter's weight of neighbour ``values`` against ``sites``."""
    return torch.exp(-((values - sites) ** 2) / (2 * sigma_color**2))


def _bilateral(
    sites: torch.Tensor, values: torch.Tensor, spatial: torch.Tensor, sigma_color: float
) -> torch.Tensor:
    """Bilateral mean of ``values`` (N, …) around ``sites`` (…), spatial weights (N,)."""
    w = spatial.reshape(-1, *([1] * sites.ndim)).to(sites) * _range_weight(
        values, sites, sigma_color
    )
    return (w * values).sum(0) / w.sum(0)


def _site_bilateral(spatial: Callable[[int, int], float], sigma_color: float):
    """A :func:`~rawsim.isp.planes.per_site` filter: the bilateral mean, summed tap by tap
    (the same bits whatever the image's size, so strips equal the whole)."""

    def mean(sites, values, offsets):
        pairs = list(zip(values, offsets, strict=True))
        w = [_range_weight(v, sites, sigma_color) * spatial(*d) for v, d in pairs]
        ones = [1.0] * len(w)
        weighted = [wk * v for wk, (v, _) in zip(w, pairs, strict=True)]
        return weighted_sum(weighted, ones) / weighted_sum(w, ones)

    return mean


def _weighted_mean(weight: Callable[[int, int], float]):
    """A :func:`~rawsim.isp.planes.per_site` filter: the normalised ``weight`` mean."""
    return lambda sites, values, offsets: weighted_sum(values, _normalised(weight, offsets))


def anti_alias(
    x: torch.Tensor, cfa: CFA | None, method: str = "weighted_average", sigma: float = 0.5
) -> torch.Tensor:
    """Small blur of a mosaic (B, 1, H, W) per colour of ``cfa``, or of an image (B, C, H, W)
    per channel: 3×3 binomial (``weighted_average``) or a Gaussian of ``sigma`` plane
    pixels (see the module doc). Linear values in, the same range out."""
    check_choice("anti-aliasing method", method, ANTI_ALIAS_METHODS)
    if method == "none":
        return x
    check_image(x, "image")
    if not sigma > 0:
        raise ParameterError(f"anti-aliasing sigma must be > 0, got {sigma}")
    if method == "weighted_average":
        kernel, weight = _WEIGHTED_AVERAGE, _tent
    else:
        kernel, weight = gaussian_kernel(sigma), _gaussian(sigma)
    if _mosaic(x, cfa) and not cfa.is_bayer:
        return per_site(x, cfa, plane_radius(kernel.shape[0]), _weighted_mean(weight))
    return _planes(x, cfa, lambda p: correlate(p, kernel))


def denoise(
    x: torch.Tensor,
    cfa: CFA | None = None,
    method: str = "bilateral",
    kernel: int = 5,
    sigma: float = 1.0,
    sigma_color: float = 0.05,
) -> torch.Tensor:
    """Gaussian blur, or an edge-preserving bilateral filter (range σ ``sigma_color``),
    of a mosaic (B, 1, H, W) per colour of ``cfa`` or of an image (B, C, H, W) per
    channel.

    ``kernel`` (odd) and the spatial ``sigma`` are in pixels of the image, or plane
    pixels on a mosaic (see the module doc); values are linear, any range, not
    clipped.
    """
    check_choice("denoise method", method, DENOISE_METHODS)
    if method == "none":
        return x
    check_image(x, "image")
    if kernel % 2 == 0 or kernel < 3:
        raise ParameterError(f"denoise kernel must be odd and ≥ 3, got {kernel}")
    if not sigma > 0 or not sigma_color > 0:
        raise ParameterError("denoise sigma and sigma_color must be > 0")
    if _mosaic(x, cfa) and not cfa.is_bayer:
        weight = _gaussian(sigma)
        if method == "gaussian":
            return per_site(x, cfa, plane_radius(kernel), _weighted_mean(weight))
        return per_site(x, cfa, plane_radius(kernel), _site_bilateral(weight, sigma_color))
    spatial = gaussian_kernel(sigma, kernel)
    if method == "gaussian":
        return _planes(x, cfa, lambda p: correlate(p, spatial))
    return _planes(x, cfa, lambda p: _bilateral(p, neighbourhood(p, kernel), spatial, sigma_color))


def _mosaic(x: torch.Tensor, cfa: CFA | None) -> bool:
    """Whether ``x`` is filtered as a mosaic of ``cfa`` (else channel by channel)."""
    return x.shape[1] == 1 and cfa is not None


def _planes(x: torch.Tensor, cfa: CFA | None, fn) -> torch.Tensor:
    """``fn`` on a Bayer mosaic's packed planes, or on an image's channels."""
    return per_plane(x, cfa, fn) if _mosaic(x, cfa) else fn(x)


class AntiAliasing(nn.Module):
    """Anti-aliasing stage (identity reverse); ``cfa`` None for an image's channels."""

    def __init__(self, cfa: CFA | None, method: str = "weighted_average", sigma: float = 0.5):
        super().__init__()
        self.cfa, self.method, self.sigma = cfa, method, sigma

    @property
    def radius(self) -> int:
        """Rows of context needed on each side (a plane window's reach on a mosaic)."""
        size = 3 if self.method != "gaussian" else gaussian_size(self.sigma)
        return plane_radius(size) if self.cfa is not None else size // 2

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return anti_alias(x, self.cfa, self.method, self.sigma)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x


class Denoise(nn.Module):
    """Denoising stage (identity reverse); ``cfa`` None after the demosaic."""

    def __init__(
        self,
        cfa: CFA | None = None,
        method: str = "bilateral",
        kernel: int = 5,
        sigma: float = 1.0,
        sigma_color: float = 0.05,
    ) -> None:
        super().__init__()
        self.cfa, self.method, self.kernel = cfa, method, kernel
        self.sigma, self.sigma_color = sigma, sigma_color

    @property
    def radius(self) -> int:
        """Rows of context needed on each side (a plane window's reach on a mosaic)."""
        return plane_radius(self.kernel) if self.cfa is not None else self.kernel // 2

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return denoise(x, self.cfa, self.method, self.kernel, self.sigma, self.sigma_color)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x
