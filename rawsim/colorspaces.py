"""Output colour spaces and their transfer functions: the standards' numbers, in one place.

An output is described by an :class:`Encoding`: a space (:data:`OUTPUT_SPACES`:
seven RGB spaces, ACES's two among them, CIE XYZ, or the camera's own RGB) and a transfer function
(:class:`TransferSpec`). Each RGB space (:data:`RGB_SPACES`) has its primaries,
white and own transfer, with the standard they come from; the transfers with a
linear toe (:class:`ToeCurve`: sRGB's, BT.2020's, ROMM's) are written once,
as operator-only code that evaluates numpy arrays (the compiled engine's
tables) and torch tensors (the differentiable reference, :mod:`rawsim.isp.transfer`)
alike. :mod:`rawsim.io.icc` turns an encoding into an ICC profile.

Whites. rawsim's D65 is the white of :data:`rawsim.color.SRGB_TO_XYZ` (ASTM
E308's 0.95047, 1, 1.08883, which that matrix was computed with): every D65
space is normalised to it, so camera white (sRGB (1, 1, 1)) is (1, 1, 1) in
each of them. Standards that derive their matrix from xy (0.3127, 0.3290)
differ from these in the fourth decimal. D50 is ICC's (0.9642, 1, 0.8249):
ProPhoto (ROMM RGB) is reached from D65 with a Bradford adaptation, as ICC
profiles do it, and so are ACES2065-1 and ACEScg, whose white (xy 0.32168,
0.33767) is near D60: their matrices from the raw's colour matrix are the
matrix-based input transform, as rawtoaces makes it where it has no spectral data.

Numpy only (torch where a tensor is passed in): the compiled engine and the CLI
import this without torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from rawsim.color import (
    SRGB_TO_XYZ,
    XYZ_D50,
    XYZ_D65,
    chromatic_adaptation,
    rgb_to_xyz_matrix,
)
from rawsim.errors import ParameterError


# ------------------------------------------------------------------ transfer functions
@dataclass(frozen=True)
class ToeCurve:
    """A power law with a linear toe, as sRGB, BT.709/BT.2020 and ROMM RGB define theirs.

    Encoding linear light ``x`` → ``v``: ``slope·x`` for ``x ≤ encode_knee``, else
    ``(1 + offset)·x^(1/gamma) − offset``. Decoding is its inverse, split at
    ``decode_knee`` (the standard's own value, ≈ ``slope·encode_knee``). This is
    ICC's parametric curve type 3 (:meth:`icc_parameters`).

    Nominal domain [0, 1] → [0, 1]; beyond it nothing is clipped: the toe continues
    linearly below 0, the power law above 1, so every value keeps an exact inverse.
    Gradients are finite everywhere (the power branch is clamped to the knee inside
    the unused side of ``where``): ``slope`` on the toe.
    """

    name: str
    gamma: float  # decoding exponent; encoding uses 1/gamma
    offset: float
    slope: float
    encode_knee: float  # linear light
    decode_knee: float  # encoded value
    source: str

    def encode(self, x):
        """Linear light → encoded values (numpy array or torch tensor, any shape)."""
        where, maximum = _operators(x)
        power = maximum(x, self.encode_knee) ** (1 / self.gamma)
        power *= 1 + self.offset
        power -= self.offset
        return where(x <= self.encode_knee, x * self.slope, power)

    def decode(self, v):
        """Encoded values → linear light (numpy array or torch tensor, any shape)."""
        where, maximum = _operators(v)
        power = ((maximum(v, self.decode_knee) + self.offset) / (1 + self.offset)) ** self.gamma
        return where(v <= self.decode_knee, v / self.slope, power)

    def icc_parameters(self) -> tuple[float, ...]:
        """(g, a, b, c, d) of ICC's parametric curve type 3, the decoding:
        ``Y = (a·X + b)^g`` for ``X ≥ d``, ``Y = c·X`` below."""
        scale = 1 + self.offset
        return (self.gamma, 1 / scale, self.offset / scale, 1 / self.slope, self.decode_knee)


def _operators(x):
    """(where, maximum) for numpy values or torch tensors: the same formula serves both."""
    if isinstance(x, (np.ndarray, np.generic, float, int)):
        return np.where, np.maximum
    import torch  # a tensor was passed in, so torch is loaded already

    return torch.where, torch.clamp_min


#: IEC 61966-2-1:1999 (sRGB) section 5.2, also Display P3's curve.
SRGB_CURVE = ToeCurve(
    "srgb", 2.4, 0.055, 12.92, 0.0031308, 0.04045, "IEC 61966-2-1:1999, 5.2 and 5.3"
)
#: ITU-R BT.2020-2 Table 4: the OETF of BT.709 with the constants that make it
#: continuous in value and slope (alpha = 1.09929682680944, beta = 0.018053968510807;
#: BT.709-6 and 10-bit BT.2020 round them to 1.099 and 0.018, 12-bit to 1.0993
#: and 0.0181).
_BT2020_ALPHA = 1.09929682680944
_BT2020_BETA = 0.018053968510807
_BT2020_SLOPE = 4.5
BT2020_CURVE = ToeCurve(
    "bt2020",
    1 / 0.45,
    _BT2020_ALPHA - 1,
    _BT2020_SLOPE,
    _BT2020_BETA,
    _BT2020_SLOPE * _BT2020_BETA,
    "ITU-R BT.2020-2, Table 4 (the BT.709-6 OETF)",
)
#: ISO 22028-2:2013 (ROMM RGB): gamma 1.8 with a linear toe of slope 16 below
#: Et = 16^(1.8 / (1 − 1.8)) = 2^-9, where both pieces meet (at 1/32).
_ROMM_GAMMA = 1.8
_ROMM_SLOPE = 16.0
_ROMM_KNEE = 1 / 512
ROMM_CURVE = ToeCurve(
    "romm",
    _ROMM_GAMMA,
    0.0,
    _ROMM_SLOPE,
    _ROMM_KNEE,
    _ROMM_SLOPE * _ROMM_KNEE,
    "ISO 22028-2:2013 (ROMM RGB)",
)
#: Adobe RGB (1998) Color Image Encoding, version 2005-05: a pure power law of
#: exponent 563/256 ≈ 2.2 (exact in ICC's s15Fixed16 numbers), no linear toe.
ADOBE_RGB_GAMMA = 563 / 256

#: Transfer name → its toe curve.
TOE_CURVES = {curve.name: curve for curve in (SRGB_CURVE, BT2020_CURVE, ROMM_CURVE)}
#: ITU-T H.273 TransferCharacteristics code points (PNG cICP) of the transfers that
#: have one. BT.2020's OETF is BT.709's: H.273 gives codes 1, 14 and 15 one
#: function; 1 is the one every reader knows.
_TRANSFER_CODES = {"srgb": 13, "bt2020": 1, "linear": 8}
#: H.273's two pure power laws (BT.470 System M and B/G's assumed display gammas).
_GAMMA_CODES = {2.2: 4, 2.8: 5}


@dataclass(frozen=True)
class TransferSpec:
    """A parsed transfer name: ``srgb``, ``bt2020``, ``romm``, ``linear`` or ``gamma:G``.

    ``gamma:G`` takes a number or a fraction (``gamma:563/256``, Adobe RGB's). The
    functions themselves are :func:`rawsim.isp.transfer.apply_transfer` and
    :func:`~rawsim.isp.transfer.invert_transfer` (torch); :attr:`curve` gives the
    toe curves for numpy.
    """

    kind: str
    gamma: float = 1.0

    @classmethod
    def parse(cls, text) -> TransferSpec:
        """Parse ``"srgb"``, ``"bt2020"``, ``"romm"``, ``"linear"`` or ``"gamma:2.2"``."""
        text = str(text).strip().lower()
        if text in TOE_CURVES or text == "linear":
            return cls(text)
        if text.startswith("gamma:"):
            try:
                gamma = float(Fraction(text.split(":", 1)[1]))
            except (ValueError, ZeroDivisionError):
                gamma = float("nan")
            if not (gamma > 0 and math.isfinite(gamma)):
                raise ParameterError(f"bad transfer {text!r}: gamma must be a number > 0")
            return cls("gamma", gamma)
        raise ParameterError(f"unknown transfer {text!r}; valid: {', '.join(TRANSFERS)}")

    def __str__(self) -> str:
        if self.kind != "gamma":
            return self.kind
        short = f"{self.gamma:g}"  # exact where it can be; else every digit, to parse back
        return f"gamma:{short if float(short) == self.gamma else repr(self.gamma)}"

    @property
    def curve(self) -> ToeCurve | None:
        """The toe curve of ``srgb``, ``bt2020`` and ``romm``; None for the others."""
        return TOE_CURVES.get(self.kind)

    @property
    def cicp(self) -> int | None:
        """Its ITU-T H.273 TransferCharacteristics code, or None where it has none."""
        if self.kind == "gamma":
            return _GAMMA_CODES.get(self.gamma)
        return _TRANSFER_CODES.get(self.kind)

    def describe(self) -> str:
        """A short English name: "sRGB curve", "gamma 2.2", "linear"."""
        if self.kind == "gamma":
            return f"gamma {self.gamma:g}"
        names = {"srgb": "sRGB curve", "bt2020": "BT.2020 curve", "romm": "ROMM curve"}
        return names.get(self.kind, self.kind)


#: The transfer names ``--transfer`` takes (``gamma:G`` for any G > 0).
TRANSFERS = ("srgb", "bt2020", "romm", "gamma:G", "linear")


# ------------------------------------------------------------------ spaces
@dataclass(frozen=True)
class RgbSpace:
    """An RGB output space: primaries and white, its own transfer, code points.

    ``primaries``: xy of red, green, blue; ``white``: XYZ (Y = 1) of RGB (1, 1, 1),
    what the matrices are built with; ``white_xy``: the white's chromaticity as
    the standard gives it, written where files name the white (OpenEXR's
    ``chromaticities``); ``cicp``: ITU-T H.273 ColourPrimaries code, None where it
    has none.
    """

    name: str
    title: str
    primaries: tuple[tuple[float, float], ...]
    white: tuple[float, float, float]
    white_xy: tuple[float, float]
    transfer: str
    cicp: int | None
    source: str

    @property
    def to_xyz(self) -> np.ndarray:
        """(3, 3) float64 linear RGB → XYZ under the space's own white."""
        if self.name == "srgb":  # the matrix every other colour path in rawsim uses
            return SRGB_TO_XYZ.copy()
        return rgb_to_xyz_matrix(self.primaries, self.white)


_D65 = tuple(float(v) for v in XYZ_D65)
_D50 = tuple(float(v) for v in XYZ_D50)
#: The standards' white chromaticities: D65 (IEC 61966-2-1, SMPTE EG 432-1, Adobe RGB,
#: BT.2020) and ROMM RGB's D50 (ISO 22028-2).
_D65_XY = (0.3127, 0.3290)
_D50_XY = (0.3457, 0.3585)
#: The ACES white (SMPTE ST 2065-1: near D60), as xy and as XYZ (Y = 1).
_ACES_XY = (0.32168, 0.33767)
_ACES_WHITE = (_ACES_XY[0] / _ACES_XY[1], 1.0, (1 - sum(_ACES_XY)) / _ACES_XY[1])

#: The RGB output spaces, by name.
RGB_SPACES: dict[str, RgbSpace] = {
    s.name: s
    for s in (
        RgbSpace(
            "srgb",
            "sRGB IEC61966-2.1",
            ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06)),
            _D65,
            _D65_XY,
            "srgb",
            1,
            "IEC 61966-2-1:1999",
        ),
        RgbSpace(
            "display-p3",
            "Display P3",
            ((0.680, 0.320), (0.265, 0.690), (0.150, 0.060)),
            _D65,
            _D65_XY,
            "srgb",
            12,
            "SMPTE EG 432-1:2010 (P3 primaries, D65 white), with the sRGB curve (Apple)",
        ),
        RgbSpace(
            "adobe-rgb",
            "Adobe RGB (1998)",
            ((0.6400, 0.3300), (0.2100, 0.7100), (0.1500, 0.0600)),
            _D65,
            _D65_XY,
            f"gamma:{Fraction(ADOBE_RGB_GAMMA)}",
            None,
            "Adobe RGB (1998) Color Image Encoding, version 2005-05",
        ),
        RgbSpace(
            "rec2020",
            "ITU-R BT.2020",
            ((0.708, 0.292), (0.170, 0.797), (0.131, 0.046)),
            _D65,
            _D65_XY,
            "bt2020",
            9,
            "ITU-R BT.2020-2",
        ),
        RgbSpace(
            "aces2065-1",
            "ACES2065-1 (AP0)",
            ((0.7347, 0.2653), (0.0, 1.0), (0.0001, -0.0770)),
            _ACES_WHITE,
            _ACES_XY,
            "linear",
            None,
            "SMPTE ST 2065-1:2012 (AP0 primaries, the ACES white)",
        ),
        RgbSpace(
            "acescg",
            "ACEScg (AP1)",
            ((0.713, 0.293), (0.165, 0.830), (0.128, 0.044)),
            _ACES_WHITE,
            _ACES_XY,
            "linear",
            None,
            "Academy S-2014-004 (AP1 primaries, the ACES white)",
        ),
        RgbSpace(
            "prophoto",
            "ProPhoto RGB (ROMM RGB)",
            ((0.7347, 0.2653), (0.1596, 0.8404), (0.0366, 0.0001)),
            _D50,
            _D50_XY,
            "romm",
            None,
            "ISO 22028-2:2013 (ROMM RGB)",
        ),
    )
}
#: Every ``--output-space``: the RGB spaces, CIE XYZ (D65-relative, Y = 1 at white)
#: and the camera's own (white-balanced) RGB.
OUTPUT_SPACES = (*RGB_SPACES, "xyz", "camera")
#: The transfer of outputs whose space has none of its own (xyz, camera): sRGB's,
#: as rawsim has always written them.
DEFAULT_TRANSFER = "srgb"


