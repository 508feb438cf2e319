"""Spatial filters: anti-aliasing (on the mosaic, per CFA plane) and denoising.

Both act plane by plane on a mosaic (B, 1, H, W) when given its CFA, or channel
by channel on an image (B, C, H, W). ``reverse`` is the identity for both.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import ParameterError, check_choice, check_image
from rawsim.isp.config import ANTI_ALIAS_METHODS, DENOISE_METHODS
from rawsim.isp.planes import correlate, gaussian_kernel, neighbourhood, per_plane

_WEIGHTED_AVERAGE = torch.tensor([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 16


def _on_planes(x: torch.Tensor, cfa: CFA | None, fn) -> torch.Tensor:
    check_image(x, "image")
    if x.shape[1] == 1 and cfa is not None:
        return per_plane(x, cfa, fn)
    return fn(x)


def anti_alias(
    x: torch.Tensor, cfa: CFA | None, method: str = "weighted_average", sigma: float = 0.5
) -> torch.Tensor:
    """Small blur: 3×3 binomial (``weighted_average``) or a Gaussian of ``sigma`` plane pixels."""
    check_choice("anti-aliasing method", method, ANTI_ALIAS_METHODS)
    if method == "none":
        return x
    if not sigma > 0:
        raise ParameterError(f"anti-aliasing sigma must be > 0, got {sigma}")
    kernel = _WEIGHTED_AVERAGE if method == "weighted_average" else gaussian_kernel(sigma)
    return _on_planes(x, cfa, lambda p: correlate(p, kernel))


def denoise(
    x: torch.Tensor,
    cfa: CFA | None = None,
    method: str = "bilateral",
    kernel: int = 5,
    sigma: float = 1.0,
    sigma_color: float = 0.05,
) -> torch.Tensor:
    """Gaussian blur, or an edge-preserving bilateral filter (range σ ``sigma_color``).

    ``sigma`` is the spatial σ in pixels (of the plane, on a mosaic); values are
    linear, any range.
    """
    check_choice("denoise method", method, DENOISE_METHODS)
    if method == "none":
        return x
    if kernel % 2 == 0 or kernel < 3:
        raise ParameterError(f"denoise kernel must be odd and ≥ 3, got {kernel}")
    if not sigma > 0 or not sigma_color > 0:
        raise ParameterError("denoise sigma and sigma_color must be > 0")
    spatial = gaussian_kernel(sigma, kernel)
    if method == "gaussian":
        return _on_planes(x, cfa, lambda p: correlate(p, spatial))

    def bilateral(p: torch.Tensor) -> torch.Tensor:
        shifted = neighbourhood(p, kernel)
        w = spatial.reshape(-1, 1, 1, 1, 1).to(p) * torch.exp(
            -((shifted - p) ** 2) / (2 * sigma_color**2)
        )
        return (w * shifted).sum(0) / w.sum(0)

    return _on_planes(x, cfa, bilateral)


class AntiAliasing(nn.Module):
    """Anti-aliasing stage (identity reverse)."""

    def __init__(self, cfa: CFA | None, method: str = "weighted_average", sigma: float = 0.5):
        super().__init__()
        self.cfa, self.method, self.sigma = cfa, method, sigma

    @property
    def radius(self) -> int:
        """Rows of context needed on each side (doubled on a mosaic's planes)."""
        size = 3 if self.method != "gaussian" else gaussian_kernel(self.sigma).shape[0]
        return (size // 2) * (2 if self.cfa is not None else 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return anti_alias(x, self.cfa, self.method, self.sigma)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x


class Denoise(nn.Module):
    """Denoising stage (identity reverse)."""

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
        """Rows of context needed on each side (doubled on a mosaic's planes)."""
        return (self.kernel // 2) * (2 if self.cfa is not None else 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return denoise(x, self.cfa, self.method, self.kernel, self.sigma, self.sigma_color)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x
