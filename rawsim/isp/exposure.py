"""Exposure: scale linear light by 2^EV (``reverse`` divides)."""

from __future__ import annotations

import torch
from torch import nn


def apply_exposure(x: torch.Tensor, ev: float) -> torch.Tensor:
    """``x · 2^ev``; any shape, linear values."""
    return x if ev == 0 else x * (2.0**ev)


class Exposure(nn.Module):
    """Exposure stage."""

    def __init__(self, ev: float = 0.0) -> None:
        super().__init__()
        self.ev = float(ev)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_exposure(x, self.ev)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return apply_exposure(x, -self.ev)
