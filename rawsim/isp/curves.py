"""Tone curves' forward formulas and the transfer functions' names, torch-free.

Operator-only code: the same functions evaluate torch tensors (the reference in
:mod:`rawsim.isp.tone` and :mod:`rawsim.isp.transfer`) and numpy arrays (the
compiled engine's lookup tables, :mod:`rawsim.engine.process`).
"""

from __future__ import annotations

import math

from rawsim.colorspaces import SRGB_CURVE
from rawsim.colorspaces import TransferSpec as TransferSpec  # its home before; still imported

# The transfer functions live with the output spaces (:mod:`rawsim.colorspaces`);
# these names stay for the modules that read sRGB's constants directly.
_SRGB_DECODE_KNEE = SRGB_CURVE.decode_knee
_SRGB_ENCODE_KNEE = SRGB_CURVE.encode_knee
_SRGB_SLOPE = SRGB_CURVE.slope
_SRGB_A = SRGB_CURVE.offset
_SRGB_GAMMA = SRGB_CURVE.gamma

_REINHARD_WHITE = 4.0
# ACES filmic fit (Narkowicz 2015): g(x) = x(a x + b) / (x(c x + d) + e).
_A, _B, _C, _D, _E = 2.51, 0.03, 2.43, 0.59, 0.14
# Hable / Uncharted 2 constants A..F and linear white.
_HA, _HB, _HC, _HD, _HE, _HF = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
_HABLE_WHITE = 11.2


def _reinhard(x, white=_REINHARD_WHITE):
    """Extended Reinhard: reaches 1 at ``white``."""
    return x * (1 + x / white**2) / (1 + x)


def _aces(x):
    return x * (_A * x + _B) / (x * (_C * x + _D) + _E)


def _hable(x):
    return (x * (_HA * x + _HC * _HB) + _HD * _HE) / (x * (_HA * x + _HB) + _HD * _HF) - _HE / _HF


def _aces_white() -> float:
    """Where ACES reaches 1: the root 2c / (−b + √(b² − 4ac)) of (C − A)x² + (D − B)x + E."""
    qa, qb, qc = _C - _A, _D - _B, _E
    return 2 * qc / (-qb + math.sqrt(max(qb * qb - 4 * qa * qc, 0.0)))


_ACES_WHITE = _aces_white()


#: Each curve's default white point W, in its own units (where the curve is normalised).
TONE_WHITE = {"reinhard": _REINHARD_WHITE, "aces": _ACES_WHITE, "hable": _HABLE_WHITE}


def tone_shape(curve: str, white: float):
    """The curve g of ``curve`` for white point ``white`` (Reinhard's g depends on it)."""
    if curve == "reinhard":
        return lambda x: _reinhard(x, white)
    return {"aces": _aces, "hable": _hable}[curve]


def filmic(x, curve: str, exposure: float = 0.0, white: float | None = None):
    """A filmic curve on linear ``x`` ≥ 0: ``g(2^exposure · W · x) / g(W)``.

    ``W`` (``white``, default :data:`TONE_WHITE`) is the white point in the curve's
    own units: display 1 is reached at ``x = 2^-exposure``, and a larger W spends
    more of [0, 1] on the shoulder (highlights compress, mid-tones lift). At
    exposure 0, x = 1 (the sensor's white) maps to 1.
    """
    white = TONE_WHITE[curve] if white is None else white
    g = tone_shape(curve, white)
    return g(x * (2.0**exposure * white)) / g(white)
