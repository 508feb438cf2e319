"""Sensor models (SPEC "Sensor models"): ``Sensor``, ``RGBSensor`` and ``MonoSensor``.

The sensors chain the ISP stages of :mod:`rawsim.isp` and the noise models of
:mod:`rawsim.noise.models`; they hold no random state: randomness comes in as a
``torch.Generator`` and sampled values as :class:`~rawsim.params.UnprocessParams`.

Shapes: images (B, 3, H, W), mosaics (B, 1, H, W) with H, W even. A mosaic
follows the sensor's CFA: a 2×2 Bayer pattern, X-Trans (6×6) or any periodic
R/G/B layout, anchored at the top-left pixel.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn

from rawsim.cameras.profiles import SensorProfile, load_profile, profile_from_dict
from rawsim.cfa import CFA
from rawsim.color import camera_from_srgb
from rawsim.errors import ParameterError, check_choice, check_image
from rawsim.io.lensfun import LensParams
from rawsim.isp.color_matrix import apply_color_matrix
from rawsim.isp.lens import add_lens
from rawsim.isp.lens_shading import invert_lens_shading, radial_gain
from rawsim.isp.levels import denormalize_levels, normalize_levels, quantize, saturate
from rawsim.isp.tone import invert_tone_curve
from rawsim.isp.transfer import TransferSpec, gamma_decode, gamma_encode, invert_transfer
from rawsim.isp.white_balance import invert_white_balance, safe_invert_white_balance
from rawsim.noise.models import NoiseLevels, add_noise
from rawsim.params import UnprocessParams, sample_params

IN_TYPES = ("rgb", "linear_rgb")


def display_to_linear(v: torch.Tensor, tone: str = "none", transfer: str = "srgb") -> torch.Tensor:
    """Display-referred values → linear light: inverse tone curve, then transfer decode.

    The order follows Brooks et al. (their tone curve acts on encoded values).
    ``v`` is any shape, nominally in [0, 1].
    """
    return invert_transfer(invert_tone_curve(v, tone), TransferSpec.parse(transfer))


def _read_config(config) -> dict:
    if isinstance(config, (str, Path)):
        return json.loads(Path(config).read_text())
    return dict(config)


class Sensor(nn.Module):
    """Base sensor: physical ``size`` (W, H) mm, ``res`` (W, H) px, and a gamma-only ISP."""

    def __init__(self, size=(36.0, 24.0), res=(5472, 3648), gamma: float = 2.2) -> None:
        super().__init__()
        self.size, self.res, self.gamma = tuple(size), tuple(res), float(gamma)

    @classmethod
    def from_config(cls, config) -> Sensor:
        """Build from a seed JSON config (``sensor_size``, ``sensor_res``, ``gamma_param``)."""
        c = _read_config(config)
        return cls(
            c.get("sensor_size", (36.0, 24.0)),
            c.get("sensor_res", (5472, 3648)),
            c.get("gamma_param", 2.2),
        )

    def response_curve(self, x: torch.Tensor) -> torch.Tensor:
        return x

    def linrgb2raw(self, x: torch.Tensor, params=None) -> torch.Tensor:
        return x

    def simu_noise(self, x: torch.Tensor, iso: float, model: str = "none", key=None, top=0):
        return x

    def unprocess(self, image: torch.Tensor, in_type: str = "rgb", params=None) -> torch.Tensor:
        """Undo the gamma (``in_type="rgb"``) or pass linear input through."""
        check_choice("in_type", in_type, IN_TYPES)
        return gamma_decode(image, self.gamma) if in_type == "rgb" else image

    def process(self, x: torch.Tensor) -> torch.Tensor:
        """The forward ISP: gamma encoding."""
        return gamma_encode(x, self.gamma)


class ProfileSensor(Sensor):
    """A sensor described by a :class:`~rawsim.cameras.profiles.SensorProfile`: levels and noise."""

    def __init__(self, profile: SensorProfile) -> None:
        super().__init__(
            profile.size_mm or (36.0, 24.0), profile.resolution or (0, 0), profile.gamma
        )
        self.profile = profile

    @classmethod
    def from_profile(cls, name_or_path, **kwargs):
        """Build from a bundled profile name or a profile JSON path (``kwargs`` go to
        the constructor, e.g. ``cfa="XTRANS"`` for an :class:`RGBSensor`)."""
        return cls(load_profile(name_or_path), **kwargs)

    @classmethod
    def from_config(cls, config):
        """Build from the seed's JSON config keys (a dict or a path)."""
        origin = str(config) if isinstance(config, (str, Path)) else "<config>"
        return cls(profile_from_dict(_read_config(config), origin))

    @property
    def black_level(self) -> float:
        return self.profile.black_level

    @property
    def white_level(self) -> float:
        return self.profile.white_level

    def default_params(self, iso: float, **fixed) -> UnprocessParams:
        """The profile's own matrix and daylight white balance at ``iso``."""
        return sample_params(self.profile, iso=iso, **fixed)

    def _params(self, params: UnprocessParams | None) -> UnprocessParams:
        lowest = self.profile.iso_range[0] if self.profile.iso_range else 100.0
        return params or self.default_params(lowest)

    def _to_dn(self, x: torch.Tensor, params, shading: torch.Tensor | None) -> torch.Tensor:
        """Normalised (B, C, H, W) → DN: vignetting (``shading`` or the params'), levels."""
        if shading is None and params is not None and params.vignetting > 0:
            shading = radial_gain(
                *x.shape[-2:], strength=params.vignetting, device=x.device, dtype=x.dtype
            )
        if shading is not None:
            x = invert_lens_shading(x, shading)
        return denormalize_levels(x, self.black_level, self.white_level)

    def _linear_light(self, image: torch.Tensor, in_type: str, p: UnprocessParams) -> torch.Tensor:
        """(B, 3, H, W) display or linear sRGB → linear light with exposure and brightness."""
        check_choice("in_type", in_type, IN_TYPES)
        check_image(image, "image", channels=3)
        x = display_to_linear(image, p.tone, p.transfer) if in_type == "rgb" else image
        scale = p.linear_scale
        return x * scale if scale != 1.0 else x

    def noise_levels(self, iso: float, model: str = "poisson-gaussian") -> NoiseLevels:
        """Noise parameters at ``iso``; the ISO must lie in the profile's range."""
        return self.profile.noise_levels(iso, model)

    def simu_noise(
        self,
        dn: torch.Tensor,
        iso: float,
        model: str | NoiseLevels = "poisson-gaussian",
        key: int | list[int] | None = None,
        top: int = 0,
        height: int | None = None,
    ) -> torch.Tensor:
        """Add noise at ``iso``, round to integers and saturate to [0, white] DN.

        ``model`` is a model name (its nominal levels at ``iso``) or already
        resolved :class:`~rawsim.noise.models.NoiseLevels`, e.g. sampled ones. ``key`` is
        the noise seed (one per sample, or one for all) and ``top`` the first
        row's index in the image and ``height`` the image's height, when ``dn``
        is a strip (see :func:`~rawsim.noise.models.add_noise`). Returns ``dn``'s dtype.
        """
        levels = model if isinstance(model, NoiseLevels) else self.noise_levels(iso, model)
        if key is None and levels.model != "none":
            raise ParameterError("noise needs a key: the seed its draws derive from")
        cfa = getattr(self, "cfa", None)
        noisy = add_noise(dn, self.black_level, levels, key, cfa, top, height)
        return saturate(quantize(noisy), self.white_level).to(dn.dtype)


