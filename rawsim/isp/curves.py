"""Tone curves' forward formulas and the transfer functions' constants, torch-free.

Operator-only code: the same functions evaluate torch tensors (the reference in
:mod:`rawsim.isp.tone` and :mod:`rawsim.isp.transfer`) and numpy arrays (the
compiled engine's lookup tables, :mod:`rawsim.engine.process`).
"""

from __future__ import annotations

import math

# IEC 61966-2-1 (sRGB) constants.
_SRGB_DECODE_KNEE = 0.04045
_SRGB_ENCODE_KNEE = 0.0031308
_SRGB_SLOPE = 12.92
_SRGB_A = 0.055
_SRGB_GAMMA = 2.4

_REINHARD_WHITE = 4.0
# ACES filmic fit (Narkowicz 2015): g(x) = x(a x + b) / (x(c x + d) + e).
_A, _B, _C, _D, _E = 2.51, 0.03, 2.43, 0.59, 0.14
# Hable / Uncharted 2 constants A..F and linear white.
_HA, _HB, _HC, _HD, _HE, _HF = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
_HABLE_WHITE = 11.2


def _reinhard(x):
    return x * (1 + x / _REINHARD_WHITE**2) / (1 + x)


def _aces(x):
    return x * (_A * x + _B) / (x * (_C * x + _D) + _E)


def _hable(x):
    return (x * (_HA * x + _HC * _HB) + _HD * _HE) / (x * (_HA * x + _HB) + _HD * _HF) - _HE / _HF


def _aces_white() -> float:
    """Where ACES reaches 1: the root 2c / (−b + √(b² − 4ac)) of (C − A)x² + (D − B)x + E."""
    qa, qb, qc = _C - _A, _D - _B, _E
    return 2 * qc / (-qb + math.sqrt(max(qb * qb - 4 * qa * qc, 0.0)))


_ACES_WHITE = _aces_white()
