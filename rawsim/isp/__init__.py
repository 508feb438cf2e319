"""ISP stages: each a pure function pair plus a thin ``nn.Module`` with forward/reverse.

Names are imported on first use (the config module needs no torch).
"""

from __future__ import annotations

from rawsim._lazy import lazy_exports

#: Public name → the module that defines it (imported on first use).
_EXPORTS = {
    "ColorMatrix": "rawsim.isp.color_matrix",
    "apply_color_matrix": "rawsim.isp.color_matrix",
    "invert_color_matrix": "rawsim.isp.color_matrix",
    "LensShading": "rawsim.isp.lens_shading",
    "apply_lens_shading": "rawsim.isp.lens_shading",
    "invert_lens_shading": "rawsim.isp.lens_shading",
    "radial_gain": "rawsim.isp.lens_shading",
    "Levels": "rawsim.isp.levels",
    "Saturation": "rawsim.isp.levels",
    "denormalize_levels": "rawsim.isp.levels",
    "normalize_levels": "rawsim.isp.levels",
    "quantize": "rawsim.isp.levels",
    "saturate": "rawsim.isp.levels",
    "ToneCurve": "rawsim.isp.tone",
    "apply_tone_curve": "rawsim.isp.tone",
    "invert_tone_curve": "rawsim.isp.tone",
    "Transfer": "rawsim.isp.transfer",
    "TransferSpec": "rawsim.isp.curves",
    "apply_transfer": "rawsim.isp.transfer",
    "invert_transfer": "rawsim.isp.transfer",
    "gamma_decode": "rawsim.isp.transfer",
    "gamma_encode": "rawsim.isp.transfer",
    "srgb_decode": "rawsim.isp.transfer",
    "srgb_encode": "rawsim.isp.transfer",
    "WhiteBalance": "rawsim.isp.white_balance",
    "apply_white_balance": "rawsim.isp.white_balance",
    "invert_white_balance": "rawsim.isp.white_balance",
    "safe_invert_white_balance": "rawsim.isp.white_balance",
}

__all__ = [
    "ColorMatrix",
    "LensShading",
    "Levels",
    "Saturation",
    "ToneCurve",
    "Transfer",
    "TransferSpec",
    "WhiteBalance",
    "apply_color_matrix",
    "apply_lens_shading",
    "apply_tone_curve",
    "apply_transfer",
    "apply_white_balance",
    "denormalize_levels",
    "gamma_decode",
    "gamma_encode",
    "invert_color_matrix",
    "invert_lens_shading",
    "invert_tone_curve",
    "invert_transfer",
    "invert_white_balance",
    "normalize_levels",
    "quantize",
    "radial_gain",
    "safe_invert_white_balance",
    "saturate",
    "srgb_decode",
    "srgb_encode",
]


__getattr__, __dir__ = lazy_exports(globals(), _EXPORTS)
