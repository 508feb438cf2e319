"""Tone curves and their exact inverses: smoothstep, Reinhard, ACES, Hable.

Every curve is normalised to map linear 0 → 0 and its white point 1 → 1
(``f(x) = g(x·W) / g(W)`` for a curve ``g`` with white ``W``), so that in
unprocessing a display value of 1 returns to the sensor's white level.

Domains:
  * ``smoothstep`` (Brooks et al. 2019, f(x) = 3x² − 2x³): defined on [0, 1] (the
    cubic is not monotone outside); forward clips its input there (renders of
    ordinary photos reach beyond white), reverse takes display values in [0, 1]
    only and raises :class:`ParameterError` otherwise.
  * ``reinhard`` (extended, white W = 4), ``aces`` (Narkowicz 2015 fit, white where
    it reaches 1, ≈ 7.24), ``hable`` (Uncharted 2, W = 11.2): forward on all reals —
    above 1 highlights compress towards the curve's asymptote, below 0 the curve
    continues as its tangent at 0, so negative noise passes through invertibly.
    Reverse is the closed-form root of each ratio of quadratics; values at or above
    the asymptote (ACES ≈ 1.033, Hable ≈ 1.21) raise :class:`ParameterError`.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from rawsim.errors import ParameterError, check_choice
from rawsim.isp.config import TONE_CURVES
from rawsim.isp.curves import (
    _A,
    _ACES_WHITE,
    _B,
    _C,
    _D,
    _E,
    _HA,
    _HABLE_WHITE,
    _HB,
    _HC,
    _HD,
    _HE,
    _HF,
    _REINHARD_WHITE,
    _aces,
    _hable,
    _reinhard,
)


def _root(qa, qb, qc):
    """The root 2c / (−b + √(b² − 4ac)) of a x² + b x + c, stable near c = 0."""
    return 2 * qc / (-qb + torch.sqrt((qb * qb - 4 * qa * qc).clamp_min(0)))


def _reinhard_inv(y):
    # Negated coefficients select the positive root (here a > 0 and c < 0).
    return _root(-1 / _REINHARD_WHITE**2, y - 1, y)


def _aces_inv(y):
    return _root(y * _C - _A, y * _D - _B, y * _E)


def _hable_inv(y):
    u = y + _HE / _HF
    return _root(_HA * (u - 1), _HB * (u - _HC), _HD * (_HF * u - _HE))


# name → (g, g⁻¹, white W, g'(0), asymptote of g or inf)
_CURVES = {
    "reinhard": (_reinhard, _reinhard_inv, _REINHARD_WHITE, 1.0, math.inf),
    "aces": (_aces, _aces_inv, _ACES_WHITE, _B / _E, _A / _C),
    "hable": (
        _hable,
        _hable_inv,
        _HABLE_WHITE,
        (_HC * _HB * _HD * _HF - _HD * _HE * _HB) / (_HD * _HF) ** 2,
        1 - _HE / _HF,
    ),
}


def _check_unit(x: torch.Tensor, curve: str) -> None:
    if bool((x < 0).any()) or bool((x > 1).any()):
        raise ParameterError(f"{curve} tone curve is defined on [0, 1]; input has values outside")


def apply_tone_curve(x: torch.Tensor, curve: str) -> torch.Tensor:
    """Tone-map linear values ``x`` (any shape) with ``curve``; f(0) = 0, f(1) = 1."""
    check_choice("tone curve", curve, TONE_CURVES)
    if curve == "none":
        return x
    if curve == "smoothstep":  # defined on [0, 1]: flat (0 and 1) outside
        x = x.clamp(0, 1)
        return x * x * (3 - 2 * x)
    g, _, white, slope0, _ = _CURVES[curve]
    scale = float(g(torch.tensor(white, dtype=torch.float64)))
    tangent = x * (slope0 * white / scale)
    return torch.where(x >= 0, g(x.clamp_min(0) * white) / scale, tangent)


def invert_tone_curve(y: torch.Tensor, curve: str) -> torch.Tensor:
    """Exact inverse of :func:`apply_tone_curve`: display values → linear values."""
    check_choice("tone curve", curve, TONE_CURVES)
    if curve == "none":
        return y
    if curve == "smoothstep":
        _check_unit(y, curve)
        # Brooks et al.: 0.5 − sin(asin(1 − 2y) / 3). At y = 0 and 1 the inverse is y
        # itself; taking that branch there keeps asin's infinite slope out of gradients.
        t = 1 - 2 * y
        inside = t.abs() < 1
        return torch.where(inside, 0.5 - torch.sin(torch.asin(torch.where(inside, t, 0)) / 3), y)
    _, g_inv, white, slope0, asymptote = _CURVES[curve]
    scale = float(_CURVES[curve][0](torch.tensor(white, dtype=torch.float64)))
    limit = asymptote / scale
    if bool((y >= limit).any()):
        raise ParameterError(f"{curve} tone curve never reaches {limit:.4g}; input has such values")
    tangent = y / (slope0 * white / scale)
    return torch.where(y >= 0, g_inv(y.clamp(0, limit * (1 - 1e-6)) * scale) / white, tangent)


class ToneCurve(nn.Module):
    """Tone-mapping stage: ``forward`` applies the curve, ``reverse`` inverts it."""

    def __init__(self, curve: str = "none") -> None:
        super().__init__()
        self.curve = check_choice("tone curve", curve, TONE_CURVES)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_tone_curve(x, self.curve)

    def reverse(self, y: torch.Tensor) -> torch.Tensor:
        return invert_tone_curve(y, self.curve)
