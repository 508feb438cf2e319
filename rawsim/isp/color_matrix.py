"""Colour-correction matrix stage: ``out = M @ rgb + b`` per pixel.

Acts on (B, 3, H, W) linear images of any range; nothing is clipped. The
matrix is (3, 3) or per-sample (B, 3, 3); the optional bias is (3,) or (B, 3).
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim import color
from rawsim.errors import ParameterError, check_image


def _batched(matrix: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    m = torch.as_tensor(matrix, dtype=x.dtype, device=x.device)
    if m.shape[-2:] != (3, 3) or m.ndim not in (2, 3):
        raise ParameterError(f"colour matrix must be (3, 3) or (B, 3, 3), got {tuple(m.shape)}")
    return m if m.ndim == 3 else m.unsqueeze(0)


def _bias(bias, x: torch.Tensor) -> torch.Tensor | None:
    if bias is None:
        return None
    b = torch.as_tensor(bias, dtype=x.dtype, device=x.device)
    if b.shape[-1] != 3 or b.ndim not in (1, 2):
        raise ParameterError(f"colour bias must be (3,) or (B, 3), got {tuple(b.shape)}")
    return b.reshape(-1, 3, 1, 1)


def apply_color_matrix(x: torch.Tensor, matrix, bias=None) -> torch.Tensor:
    """(B, 3, H, W) → (B, 3, H, W): ``M @ x + b`` at every pixel."""
    check_image(x, "image", channels=3)
    out = torch.einsum("bij,bjhw->bihw", _batched(matrix, x).expand(x.shape[0], 3, 3), x)
    b = _bias(bias, x)
    return out if b is None else out + b


def invert_color_matrix(y: torch.Tensor, matrix, bias=None) -> torch.Tensor:
    """Exact inverse of :func:`apply_color_matrix`: ``M⁻¹ @ (y − b)``."""
    check_image(y, "image", channels=3)
    b = _bias(bias, y)
    m = _batched(matrix, y).to(torch.float64)
    if bool((torch.linalg.det(m).abs() < 1e-12).any()):
        raise ParameterError("colour matrix is singular and cannot be inverted")
    inv = torch.linalg.inv(m).to(y.dtype)
    return apply_color_matrix(y if b is None else y - b, inv)


def split_seed_matrix(values) -> tuple[torch.Tensor, torch.Tensor | None]:
    """:func:`rawsim.color.split_seed_matrix` as float64 tensors."""
    matrix, bias = color.split_seed_matrix(values)
    return torch.from_numpy(matrix), None if bias is None else torch.from_numpy(bias)


class ColorMatrix(nn.Module):
    """Colour-correction stage: ``forward`` applies ``M x + b``, ``reverse`` inverts it."""

    def __init__(self, matrix, bias=None) -> None:
        super().__init__()
        self.register_buffer("matrix", torch.as_tensor(matrix, dtype=torch.float32))
        self.register_buffer("bias", None if bias is None else torch.as_tensor(bias).float())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_color_matrix(x, self.matrix, self.bias)

    def reverse(self, y: torch.Tensor) -> torch.Tensor:
        return invert_color_matrix(y, self.matrix, self.bias)
