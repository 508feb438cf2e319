"""Unprocessing parameters: the values that turn one image into one raw, and their sampling.

:class:`UnprocessParams` is a plain, replayable value (it goes into the JSON
sidecar). :func:`sample_params` draws it per image from a ``torch.Generator``,
with the ranges of Brooks et al., "Unprocessing Images for Learned Raw
Denoising" (CVPR 2019), when ``randomize`` is set.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

from rawsim.cameras.profiles import SensorProfile
from rawsim.errors import ParameterError

if TYPE_CHECKING:
    import torch

#: Brooks et al.'s four XYZ → camera matrices, mixed by random convex weights.
BROOKS_XYZ_TO_CAMERA = (
    ((1.0234, -0.2969, -0.2266), (-0.5625, 1.6328, -0.0469), (-0.0703, 0.2188, 0.6406)),
    ((0.4913, -0.0541, -0.0202), (-0.613, 1.3513, 0.2906), (-0.1564, 0.2151, 0.7183)),
    ((0.838, -0.263, -0.0639), (-0.2887, 1.0725, 0.2496), (-0.0627, 0.1427, 0.5438)),
    ((0.6596, -0.2079, -0.0562), (-0.4782, 1.3016, 0.1933), (-0.097, 0.1581, 0.5181)),
)
#: Brooks et al.'s ranges: red gain U(1.9, 2.4), blue gain U(1.5, 1.9), and
#: brightness (their ``rgb_gain``) 1 / N(0.8, 0.1).
RED_GAIN_RANGE = (1.9, 2.4)
BLUE_GAIN_RANGE = (1.5, 1.9)
BRIGHTNESS_MEAN, BRIGHTNESS_STD = 0.8, 0.1


@dataclass(frozen=True)
class UnprocessParams:
    """Everything the inverse ISP needs for one image.

    Attributes:
        iso: ISO speed of the simulated capture.
        xyz_to_camera: (3, 3) D65 XYZ → camera matrix written as ColorMatrix1.
        wb_gains: (R, G, B) white-balance gains of the camera; AsShotNeutral is 1/gains.
        brightness: Brooks's ``rgb_gain``; the linear image is divided by it (1 = unchanged).
        exposure_ev: exposure in stops applied to the linear image before the sensor.
        tone: inverse tone curve applied to display-referred input.
        transfer: transfer function of display-referred input (``srgb``, ``gamma:G``, ``linear``).
        vignetting: strength of the radial lens-shading model added (0 = none).
        safe_white_balance: use the highlight-preserving inverse white balance (Brooks
            et al.'s; off by default: the exact inverse, ``--wb-inverse exact``).
        ccm_bias: bias of a seed camera → sRGB matrix, subtracted before its inverse.
    """

    iso: float
    xyz_to_camera: tuple[tuple[float, float, float], ...]
    wb_gains: tuple[float, float, float]
    brightness: float = 1.0
    exposure_ev: float = 0.0
    tone: str = "none"
    transfer: str = "srgb"
    vignetting: float = 0.0
    safe_white_balance: bool = False
    ccm_bias: tuple[float, float, float] | None = None

    @property
    def linear_scale(self) -> float:
        """The factor on the linear image before the inverse ISP: the exposure, the
        brightness, and the smallest white-balance gain where it is below 1. Raw
        converters (LibRaw, ``rawsim process``) divide the gains by the smallest when it
        is below 1, so that clipped highlights stay white; that brightens their render
        by as much, which the raw is darkened to match (not part of BaselineExposure)."""
        return 2.0**self.exposure_ev / self.brightness * min(1.0, *self.wb_gains)

    @property
    def baseline_exposure(self) -> float:
        """DNG BaselineExposure (stops) that restores the source brightness."""
        return math.log2(self.brightness) - self.exposure_ev

    def to_dict(self) -> dict:
        d = asdict(self)
        d["xyz_to_camera"] = [list(r) for r in self.xyz_to_camera]
        d["wb_gains"] = list(self.wb_gains)
        d["ccm_bias"] = None if self.ccm_bias is None else list(self.ccm_bias)
        return d


def sample_params(
    profile: SensorProfile,
    *,
    iso: float | None = None,
    iso_range: tuple[float, float] | None = None,
    randomize: bool = False,
    generator: torch.Generator | None = None,
    **fixed,
) -> UnprocessParams:
    """Draw the parameters of one image.

    Without ``randomize`` the profile's own matrix and daylight gains are used.
    With it, the matrix is a random convex mix of Brooks's four, the red and blue
    gains and the brightness are drawn from Brooks's ranges. ISO is ``iso``, or
    log-uniform in ``iso_range``. Each value is checked against the profile.
    Only draws need torch (its generator): a fixed ISO without ``randomize``
    returns without importing it.

    Args:
        fixed: further :class:`UnprocessParams` fields (tone, transfer, …).
    """
    if (iso is None) == (iso_range is None):
        raise ParameterError("give exactly one of an ISO or an ISO range")
    if iso_range is not None or randomize:
        import torch

        g = generator if generator is not None else torch.Generator().manual_seed(0)

    def uniform(lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))

    if iso_range is not None:
        lo, hi = (float(v) for v in iso_range)
        if not 0 < lo <= hi:
            raise ParameterError(f"ISO range must satisfy 0 < min ≤ max, got {lo:g}–{hi:g}")
        profile.check_iso(lo)
        profile.check_iso(hi)
        iso = math.exp(uniform(math.log(lo), math.log(hi)))
        iso = float(round(iso))
    profile.check_iso(float(iso))

    xyz, gains, brightness = profile.xyz_to_camera, profile.white_balance, 1.0
    bias = profile.ccm_bias
    if randomize:
        bias = None
        weights = torch.rand(4, generator=g, dtype=torch.float64)
        mix = torch.einsum(
            "k,kij->ij",
            weights / weights.sum(),
            torch.tensor(BROOKS_XYZ_TO_CAMERA, dtype=torch.float64),
        )
        xyz = tuple(tuple(float(v) for v in row) for row in mix)
        gains = (uniform(*RED_GAIN_RANGE), 1.0, uniform(*BLUE_GAIN_RANGE))
        draw = torch.normal(BRIGHTNESS_MEAN, BRIGHTNESS_STD, (), generator=g)
        # Brooks's rgb_gain = 1 / N(0.8, 0.1); a draw ≤ 0.1 (prob. 1e-12) is clamped.
        brightness = 1.0 / max(float(draw), 0.1)
    return UnprocessParams(
        iso=float(iso),
        xyz_to_camera=tuple(xyz),
        wb_gains=tuple(gains),
        brightness=brightness,
        ccm_bias=bias,
        **fixed,
    )
