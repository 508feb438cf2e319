"""EXIF/TIFF orientation (1–8): turn stored pixels into display orientation and back."""

from __future__ import annotations

import torch
from torch import nn

from rawsim.errors import ParameterError
from rawsim.isp.config import ORIENTATION_OPS

_OPS = ORIENTATION_OPS


def _check(orientation: int) -> tuple[bool, bool, bool]:
    if orientation not in _OPS:
        raise ParameterError(f"orientation must be 1–8, got {orientation}")
    return _OPS[orientation]


def apply_orientation(x: torch.Tensor, orientation: int) -> torch.Tensor:
    """Stored (…, H, W) → as displayed (orientation 6: rotate 90° clockwise)."""
    transpose, flip_rows, flip_cols = _check(orientation)
    if transpose:
        x = x.transpose(-2, -1)
    dims = [d for d, f in ((-2, flip_rows), (-1, flip_cols)) if f]
    return x.flip(dims) if dims else x


def undo_orientation(x: torch.Tensor, orientation: int) -> torch.Tensor:
    """Inverse of :func:`apply_orientation`."""
    transpose, flip_rows, flip_cols = _check(orientation)
    dims = [d for d, f in ((-2, flip_rows), (-1, flip_cols)) if f]
    x = x.flip(dims) if dims else x
    return x.transpose(-2, -1) if transpose else x


class Orientation(nn.Module):
    """Orientation stage: ``forward`` to display orientation, ``reverse`` back."""

    def __init__(self, orientation: int = 1) -> None:
        super().__init__()
        _check(orientation)
        self.orientation = orientation

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_orientation(x, self.orientation)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return undo_orientation(x, self.orientation)
