"""Highlight handling after white balance: clip, or blend (dcraw's method).

White-balance gains push saturated sites above 1 by different amounts per
channel, which turns clipped highlights magenta. ``clip`` limits every value to
1 (the one intended clipping here; value by value, so on a mosaic of any CFA
as on RGB, as LibRaw does before demosaicking). ``blend`` (RGB only) keeps
the clipped image's lightness and the unclipped image's hue, with the chroma
scaled to the clipped chroma's size, where any channel exceeds 1 — dcraw's
``-H 2``.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.errors import ParameterError, check_choice, check_image
from rawsim.isp.config import HIGHLIGHT_MODES, HIGHLIGHT_TRANSFORM

# An orthonormal-ish transform separating lightness from two chroma axes (dcraw).
_TRANS = torch.tensor(HIGHLIGHT_TRANSFORM, dtype=torch.float64)


def handle_highlights(x: torch.Tensor, mode: str = "clip") -> torch.Tensor:
    """Apply ``mode`` to white-balanced linear data, white = 1: a mosaic (B, 1, H, W) of
    any CFA or an image (B, C, H, W) for ``clip`` (values ≤ 1 out), RGB (B, 3, H, W)
    for ``blend`` (values above 1 may remain)."""
    check_choice("highlight mode", mode, HIGHLIGHT_MODES)
    check_image(x, "image")
    if mode == "clip":
        return x.clamp(max=1.0)
    if x.shape[1] != 3:
        raise ParameterError("highlight mode 'blend' needs RGB: put the stage after demosaic")
    trans = _TRANS.to(x.dtype).to(x.device)
    inverse = torch.linalg.inv(_TRANS).to(x.dtype).to(x.device)
    clipped = x.clamp(max=1.0)
    cam = torch.einsum("ij,bjhw->bihw", trans, x)
    lab = torch.einsum("ij,bjhw->bihw", trans, clipped)
    chroma_cam = (cam[:, 1:] ** 2).sum(1, keepdim=True)
    chroma_lab = (lab[:, 1:] ** 2).sum(1, keepdim=True)
    # Fully clipped pixels have no chroma left: clamp inside the root keeps its
    # gradient finite there (the value changes by < 1e-15).
    scale = torch.sqrt((chroma_lab / chroma_cam.clamp_min(1e-20)).clamp_min(1e-30))
    blended = torch.cat([lab[:, :1], cam[:, 1:] * scale], dim=1)
    out = torch.einsum("ij,bjhw->bihw", inverse, blended)
    over = (x > 1).any(dim=1, keepdim=True)
    return torch.where(over, out, x)


class Highlights(nn.Module):
    """Highlight stage; ``reverse`` is the identity (clipped values are lost)."""

    def __init__(self, mode: str = "clip") -> None:
        super().__init__()
        self.mode = check_choice("highlight mode", mode, HIGHLIGHT_MODES)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return handle_highlights(x, self.mode)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x
