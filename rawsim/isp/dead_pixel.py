"""Dead/hot pixel correction on a CFA mosaic, within each colour.

Each site is compared with the median of its same-colour neighbours (the
original design used their mean, which a hot pixel drags along with it, so its
neighbours got "corrected" too); where it deviates by more than ``threshold``
(linear units, white = 1) it is replaced by that median, blended through a
sigmoid of width ``temperature`` so the stage stays differentiable. ``reverse``
is the identity (defects are not re-created).

The neighbours are those of :mod:`rawsim.isp.planes` for a ``kernel``×``kernel``
window of plane pixels, ``2·(kernel // 2)`` mosaic pixels on each side: on a
Bayer mosaic the other sites of the site's plane (R, Gr, Gb or B: 8 for
``kernel`` 3, 24 for 5); on any other pattern the other sites of its colour in
that window (X-Trans: 5 red or blue and 12 or 16 green for ``kernel`` 3; 16 and
44 for 5). An even count takes the lower of the two middle values.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import ParameterError, check_image
from rawsim.isp.planes import neighbourhood, per_plane, per_site, plane_radius


def _replace_outliers(
    sites: torch.Tensor, others: torch.Tensor, threshold: float, temperature: float
) -> torch.Tensor:
    """``sites`` (…) blended towards the median of ``others`` (N, …) where they differ by
    more than ``threshold``."""
    reference = others.median(dim=0).values
    weight = torch.sigmoid(((sites - reference).abs() - threshold) / temperature)
    return sites + weight * (reference - sites)


def correct_dead_pixels(
    mosaic: torch.Tensor,
    cfa: CFA,
    threshold: float = 0.1,
    kernel: int = 3,
    temperature: float = 0.01,
) -> torch.Tensor:
    """(B, 1, H, W) linear mosaic (white = 1, any range) of any periodic ``cfa`` → the
    same with outliers replaced by their same-colour neighbours' median. Not clipped.
    """
    check_image(mosaic, "mosaic", channels=1)
    if kernel not in (3, 5):
        raise ParameterError(f"dead-pixel kernel must be 3 or 5, got {kernel}")
    if not threshold > 0 or not temperature > 0:
        raise ParameterError("dead-pixel threshold and temperature must be > 0")

    if not cfa.is_bayer:
        return per_site(
            mosaic,
            cfa,
            plane_radius(kernel),
            lambda sites, values, _: _replace_outliers(
                sites, torch.stack(values), threshold, temperature
            ),
            centre=False,
        )

    def fix(planes: torch.Tensor) -> torch.Tensor:
        shifted = neighbourhood(planes, kernel)
        centre = kernel * kernel // 2
        others = torch.cat([shifted[:centre], shifted[centre + 1 :]])
        return _replace_outliers(planes, others, threshold, temperature)

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
        """Rows of context needed on each side (the window, in mosaic rows), any pattern."""
        return plane_radius(self.kernel)

    def forward(self, mosaic: torch.Tensor) -> torch.Tensor:
        return correct_dead_pixels(mosaic, self.cfa, self.threshold, self.kernel, self.temperature)

    def reverse(self, mosaic: torch.Tensor) -> torch.Tensor:
        return mosaic
