"""Lens shading: a radial gain V(r) = 1 + k1 r² + k2 r⁴ + k3 r⁶ (r = 1 at the corners).

``forward`` corrects shading (multiplies by the gain); ``reverse`` divides by it,
which adds vignetting — the unprocessing direction. The gain is evaluated at
each pixel's own position, so on a mosaic of any CFA (Bayer, X-Trans, …) every
site gets the value of where it lies, whatever its colour; the stage needs no
context (strips give it their first row and the full height, ``region``).
Values are linear, any range; nothing is clipped.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.errors import ParameterError, check_image
from rawsim.isp.config import DEFAULT_K


def radial_gain(
    height: int,
    width: int,
    k=DEFAULT_K,
    strength: float = 1.0,
    device=None,
    dtype=torch.float32,
    top: int = 0,
    full_height: int | None = None,
) -> torch.Tensor:
    """Gain map (1, 1, H, W): ``1 + strength · (V(r) − 1)``, ≥ 1 for k ≥ 0, 1 at the centre.

    With ``full_height``, the map is rows ``top`` … ``top + height`` of the map of
    a ``full_height`` × ``width`` image (for processing in strips).
    """
    full = height if full_height is None else full_height
    k1, k2, k3 = (float(v) for v in k)
    if strength < 0:
        raise ParameterError(f"lens shading strength must be ≥ 0, got {strength}")
    y = torch.arange(top, top + height, device=device, dtype=torch.float64) - (full - 1) / 2
    x = torch.arange(width, device=device, dtype=torch.float64) - (width - 1) / 2
    r2 = (y[:, None] ** 2 + x[None, :] ** 2) / (((full - 1) / 2) ** 2 + ((width - 1) / 2) ** 2)
    v = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    gain = 1 + strength * (v - 1)
    if bool((gain <= 0).any()):
        raise ParameterError(f"lens shading gain must stay positive (k={k}, strength={strength})")
    return gain.to(dtype)[None, None]


def apply_lens_shading(x: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
    """Correct shading: (B, C, H, W) · gain (1, 1, H, W)."""
    check_image(x, "image")
    return x * gain.to(x.dtype)


def invert_lens_shading(x: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
    """Add vignetting: (B, C, H, W) / gain (1, 1, H, W)."""
    check_image(x, "image")
    return x / gain.to(x.dtype)


class LensShading(nn.Module):
    """Lens-shading stage with the radial model (or an explicit gain map)."""

    def __init__(self, k=DEFAULT_K, strength: float = 1.0, gain_map: torch.Tensor | None = None):
        super().__init__()
        self.k, self.strength, self.gain_map = tuple(k), strength, gain_map

    #: The gain depends on where the pixels are: see ``region``.
    positional = True

    def _gain(self, x: torch.Tensor, region) -> torch.Tensor:
        top, full_height = region if region is not None else (0, x.shape[-2])
        if self.gain_map is not None:
            return self.gain_map[..., top : top + x.shape[-2], :]
        return radial_gain(
            *x.shape[-2:], self.k, self.strength, x.device, x.dtype, top, full_height
        )

    def forward(self, x: torch.Tensor, region: tuple[int, int] | None = None) -> torch.Tensor:
        """``region`` = (first row, full height) when ``x`` is a strip of a taller image."""
        return apply_lens_shading(x, self._gain(x, region))

    def reverse(self, x: torch.Tensor, region: tuple[int, int] | None = None) -> torch.Tensor:
        return invert_lens_shading(x, self._gain(x, region))
