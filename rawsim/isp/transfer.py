"""Transfer functions (OETFs): exact sRGB (IEC 61966-2-1), power gamma, linear.

``forward`` encodes linear light for display; ``reverse`` decodes display values
back to linear light. Nominal domain [0, 1]; values outside it are not clipped:
sRGB's linear toe continues below 0 and its power segment above 1; the power
law is extended as an odd function. Every value keeps an exact inverse.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.errors import ParameterError
from rawsim.isp.curves import (
    _SRGB_A,
    _SRGB_DECODE_KNEE,
    _SRGB_ENCODE_KNEE,
    _SRGB_GAMMA,
    _SRGB_SLOPE,
    TransferSpec,
)


def _signed_pow(x: torch.Tensor, exponent: float) -> torch.Tensor:
    # Clamp inside the power so the gradient stays finite at 0.
    return torch.sign(x) * x.abs().clamp_min(1e-12).pow(exponent)


def srgb_decode(v: torch.Tensor) -> torch.Tensor:
    """sRGB-encoded values → linear light. Any shape; linear below 0, power law above 1."""
    power = ((v.clamp_min(_SRGB_DECODE_KNEE) + _SRGB_A) / (1 + _SRGB_A)).pow(_SRGB_GAMMA)
    return torch.where(v <= _SRGB_DECODE_KNEE, v / _SRGB_SLOPE, power)


def srgb_encode(x: torch.Tensor) -> torch.Tensor:
    """Linear light → sRGB-encoded values. Any shape; linear below 0, power law above 1."""
    power = x.clamp_min(_SRGB_ENCODE_KNEE).pow(1 / _SRGB_GAMMA).mul_(1 + _SRGB_A).sub_(_SRGB_A)
    return torch.where(x <= _SRGB_ENCODE_KNEE, x * _SRGB_SLOPE, power)


def gamma_decode(v: torch.Tensor, gamma: float = 2.2) -> torch.Tensor:
    """Power-law decode ``sign(v)·|v|^gamma`` (the seed's ``gamma_param``)."""
    _check_gamma(gamma)
    return _signed_pow(v, gamma)


def gamma_encode(x: torch.Tensor, gamma: float = 2.2) -> torch.Tensor:
    """Power-law encode ``sign(x)·|x|^(1/gamma)``."""
    _check_gamma(gamma)
    return _signed_pow(x, 1.0 / gamma)


def _check_gamma(gamma: float) -> None:
    if not gamma > 0:
        raise ParameterError(f"gamma must be > 0, got {gamma}")


def apply_transfer(x: torch.Tensor, spec: TransferSpec) -> torch.Tensor:
    """Linear light → display values through ``spec``'s function. Any shape."""
    if spec.kind == "srgb":
        return srgb_encode(x)
    if spec.kind == "gamma":
        return gamma_encode(x, spec.gamma)
    return x


def invert_transfer(v: torch.Tensor, spec: TransferSpec) -> torch.Tensor:
    """Display values → linear light through ``spec``'s function. Any shape."""
    if spec.kind == "srgb":
        return srgb_decode(v)
    if spec.kind == "gamma":
        return gamma_decode(v, spec.gamma)
    return v


class Transfer(nn.Module):
    """Output transfer stage: ``forward`` encodes linear → display, ``reverse`` decodes."""

    def __init__(self, transfer: str = "srgb") -> None:
        super().__init__()
        self.spec = TransferSpec.parse(transfer)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_transfer(x, self.spec)

    def reverse(self, v: torch.Tensor) -> torch.Tensor:
        return invert_transfer(v, self.spec)