def space_transfer(space: str) -> TransferSpec:
    """The transfer ``space`` is encoded with unless told otherwise (``--transfer auto``)."""
    _check_space(space)
    rgb = RGB_SPACES.get(space)
    return TransferSpec.parse(rgb.transfer if rgb else DEFAULT_TRANSFER)


def space_from_srgb(space: str) -> np.ndarray:
    """(3, 3) float64 linear sRGB → ``space`` (linear), through XYZ, with Bradford's
    adaptation from D65 where the space's white differs (ProPhoto's D50). For
    ``xyz`` it is :data:`~rawsim.color.SRGB_TO_XYZ`; not defined for ``camera``."""
    _check_space(space)
    if space == "camera":
        raise ParameterError("camera RGB is no fixed space: its matrix is the raw's own")
    if space == "xyz":
        return SRGB_TO_XYZ.copy()
    rgb = RGB_SPACES[space]
    if space == "srgb":
        return np.eye(3)
    adapt = chromatic_adaptation(XYZ_D65, rgb.white)
    return np.linalg.solve(rgb.to_xyz, adapt @ SRGB_TO_XYZ)


def _check_space(space: str) -> None:
    if space not in OUTPUT_SPACES:
        raise ParameterError(f"unknown output space {space!r}; valid: {', '.join(OUTPUT_SPACES)}")


