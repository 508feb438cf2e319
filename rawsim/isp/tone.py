"""Tone curves and their exact inverses: smoothstep, Reinhard, ACES, Hable.

Every curve maps linear 0 → 0. The filmic ones take an ``exposure`` (stops of
gain before the curve, 0 to 4) and a white point ``W`` in the curve's own units
(:func:`rawsim.isp.curves.filmic`): ``f(x) = g(2^exposure · W · x) / g(W)``.
Defaults (exposure 0, each curve's W) map the sensor's white 1 → 1, so that in
unprocessing a display value of 1 returns to the sensor's white level.

Domains:
  * ``smoothstep`` (Brooks et al. 2019, f(x) = 3x² − 2x³): defined on [0, 1] (the
    cubic is not monotone outside); forward clips its input there (renders of
    ordinary photos reach beyond white), reverse takes display values in [0, 1]
    only and raises :class:`ParameterError` otherwise.
  * ``reinhard`` (extended, white W = 4 by default), ``aces`` (Narkowicz 2015 fit,
    W where it reaches 1, ≈ 7.24), ``hable`` (Uncharted 2, W = 11.2): forward on all reals —
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
    _B,
    _C,
    _D,
    _E,
    _HA,
    _HB,
    _HC,
    _HD,
    _HE,
    _HF,
    TONE_WHITE,
    filmic,
    tone_shape,
)


def _root(qa, qb, qc):
    """The root 2c / (−b + √(b² − 4ac)) of a x² + b x + c, stable near c = 0."""
    return 2 * qc / (-qb + torch.sqrt((qb * qb - 4 * qa * qc).clamp_min(0)))


def _reinhard_inv(y, white):
    # Negated coefficients select the positive root (here a > 0 and c < 0).
    return _root(-1 / white**2, y - 1, y)


def _aces_inv(y, white):
    return _root(y * _C - _A, y * _D - _B, y * _E)


def _hable_inv(y, white):
    u = y + _HE / _HF
    return _root(_HA * (u - 1), _HB * (u - _HC), _HD * (_HF * u - _HE))


# name → (g⁻¹(y, W), g'(0), asymptote of g or inf)
_CURVES = {
    "reinhard": (_reinhard_inv, 1.0, math.inf),
    "aces": (_aces_inv, _B / _E, _A / _C),
    "hable": (
        _hable_inv,
        (_HC * _HB * _HD * _HF - _HD * _HE * _HB) / (_HD * _HF) ** 2,
        1 - _HE / _HF,
    ),
}


def _check_unit(x: torch.Tensor, curve: str) -> None:
    if bool((x < 0).any()) or bool((x > 1).any()):
        raise ParameterError(f"{curve} tone curve is defined on [0, 1]; input has values outside")


def _check_params(curve: str, exposure: float, white: float | None) -> float:
    """The white point to use; exposure and white apply to the filmic curves only."""
    if curve in _CURVES:
        if not 0 <= exposure <= 4:
            raise ParameterError(f"tone exposure must be in [0, 4] stops, got {exposure!r}")
        if white is not None and not 0.25 <= white <= 12:
            raise ParameterError(f"tone white must be in [0.25, 12], got {white!r}")
        return TONE_WHITE[curve] if white is None else float(white)
    if exposure != 0 or white is not None:
        raise ParameterError(
            f"the {curve} tone curve takes no exposure or white; they shape reinhard, aces, hable"
        )
    return 1.0


def _gain(curve: str, exposure: float, white: float) -> tuple[float, float]:
    """(input gain 2^exposure · W, output scale g(W)) of a filmic curve."""
    scale = float(tone_shape(curve, white)(torch.tensor(white, dtype=torch.float64)))
    return 2.0**exposure * white, scale


def apply_tone_curve(
    x: torch.Tensor, curve: str, exposure: float = 0.0, white: float | None = None
) -> torch.Tensor:
    """Tone-map linear values ``x`` (any shape) with ``curve``; f(0) = 0, and at the
    default exposure and white f(1) = 1 (see the module docstring)."""
    check_choice("tone curve", curve, TONE_CURVES)
    white = _check_params(curve, exposure, white)
    if curve == "none":
        return x
    if curve == "smoothstep":  # defined on [0, 1]: flat (0 and 1) outside
        x = x.clamp(0, 1)
        return x * x * (3 - 2 * x)
    _, slope0, _ = _CURVES[curve]
    gain, scale = _gain(curve, exposure, white)
    tangent = x * (slope0 * gain / scale)
    return torch.where(x >= 0, filmic(x.clamp_min(0), curve, exposure, white), tangent)


def invert_tone_curve(
    y: torch.Tensor, curve: str, exposure: float = 0.0, white: float | None = None
) -> torch.Tensor:
    """Exact inverse of :func:`apply_tone_curve`: display values → linear values."""
    check_choice("tone curve", curve, TONE_CURVES)
    white = _check_params(curve, exposure, white)
    if curve == "none":
        return y
    if curve == "smoothstep":
        _check_unit(y, curve)
        # Brooks et al.: 0.5 − sin(asin(1 − 2y) / 3). At y = 0 and 1 the inverse is y
        # itself; taking that branch there keeps asin's infinite slope out of gradients.
        t = 1 - 2 * y
        inside = t.abs() < 1
        return torch.where(inside, 0.5 - torch.sin(torch.asin(torch.where(inside, t, 0)) / 3), y)
    g_inv, slope0, asymptote = _CURVES[curve]
    gain, scale = _gain(curve, exposure, white)
    limit = asymptote / scale
    if bool((y >= limit).any()):
        raise ParameterError(f"{curve} tone curve never reaches {limit:.4g}; input has such values")
    tangent = y / (slope0 * gain / scale)
    return torch.where(y >= 0, g_inv(y.clamp(0, limit * (1 - 1e-6)) * scale, white) / gain, tangent)


class ToneCurve(nn.Module):
    """Tone-mapping stage: ``forward`` applies the curve, ``reverse`` inverts it."""

    def __init__(self, curve: str = "none", exposure: float = 0.0, white: float | None = None):
        super().__init__()
        self.curve = check_choice("tone curve", curve, TONE_CURVES)
        _check_params(curve, exposure, white)
        self.exposure, self.white = exposure, white

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_tone_curve(x, self.curve, self.exposure, self.white)

    def reverse(self, y: torch.Tensor) -> torch.Tensor:
        return invert_tone_curve(y, self.curve, self.exposure, self.white)
