"""Black/white levels, saturation and quantisation of raw digital numbers (DN).

``normalize_levels`` maps DN to linear units where black is 0 and white is 1
(the seed's BlackLevelCompensation, without its clamp: values below black stay
negative so read noise survives). ``saturate`` is the one place where values are
clipped, because a real sensor saturates at its white level.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.cfa import apply_tile
from rawsim.errors import ParameterError


def _check_levels(black, white) -> None:
    b = torch.as_tensor(black)
    if not bool((torch.as_tensor(white) > b).all()):
        raise ParameterError(f"white level must exceed black level (black {black}, white {white})")


def normalize_levels(dn: torch.Tensor, black, white) -> torch.Tensor:
    """DN → linear units: ``(dn − black) / (white − black)``. No clipping.

    ``black`` is a number or a tensor broadcastable to ``dn`` (e.g. per-site).
    """
    _check_levels(black, white)
    return (dn - black) / (white - black)


def denormalize_levels(x: torch.Tensor, black, white) -> torch.Tensor:
    """Linear units → DN: ``black + x · (white − black)``. No clipping or rounding."""
    _check_levels(black, white)
    return black + x * (white - black)


def saturate(dn: torch.Tensor, white) -> torch.Tensor:
    """Clip DN to the physical range [0, white]: the sensor's saturation, a named step."""
    return dn.clamp(0, float(white))


def quantize(dn: torch.Tensor) -> torch.Tensor:
    """Round DN to integers (half to even). The gradient passes straight through."""
    if not dn.requires_grad:
        return torch.round(dn)
    return dn + (torch.round(dn) - dn).detach()


def white_level_for_bits(bits: int) -> int:
    """``2**bits − 1``, the largest code of an unsigned ``bits``-bit sample."""
    if not 1 <= int(bits) <= 16:
        raise ParameterError(f"bit depth must be in 1..16, got {bits}")
    return 2 ** int(bits) - 1


class Levels(nn.Module):
    """Black-level stage: ``forward`` DN → [0, 1] units, ``reverse`` back to DN.

    ``black`` is a number, a tensor broadcastable to the data, or a (…, 2, 2) CFA
    tile of per-site levels, repeated over the data (whose first row and column
    are the tile's); a tile of another period (X-Trans: (…, 6, 6)) with
    ``period`` set to it.
    """

    def __init__(self, black, white, period: tuple[int, int] = (2, 2)) -> None:
        super().__init__()
        _check_levels(black, white)
        self.black, self.white, self.period = black, white, tuple(period)

    def _tiled(self) -> bool:
        return isinstance(self.black, torch.Tensor) and self.black.shape[-2:] == self.period

    def forward(self, dn: torch.Tensor) -> torch.Tensor:
        if self._tiled():
            return apply_tile(dn, self.black, lambda x, b: normalize_levels(x, b, self.white))
        return normalize_levels(dn, self.black, self.white)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        if self._tiled():
            return apply_tile(x, self.black, lambda y, b: denormalize_levels(y, b, self.white))
        return denormalize_levels(x, self.black, self.white)


class Saturation(nn.Module):
    """Saturation at the white level (and at 0 DN): clips, by design."""

    def __init__(self, white) -> None:
        super().__init__()
        self.white = white

    def forward(self, dn: torch.Tensor) -> torch.Tensor:
        return saturate(dn, self.white)
