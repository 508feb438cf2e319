"""White-balance stage: per-channel gains on RGB images or on CFA mosaics.

Gains are (3,) or per-sample (B, 3) for camera (R, G, B), usually G = 1.
Images are linear, any range; nothing is clipped.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.cfa import CFA, apply_tile
from rawsim.errors import ParameterError, check_image
from rawsim.isp.config import SAFE_WB_THRESHOLD


def _gains(x: torch.Tensor, gains) -> torch.Tensor:
    g = torch.as_tensor(gains, dtype=x.dtype, device=x.device)
    if g.shape[-1] != 3 or g.ndim not in (1, 2):
        raise ParameterError(f"white-balance gains must be (3,) or (B, 3), got {tuple(g.shape)}")
    if not bool((g > 0).all()):
        raise ParameterError("white-balance gains must be positive")
    return g.reshape(-1, 3)


def _scale(x: torch.Tensor, gains, cfa: CFA | None, op) -> torch.Tensor:
    g = _gains(x, gains)
    if x.shape[1] == 3:
        return op(x, g.reshape(-1, 3, 1, 1))
    if cfa is None:
        raise ParameterError("a mosaic (B, 1, H, W) needs its CFA pattern")
    return apply_tile(x, cfa.tile(g), op)


def apply_white_balance(x: torch.Tensor, gains, cfa: CFA | None = None) -> torch.Tensor:
    """Multiply by the gains: RGB (B, 3, H, W), or a mosaic (B, 1, H, W) with its ``cfa``."""
    check_image(x, "image")
    return _scale(x, gains, cfa, torch.mul)


def invert_white_balance(x: torch.Tensor, gains, cfa: CFA | None = None) -> torch.Tensor:
    """Exact inverse of :func:`apply_white_balance` (divide by the gains)."""
    check_image(x, "image")
    return _scale(x, gains, cfa, torch.div)


def safe_invert_white_balance(
    rgb: torch.Tensor, gains, threshold: float = SAFE_WB_THRESHOLD
) -> torch.Tensor:
    """Highlight-preserving inverse white balance (Brooks et al. 2019), RGB only.

    Dividing by gains > 1 would leave near-white pixels below the white level in
    R and B, so after the forward gains and clipping they would turn pink. Where the
    channel mean exceeds ``threshold`` the factor blends towards 1:

    ``mask = (max(gray − t, 0) / (1 − t))²``,
    ``factor = max(mask + (1 − mask) / g, 1 / g)``.

    Exactly :func:`invert_white_balance` where gray ≤ ``threshold``; elsewhere the
    map is not inverted by :func:`apply_white_balance`.

    Args:
        rgb: (B, 3, H, W) linear camera RGB, white at 1.
        gains: (3,) or (B, 3) forward gains.
        threshold: gray level where blending starts, in (0, 1).
    """
    check_image(rgb, "image", channels=3)
    if not 0 < threshold < 1:
        raise ParameterError(f"threshold must be in (0, 1), got {threshold}")
    inv = 1 / _gains(rgb, gains).reshape(-1, 3, 1, 1)
    gray = rgb.mean(dim=1, keepdim=True)
    mask = ((gray - threshold).clamp_min(0) / (1 - threshold)) ** 2
    # max(mask + (1 − mask)/g, 1/g) = 1/g + mask · max(1 − 1/g, 0) for mask in [0, 1].
    return rgb * (inv + mask * (1 - inv).clamp_min(0))


class WhiteBalance(nn.Module):
    """White-balance stage. ``reverse`` is the exact inverse, or the safe one if ``safe``."""

    def __init__(self, gains, cfa: CFA | None = None, safe: bool = False) -> None:
        super().__init__()
        self.register_buffer("gains", torch.as_tensor(gains, dtype=torch.float32))
        self.cfa = cfa
        self.safe = safe

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_white_balance(x, self.gains, self.cfa)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        if self.safe:
            return safe_invert_white_balance(x, self.gains)
        return invert_white_balance(x, self.gains, self.cfa)
