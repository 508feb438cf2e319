"""Transfer functions (OETFs): exact sRGB (IEC 61966-2-1), BT.2020's, ROMM RGB's,
power gamma, linear.

``forward`` encodes linear light for display; ``reverse`` decodes display values
back to linear light. Nominal domain [0, 1]; values outside it are not clipped:
the toe curves (sRGB, BT.2020, ROMM; :class:`rawsim.colorspaces.ToeCurve`)
continue linearly below 0 and as their power law above 1; the power law is
extended as an odd function. Every value keeps an exact inverse. The toe curves'
formulas are the ones the compiled engine tabulates (one definition, in
:mod:`rawsim.colorspaces`); their gradients are finite everywhere.
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.colorspaces import BT2020_CURVE, ROMM_CURVE, SRGB_CURVE, TransferSpec
from rawsim.errors import ParameterError


def _signed_pow(x: torch.Tensor, exponent: float) -> torch.Tensor:
    # Clamp inside the power so the gradient stays finite at 0.
    return torch.sign(x) * x.abs().clamp_min(1e-12).pow(exponent)


def srgb_decode(v: torch.Tensor) -> torch.Tensor:
    """sRGB-encoded values → linear light. Any shape; linear below 0, power law above 1."""
    return SRGB_CURVE.decode(v)


def srgb_encode(x: torch.Tensor) -> torch.Tensor:
    """Linear light → sRGB-encoded values. Any shape; linear below 0, power law above 1."""
    return SRGB_CURVE.encode(x)


def bt2020_encode(x: torch.Tensor) -> torch.Tensor:
    """Linear light → ITU-R BT.2020 (BT.709) OETF values: 4.5·x below 0.018054, else
    1.0993·x^0.45 − 0.0993. Any shape; linear below 0, power law above 1."""
    return BT2020_CURVE.encode(x)


def bt2020_decode(v: torch.Tensor) -> torch.Tensor:
    """BT.2020 OETF values → linear light (the OETF's inverse). Any shape."""
    return BT2020_CURVE.decode(v)


def romm_encode(x: torch.Tensor) -> torch.Tensor:
    """Linear light → ROMM RGB (ProPhoto) values: 16·x below 1/512, else x^(1/1.8).
    Any shape; linear below 0, power law above 1."""
    return ROMM_CURVE.encode(x)


def romm_decode(v: torch.Tensor) -> torch.Tensor:
    """ROMM RGB (ProPhoto) values → linear light. Any shape."""
    return ROMM_CURVE.decode(v)


def gamma_decode(v: torch.Tensor, gamma: float = 2.2) -> torch.Tensor:
    """Power-law decode ``sign(v)·|v|^gamma`` (the seed's ``gamma_param``). Any shape;
    the gradient is finite but large within 1e-12 of 0 (|v| is clamped there)."""
    _check_gamma(gamma)
    return _signed_pow(v, gamma)


def gamma_encode(x: torch.Tensor, gamma: float = 2.2) -> torch.Tensor:
    """Power-law encode ``sign(x)·|x|^(1/gamma)``. Any shape; as :func:`gamma_decode`
    near 0."""
    _check_gamma(gamma)
    return _signed_pow(x, 1.0 / gamma)


def _check_gamma(gamma: float) -> None:
    if not gamma > 0:
        raise ParameterError(f"gamma must be > 0, got {gamma}")


def apply_transfer(x: torch.Tensor, spec: TransferSpec) -> torch.Tensor:
    """Linear light → display values through ``spec``'s function. Any shape."""
    if spec.curve is not None:
        return spec.curve.encode(x)
    if spec.kind == "gamma":
        return gamma_encode(x, spec.gamma)
    if spec.kind == "linear":
        return x
    raise ParameterError(f"unknown transfer {spec.kind!r}")


def invert_transfer(v: torch.Tensor, spec: TransferSpec) -> torch.Tensor:
    """Display values → linear light through ``spec``'s function. Any shape."""
    if spec.curve is not None:
        return spec.curve.decode(v)
    if spec.kind == "gamma":
        return gamma_decode(v, spec.gamma)
    if spec.kind == "linear":
        return v
    raise ParameterError(f"unknown transfer {spec.kind!r}")


class Transfer(nn.Module):
    """Output transfer stage: ``forward`` encodes linear → display, ``reverse`` decodes.

    ``transfer``: a name :meth:`TransferSpec.parse` takes (``srgb``, ``bt2020``,
    ``romm``, ``gamma:G``, ``linear``), or a :class:`TransferSpec`.
    """

    def __init__(self, transfer: str | TransferSpec = "srgb") -> None:
        super().__init__()
        self.spec = TransferSpec.parse(transfer)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_transfer(x, self.spec)

    def reverse(self, v: torch.Tensor) -> torch.Tensor:
        return invert_transfer(v, self.spec)
