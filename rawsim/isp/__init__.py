"""ISP stages: each a pure function pair plus a thin ``nn.Module`` with forward/reverse."""

from rawsim.isp.color_matrix import ColorMatrix, apply_color_matrix, invert_color_matrix
from rawsim.isp.lens_shading import (
    LensShading,
    apply_lens_shading,
    invert_lens_shading,
    radial_gain,
)
from rawsim.isp.levels import (
    Levels,
    Saturation,
    denormalize_levels,
    normalize_levels,
    quantize,
    saturate,
)
from rawsim.isp.tone import ToneCurve, apply_tone_curve, invert_tone_curve
from rawsim.isp.transfer import (
    Transfer,
    TransferSpec,
    gamma_decode,
    gamma_encode,
    srgb_decode,
    srgb_encode,
)
from rawsim.isp.white_balance import (
    WhiteBalance,
    apply_white_balance,
    invert_white_balance,
    safe_invert_white_balance,
)

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
    "apply_white_balance",
    "denormalize_levels",
    "gamma_decode",
    "gamma_encode",
    "invert_color_matrix",
    "invert_lens_shading",
    "invert_tone_curve",
    "invert_white_balance",
    "normalize_levels",
    "quantize",
    "radial_gain",
    "safe_invert_white_balance",
    "saturate",
    "srgb_decode",
    "srgb_encode",
]