class RGBSensor(ProfileSensor):
    """A colour sensor described by a :class:`~rawsim.cameras.profiles.SensorProfile`.

    Its mosaic follows the profile's CFA, or ``cfa`` when given: a :class:`CFA`
    or its string (``"RGGB"``, ``"XTRANS"``, rows such as ``"GRG/BGB/GRG"``), which
    replaces the profile's layout and keeps its levels, colour and noise
    (:meth:`~rawsim.cameras.profiles.SensorProfile.with_cfa`).
    """

    def __init__(self, profile: SensorProfile, cfa: CFA | str | None = None) -> None:
        super().__init__(profile if cfa is None else profile.with_cfa(cfa))

    @property
    def cfa(self) -> CFA:
        return self.profile.cfa

    def response_curve(self, spectral: torch.Tensor) -> torch.Tensor:
        """Spectral image (B, Nλ, H, W) → (B, 3, H, W) through the channel responses.

        The seed's form, on the profile's own samples (``wavelengths`` and
        ``*_spectral_response``), differentiable; all responses are normalised by
        the sum of the green response. Spectral scene files (``rawsim unprocess``)
        are seen by :mod:`rawsim.spectral.render` instead, on the 5 nm grid and
        under a light, through :func:`~rawsim.spectral.render.curves_for`: the
        camera's measured curves, else these responses.
        """
        spec = self.profile.spectral
        if spec is None:
            raise ParameterError(f"profile {self.profile.name!r} has no spectral responses")
        check_image(spectral, "spectral image", channels=len(spec["wavelengths"]))
        resp = torch.tensor(
            [spec["red"], spec["green"], spec["blue"]], dtype=spectral.dtype, device=spectral.device
        )
        return torch.einsum("cl,blhw->bchw", resp / resp[1].sum(), spectral)

    def unprocess(
        self,
        image: torch.Tensor,
        in_type: str = "rgb",
        params=None,
        lens: LensParams | dict | None = None,
    ) -> torch.Tensor:
        """sRGB or linear sRGB (B, 3, H, W) → linear camera RGB as the sensor records it.

        Steps: display decode (``in_type="rgb"``: inverse tone, transfer), exposure
        and brightness, sRGB → camera matrix, the ``lens``'s distortion, TCA and
        vignetting (:func:`~rawsim.isp.lens.add_lens`; ``image`` must then be the
        whole frame), inverse white balance. The lens acts on white-balanced camera
        RGB: where ``rawsim process`` corrects it. Values above 1 are kept (they
        saturate later at the white level); nothing is clipped.
        """
        p = self._params(params)
        x = self._linear_light(image, in_type, p)
        if p.ccm_bias is not None:
            x = x - torch.tensor(p.ccm_bias, dtype=x.dtype, device=x.device).reshape(1, 3, 1, 1)
        x = apply_color_matrix(x, camera_from_srgb(p.xyz_to_camera))
        if lens is not None:
            x = add_lens(x, lens)
        if p.safe_white_balance:
            return safe_invert_white_balance(x, p.wb_gains)
        return invert_white_balance(x, p.wb_gains)

    def linrgb2raw(
        self, camera_rgb: torch.Tensor, params=None, shading: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Camera RGB (B, 3, H, W) → clean mosaic in DN (B, 1, H, W), unrounded.

        Mosaics in the sensor's CFA (any period), adds vignetting if ``params.vignetting``
        (``shading`` overrides the radial gain map, e.g. a strip of a larger one),
        and scales [0, 1] to [black, white]. Not clipped: see :meth:`simu_noise`.
        """
        return self._to_dn(self.cfa.mosaic(camera_rgb), params, shading)

    def bayer2rggb(self, dn: torch.Tensor) -> torch.Tensor:
        """Mosaic DN (B, 1, H, W) → normalised planes (B, 4, H/2, W/2) in R, Gr, Gb, B order.

        Bayer CFAs only (:meth:`~rawsim.cfa.CFA.pack`); other layouts raise."""
        return self.cfa.pack(normalize_levels(dn, self.black_level, self.white_level))

    def rggb2bayer(self, planes: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`bayer2rggb`: normalised planes → mosaic DN."""
        return denormalize_levels(self.cfa.unpack(planes), self.black_level, self.white_level)


class MonoSensor(ProfileSensor):
    """A sensor without a colour filter, using a profile's levels and noise.

    ``response_curve`` is the spectral weighting when the profile has spectral data,
    else the mean of the RGB channels. ISP: black level, then gamma.
    """

    def response_curve(self, x: torch.Tensor) -> torch.Tensor:
        """(B, Nλ, H, W) spectral → (B, 1, H, W) weighted by the green response, or RGB mean."""
        spec = self.profile.spectral
        if spec is None:
            check_image(x, "image", channels=3)
            return x.mean(dim=1, keepdim=True)
        check_image(x, "spectral image", channels=len(spec["wavelengths"]))
        w = torch.tensor(spec["green"], dtype=x.dtype, device=x.device)
        return torch.einsum("l,blhw->bhw", w / w.sum(), x).unsqueeze(1)

    def unprocess(
        self,
        image: torch.Tensor,
        in_type: str = "rgb",
        params=None,
        lens: LensParams | dict | None = None,
    ) -> torch.Tensor:
        """(B, 3, H, W) display or linear sRGB → linear grey (B, 1, H, W).

        Display decode (``in_type="rgb"``), exposure and brightness as for RGB,
        then :meth:`response_curve`, then the ``lens`` (its green channel's remap, as
        ``rawsim process`` corrects a grey raw; ``image`` the whole frame). No matrix
        or white balance: there is no filter.
        """
        grey = self.response_curve(self._linear_light(image, in_type, self._params(params)))
        return grey if lens is None else add_lens(grey, lens)

    def linrgb2raw(
        self, x: torch.Tensor, params=None, shading: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Linear grey (B, 1, H, W), white at 1 → DN, with vignetting as for RGB.

        Not clipped or rounded: see :meth:`simu_noise`.
        """
        return self._to_dn(x, params, shading)

    def process(self, dn: torch.Tensor) -> torch.Tensor:
        """Black-level compensation, then gamma."""
        x = normalize_levels(dn, self.black_level, self.white_level)
        return gamma_encode(x, self.gamma)
