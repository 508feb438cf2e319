"""Dead/hot pixel correction on a CFA mosaic, within each colour plane.

Each site is compared with the median of its same-colour neighbours (the
original design used their mean, which a hot pixel drags along with it, so its
neighbours got "corrected" too); where it deviates by more than ``threshold``
(linear units, white = 1) it is replaced by that median, blended through a
sigmoid of width ``temperature`` so the stage stays differentiable. ``reverse``
is the identity (defects are not re-created).
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import ParameterError, check_image
from rawsim.isp.planes import neighbourhood, per_plane


def correct_dead_pixels(
    mosaic: torch.Tensor,
    cfa: CFA,
    threshold: float = 0.1,
    kernel: int = 3,
    temperature: float = 0.01,
) -> torch.Tensor:
    """(B, 1, H, W) linear mosaic → the same with outliers replaced by their neighbours' median."""
    check_image(mosaic, "mosaic", channels=1)
    if kernel not in (3, 5):
        raise ParameterError(f"dead-pixel kernel must be 3 or 5, got {kernel}")
    if not threshold > 0 or not temperature > 0:
        raise ParameterError("dead-pixel threshold and temperature must be > 0")

    def fix(planes: torch.Tensor) -> torch.Tensor:
        shifted = neighbourhood(planes, kernel)
        centre = kernel * kernel // 2
        others = torch.cat([shifted[:centre], shifted[centre + 1 :]])
        reference = others.median(dim=0).values
        weight = torch.sigmoid(((planes - reference).abs() - threshold) / temperature)
        return planes + weight * (reference - planes)

    return per_plane(mosaic, cfa, fix)


class DeadPixelCorrection(nn.Module):
    """Dead-pixel stage (forward corrects; reverse is the identity)."""

    def __init__(
        self, cfa: CFA, threshold: float = 0.1, kernel: int = 3, temperature: float = 0.01
    ) -> None:
        super().__init__()
        self.cfa, self.threshold, self.kernel, self.temperature = (
            cfa,
            threshold,
            kernel,
            temperature,
        )

    @property
    def radius(self) -> int:
        """Rows of context needed on each side (the neighbourhood, in mosaic rows)."""
        return 2 * (self.kernel // 2)

    def forward(self, mosaic: torch.Tensor) -> torch.Tensor:
        return correct_dead_pixels(mosaic, self.cfa, self.threshold, self.kernel, self.temperature)

    def reverse(self, mosaic: torch.Tensor) -> torch.Tensor:
        return mosaic
