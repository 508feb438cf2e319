"""The ``raw_denoise`` stage's module: :mod:`rawsim.denoise`'s methods on a normalised
mosaic (B, 1, H, W), white = 1, before anything mixes its sites. ``reverse`` is the
identity."""

from __future__ import annotations

import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.denoise.learned import learned_denoise
from rawsim.denoise.profiled import profiled_denoise

#: The method (as :meth:`rawsim.isp.config.RawDenoiseStage.resolve` records it) → its function.
METHODS = {"profiled": profiled_denoise, "learned": learned_denoise}


class RawDenoise(nn.Module):
    """Raw denoising by ``method`` (``profiled`` or ``learned``), with the noise model's
    per-colour ``gain`` and ``offset`` (normalised units) and ``strength``."""

    def __init__(self, cfa: CFA, method: str, gain, offset, strength: float = 1.0) -> None:
        super().__init__()
        self.cfa, self.method = cfa, method
        self.gain, self.offset, self.strength = gain, offset, strength

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return METHODS[self.method](x, self.cfa, self.gain, self.offset, self.strength)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x