@dataclass(frozen=True)
class Encoding:
    """What an output's samples are: linear light in ``space`` (one of
    :data:`OUTPUT_SPACES` but ``camera``, which has no fixed meaning) encoded with
    ``transfer``. Grey outputs use only the transfer."""

    space: str
    transfer: TransferSpec

    def __post_init__(self) -> None:
        _check_space(self.space)
        if self.space == "camera":
            raise ParameterError("camera RGB has no encoding to tag: write it untagged (None)")
        object.__setattr__(self, "transfer", TransferSpec.parse(self.transfer))

    @property
    def is_srgb(self) -> bool:
        """sRGB primaries with the sRGB curve: what EXIF's ColorSpace 1 and PNG's ``sRGB`` say."""
        return self.space == "srgb" and self.transfer.kind == "srgb"

    @property
    def rgb_space(self) -> RgbSpace | None:
        """The RGB space, or None for ``xyz``."""
        return RGB_SPACES.get(self.space)

    @property
    def cicp(self) -> tuple[int, int, int, int] | None:
        """ITU-T H.273 (primaries, transfer, matrix 0 = RGB, full range 1) for PNG's
        ``cICP``, or None where the space or the transfer has no code point."""
        rgb, transfer = self.rgb_space, self.transfer.cicp
        if rgb is None or rgb.cicp is None or transfer is None:
            return None
        return (rgb.cicp, transfer, 0, 1)

    @property
    def chromaticities(self) -> tuple[float, ...]:
        """OpenEXR's ``chromaticities``: xy of red, green, blue and of RGB (1, 1, 1),
        8 numbers. CIE XYZ is red (1, 0), green (0, 1), blue (0, 0), white (1/3, 1/3),
        as OpenEXR defines it."""
        rgb = self.rgb_space
        if rgb is None:
            return (1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1 / 3, 1 / 3)
        return (*(c for xy in rgb.primaries for c in xy), *rgb.white_xy)

    @property
    def neutral_xy(self) -> tuple[float, float]:
        """xy of the scene's neutral (OpenEXR's ``adoptedNeutral``): the space's white;
        D65 for CIE XYZ, whose (1, 1, 1) is not neutral."""
        return self.rgb_space.white_xy if self.rgb_space else _D65_XY

    def describe(self) -> str:
        """A profile description: the space, and the transfer where it is not its own."""
        title = self.rgb_space.title if self.rgb_space else "CIE XYZ (D65)"
        if self.transfer == space_transfer(self.space) and self.rgb_space:
            return title
        return f"{title}, {self.transfer.describe()}"


#: Plain sRGB: what rawsim's outputs are by default.
SRGB = Encoding("srgb", TransferSpec("srgb"))
