"""RGB ↔ YCbCr, ITU-R BT.601, full range, chroma offset 0.5 (exact inverse)."""

from __future__ import annotations

import torch
from torch import nn

from rawsim.errors import check_image

_KR, _KB = 0.299, 0.114
_KG = 1 - _KR - _KB


def rgb_to_ycbcr(rgb: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W) RGB → (B, 3, H, W) Y, Cb, Cr; RGB in [0, 1] gives Y, Cb, Cr in [0, 1]."""
    check_image(rgb, "image", channels=3)
    r, g, b = rgb.unbind(1)
    y = _KR * r + _KG * g + _KB * b
    cb = (b - y) / (2 * (1 - _KB)) + 0.5
    cr = (r - y) / (2 * (1 - _KR)) + 0.5
    return torch.stack([y, cb, cr], dim=1)


def ycbcr_to_rgb(ycc: torch.Tensor) -> torch.Tensor:
    """Exact inverse of :func:`rgb_to_ycbcr` (Cb goes to blue, Cr to red)."""
    check_image(ycc, "image", channels=3)
    y, cb, cr = ycc.unbind(1)
    r = y + 2 * (1 - _KR) * (cr - 0.5)
    b = y + 2 * (1 - _KB) * (cb - 0.5)
    g = (y - _KR * r - _KB * b) / _KG
    return torch.stack([r, g, b], dim=1)


class ColorSpaceConversion(nn.Module):
    """RGB → YCbCr stage; ``reverse`` converts back."""

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        return rgb_to_ycbcr(rgb)

    def reverse(self, ycc: torch.Tensor) -> torch.Tensor:
        return ycbcr_to_rgb(ycc)
