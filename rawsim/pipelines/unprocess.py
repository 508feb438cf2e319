"""Unprocessing: an sRGB or scene-linear image → a noisy CFA mosaic (and a clean one).

The mosaic follows the profile's CFA: a 2×2 Bayer pattern, Fujifilm's 6×6
X-Trans or any periodic R/G/B layout (:class:`~rawsim.cfa.CFA`).
:func:`unprocess_tensor` is the tensor core, used by the files job here and by
the Python API. It runs the sensor's stages over strips of :data:`STRIP_ROWS`
rows, cut to whole CFA periods (126 for X-Trans, :func:`strip_rows`), so that
temporaries stay small and cache-resident. The noise is drawn per pixel from a
counter-based generator (:mod:`rawsim.noise.reference`), so any strip height,
device, job count or run split gives the same bits.
Without gradients on the CPU, :mod:`rawsim.engine` runs the same stages compiled
and fused (:func:`simulate` chooses). That path, and the files job around it, import
no torch where nothing needs it (8/16-bit inputs through the toe-curve transfers, a
fixed ISO, no drawn parameters, no dark-shading maps): a one-file command does not
pay the 0.8 s that importing torch takes.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from rawsim._version import __version__
from rawsim.cameras.profiles import SensorProfile
from rawsim.cfa import PACKED_PLANES
from rawsim.color import camera_from_srgb
from rawsim.device import resolve_device
from rawsim.errors import ParameterError, check_choice, check_image, values_checked
from rawsim.io.dng import DngInfo, write_dng
from rawsim.io.dng_colour import DngColour
from rawsim.io.images import CODE_MAX, DecodedImage, read_image
from rawsim.io.lensfun import LensParams
from rawsim.io.metadata import PhotoMetadata, read_metadata
from rawsim.io.outputs import atomic_outputs
from rawsim.io.pieces import open_empty
from rawsim.io.progress import DecodeProgress
from rawsim.io.readahead import ReadAhead
from rawsim.io.spare import Spare
from rawsim.io.spectral import SpectralScene, is_spectral, read_spectral
from rawsim.io.task import Task
from rawsim.isp.config import DEFAULT_K, SAFE_WB_THRESHOLD
from rawsim.isp.curves import TransferSpec
from rawsim.noise.dark_shading import check_fits
from rawsim.noise.seeds import derive_seed
from rawsim.noise.spec import NOISE_MODELS, NoiseLevels, bias_tile
from rawsim.params import UnprocessParams, sample_params

if TYPE_CHECKING:
    import torch

    from rawsim.cameras.spectra import Curves
    from rawsim.cfa import CFA
    from rawsim.sensors import ProfileSensor
    from rawsim.spectral.render import Light

STRIP_ROWS = 128
#: ``planes`` of an npz whose mosaic is kept whole, (1, H, W): a CFA that is not Bayer.
MOSAIC_PLANE = "CFA"
#: The integer element types taken as display codes (:func:`element_type`'s names).
INTEGER_TYPES = ("uint8", "uint16", "int32")
SENSOR_KINDS = ("rgb", "mono")


def element_type(image) -> str:
    """The name of the element type of a NumPy array or a torch tensor, the same for
    both (``uint8``, ``float32``, …), found without importing torch."""
    return str(image.dtype).removeprefix("torch.")


def _reads_every_value(kind: str, code_max: int | None) -> bool:
    """Whether :func:`_prepare` reads every value of an image whose elements are of
    type ``kind`` (:func:`element_type`): floats (checked finite), integer types
    that can hold codes outside [0, ``code_max``], and types it refuses; not the
    codes a type itself keeps in range (uint8 at 255)."""
    if kind not in INTEGER_TYPES:
        return True
    info = np.iinfo(kind)
    return info.min < 0 or (code_max or info.max) < info.max


def code_table(top: int, tone: str = "none", transfer: str = "srgb") -> np.ndarray:
    """The linear light of each display code 0 … ``top``: float32 (top + 1,), code / top
    through :func:`rawsim.sensors.display_to_linear` (the inverse tone curve, then
    the transfer's decoding), evaluated in float64 and rounded once, so that every
    machine gets the same table. Both backends read integer images through it.

    Without a tone curve, the toe-curve transfers (sRGB, BT.2020, ROMM) and
    ``linear`` are evaluated in NumPy; a tone curve or a power gamma through the
    torch functions (importing torch).
    """
    codes = np.arange(top + 1, dtype=np.float64) / top
    spec = TransferSpec.parse(transfer)
    if tone == "none" and (spec.curve is not None or spec.kind == "linear"):
        linear = codes if spec.curve is None else spec.curve.decode(codes)
    else:
        import torch

        from rawsim.sensors import display_to_linear

        linear = display_to_linear(torch.from_numpy(codes), tone, transfer).numpy()
    return linear.astype(np.float32)


def _prepare(sensor, image, params, noise, display_referred, code_max):
    """Checks shared by the reference and the engine: ``image`` is (B, 3, H, W) as a
    tensor or (H, W, 3) as an array. Returns the noise levels and the lookup table
    of integer codes (float32 linear values, :func:`code_table`; a tensor on the
    image's device for a tensor), or None for float images."""
    if not isinstance(noise, NoiseLevels):
        check_choice("noise model", noise, NOISE_MODELS)
        noise = sensor.noise_levels(params.iso, noise)  # validates the ISO before any work
    array = isinstance(image, np.ndarray)
    h, w = image.shape[:2] if array else image.shape[-2:]
    if h % 2 or w % 2:
        raise ParameterError(f"image height and width must be even, got {h}×{w}")
    if noise.has_dark and noise.dark_shading is not None:
        check_fits(noise.dark_shading, h, w)
    kind = element_type(image)
    if kind in INTEGER_TYPES:
        if kind == "int32" and code_max is None:
            raise ParameterError("int32 codes need code_max (e.g. 255 or 65535)")
        top = code_max or int(np.iinfo(kind).max)
        if _reads_every_value(kind, code_max) and (int(image.min()) < 0 or int(image.max()) > top):
            raise ParameterError(f"integer codes must lie in [0, {top}]")
        lut = code_table(top, params.tone, params.transfer)
        if array:
            return noise, lut
        import torch

        return noise, torch.from_numpy(lut).to(image.device)
    if kind.startswith("float") or kind == "bfloat16":
        if array:  # a sum of float32 values in float64 is finite when each one is
            if image.ndim != 3 or image.shape[2] != 3:
                raise ParameterError(f"image must have shape (H, W, 3), got {image.shape}")
            if not np.isfinite(image.sum(dtype=np.float64)):
                raise ParameterError("image contains NaN or infinite values")
        else:
            check_image(image, "image", channels=3)
        return noise, None
    raise ParameterError(f"unsupported image dtype {kind}")


def unprocess_tensor(
    sensor: ProfileSensor,
    image: torch.Tensor,
    params: UnprocessParams,
    *,
    noise: str | NoiseLevels = "poisson-gaussian",
    key: int | None = None,
    display_referred: bool = True,
    code_max: int | None = None,
    clean: bool = False,
    lens: LensParams | None = None,
    out: tuple[torch.Tensor, torch.Tensor | None] | None = None,
    camera_rgb: bool = False,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Simulate the raw capture of ``image`` by ``sensor``.

    Args:
        image: (B, 3, H, W), H and W even. Either integer codes (uint8/uint16/int32,
            decoded through a lookup table of the display transform, with
            ``code_max`` the full-scale code, default the dtype's maximum; int32
            needs it), or float
            values: display-referred in [0, 1] if ``display_referred``, else
            scene-linear (1.0 = white level before exposure).
        params: the image's :class:`UnprocessParams` (ISO, matrix, gains, …).
        noise: noise model name (one of ``NOISE_MODELS``, nominal levels at the
            ISO) or resolved :class:`~rawsim.noise.models.NoiseLevels` (e.g. sampled).
        key: the noise seed (64-bit int; one per sample as a list, or one for
            the batch): see :func:`rawsim.noise.models.add_noise`. Needed unless the
            model is ``none``.
        clean: also return the noise-free mosaic.
        lens: a lens whose distortion, lateral CA and vignetting the capture gets
            (:meth:`RGBSensor.unprocess <rawsim.sensors.RGBSensor.unprocess>`), or
            None. It moves pixels across the frame: the image then runs as one strip.
        out: float32 (B, 1, H, W) tensors to write the noisy and (with ``clean``)
            clean mosaics into (the second one None unless ``clean``), or None (new
            tensors).
        camera_rgb: ``image`` is linear raw camera RGB (white at G = 1, a spectral
            scene's: :mod:`rawsim.spectral.render`), not sRGB: only the exposure
            scale and the lens act on it before the mosaic (no matrix, no inverse
            white balance); ``display_referred`` must be False.

    Returns:
        ``(noisy, clean)``: float32 (B, 1, H, W) integer DN in [0, white] (a mosaic
        in the sensor's CFA for an :class:`RGBSensor`, grey for a :class:`MonoSensor`),
        ``clean`` None unless asked for. Not differentiable (see
        :func:`rawsim.api.unprocess` for gradients).
    """
    import torch

    from rawsim import memory
    from rawsim.isp.lens_shading import radial_gain

    if image.ndim != 4 or image.shape[1] != 3:
        raise ParameterError(f"image must have shape (B, 3, H, W), got {tuple(image.shape)}")
    b, _, h, w = image.shape
    noise, lut = _prepare(sensor, image, params, noise, display_referred, code_max)
    shading = None
    if params.vignetting > 0:
        shading = radial_gain(h, w, strength=params.vignetting, device=image.device)
    if out is None:
        noisy = memory.empty((b, 1, h, w), torch.float32, image.device)
        clean_out = memory.empty((b, 1, h, w), torch.float32, image.device) if clean else None
    else:
        noisy, clean_out = out[0], out[1] if clean else None
    with values_checked(False), torch.no_grad():
        _run_strips(
            sensor,
            image,
            params,
            noise,
            key,
            display_referred,
            lut,
            shading,
            noisy,
            clean_out,
            lens,
            camera_rgb,
        )
    return noisy, clean_out


def strip_rows(sensor: ProfileSensor) -> int:
    """Rows of a reference strip: :data:`STRIP_ROWS` cut to whole CFA periods, so that
    each strip's mosaic starts on the period's first row (128 for Bayer, 126 for
    X-Trans)."""
    cfa = getattr(sensor, "cfa", None)  # a MonoSensor has none
    period = 1 if cfa is None else cfa.period[0]
    return STRIP_ROWS - STRIP_ROWS % period


def _run_strips(
    sensor,
    image,
    params,
    noise,
    key,
    display_referred,
    lut,
    shading,
    noisy,
    clean_out,
    lens,
    camera_rgb=False,
) -> None:
    from rawsim.isp.levels import quantize, saturate

    h = image.shape[-2]
    step = h if lens is not None else strip_rows(sensor)  # the lens samples the whole frame
    for top_row in range(0, h, step):
        rows = slice(top_row, top_row + step)
        strip = image[:, :, rows]
        if lut is not None:  # index_select with int32 indices is the fastest gather
            linear = lut.index_select(0, strip.reshape(-1).int()).view(strip.shape)
            in_type = "linear_rgb"
        else:
            linear = strip.float()
            in_type = "rgb" if display_referred else "linear_rgb"
        if camera_rgb:
            camera = _camera_rgb(linear, params, lens)
        else:
            camera = sensor.unprocess(linear, in_type, params, lens)
        dn = sensor.linrgb2raw(camera, params, None if shading is None else shading[..., rows, :])
        if clean_out is not None:
            clean_out[:, :, rows] = saturate(quantize(dn), sensor.white_level)
        noisy[:, :, rows] = sensor.simu_noise(dn, params.iso, noise, key, top_row, h)


def _camera_rgb(camera: torch.Tensor, params: UnprocessParams, lens) -> torch.Tensor:
    """Raw camera RGB (B, 3, H, W) as the sensor records it: the exposure scale, then
    the ``lens`` (on the whole frame) where there is one."""
    from rawsim.isp.lens import add_lens

    scale = params.linear_scale
    camera = camera * scale if scale != 1.0 else camera
    return camera if lens is None else add_lens(camera, lens)


@dataclass(frozen=True)
class SensorLayout:
    """What the compiled engine needs of a sensor, without torch: its ``profile`` and
    whether it is ``mono`` (no colour filter). :meth:`UnprocessOptions.layout` gives
    the options' one; a :class:`~rawsim.sensors.ProfileSensor` has the same
    attributes (``profile``, ``cfa`` for a colour one, ``noise_levels``), so
    either serves :func:`engine_unprocess`."""

    profile: SensorProfile
    mono: bool = False

    @property
    def cfa(self) -> CFA | None:
        """The profile's CFA, or None for a monochrome sensor."""
        return None if self.mono else self.profile.cfa

    def noise_levels(self, iso: float, model: str = "poisson-gaussian") -> NoiseLevels:
        """Noise parameters at ``iso`` (:meth:`ProfileSensor.noise_levels
        <rawsim.sensors.ProfileSensor.noise_levels>`)."""
        return self.profile.noise_levels(iso, model)


def engine_unprocess(
    sensor: ProfileSensor | SensorLayout,
    pixels: np.ndarray,
    params: UnprocessParams,
    *,
    noise: NoiseLevels,
    key: int,
    display_referred: bool = True,
    code_max: int | None = None,
    clean: bool = False,
    lens: LensParams | None = None,
    out: tuple[np.ndarray, np.ndarray | None] | None = None,
    bands: Iterable[tuple[int, int]] | None = None,
    camera_rgb: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`unprocess_tensor` for one (H, W, 3) image, by the compiled engine.

    ``pixels`` may have any strides (e.g. the (H, W, 3) view of a channels-first
    tensor, or a crop): the kernel reads them in place. Returns uint16 (H, W) noisy
    and clean codes, or writes them into ``out``: (H, W) arrays of uint16 or
    float32 (any strides; the same whole codes, exactly), ``out[1]`` None
    unless ``clean``. The same checks and lookup table as the reference; the stages
    fused in :func:`rawsim.engine.unprocess.unprocess_kernel`, after a whole-image
    pass through the ``lens`` if any (:func:`rawsim.engine.unprocess.lens_camera`).

    ``bands``: (start, stop) ranges of rows, in order and covering the image, as
    they become readable (an image still being decoded,
    :meth:`~rawsim.io.progress.DecodeProgress.bands`): the kernel unprocesses each
    as it comes, the same bits as the whole at once. An image that is read whole
    first (floats, whose values are checked; codes below their type's maximum; a
    lens) waits for the last band.

    ``camera_rgb``: ``pixels`` are float raw camera RGB (:func:`unprocess_tensor`'s
    ``camera_rgb``): the kernel runs with the identity matrix and unit gains.
    """
    from rawsim.engine import unprocess as kernels
    from rawsim.noise.kernels import np_key

    whole_first = lens is not None or _reads_every_value(element_type(pixels), code_max)
    if bands is not None and whole_first:
        for _ in bands:  # every row decoded before any is read
            pass
        bands = None
    noise, lut = _prepare(sensor, pixels, params, noise, display_referred, code_max)
    if lut is None and display_referred:  # display-referred floats: decode first
        import torch

        from rawsim.sensors import display_to_linear

        pixels = display_to_linear(torch.from_numpy(pixels), params.tone, params.transfer).numpy()
    cfa = getattr(sensor, "cfa", None)  # None: monochrome (a MonoSensor has no cfa)
    mono = cfa is None
    h, w = pixels.shape[:2]
    period = (2, 2) if mono else cfa.period
    bias = bias_tile(noise, cfa)
    bias = np.zeros(period) + (0.0 if bias is None else np.asarray(bias, np.float64))
    dark = _dark_draw(noise, key, h, w, cfa)
    noisy, clean_out = out if out is not None else (np.empty((h, w), np.uint16), None)
    if clean_out is None:
        clean_out = np.empty((h, w) if clean else (0, 0), noisy.dtype)
    lut = np.zeros(0, np.float32) if lut is None else lut
    scale = params.linear_scale
    ccm_bias = np.asarray(params.ccm_bias if params.ccm_bias and not mono else (0.0,) * 3, float)
    matrix = camera_from_srgb(params.xyz_to_camera)
    gains, safe = np.asarray(params.wb_gains, np.float64), params.safe_white_balance
    if camera_rgb:  # each channel unchanged but for the scale, exactly
        matrix, gains, safe, ccm_bias = np.eye(3), np.ones(3), False, np.zeros(3)
    if lens is not None:  # camera RGB through the lens, whole; then the rows as linear floats
        pixels = kernels.lens_camera(pixels, lut, scale, ccm_bias, matrix, mono, lens)
        lut, scale, ccm_bias, matrix = np.zeros(0, np.float32), 1.0, np.zeros(3), np.eye(3)
    run = (
        lut,
        scale,
        ccm_bias,
        matrix,
        gains,
        safe,
        SAFE_WB_THRESHOLD,
        mono,
        np.zeros(period, np.int64) if mono else np.array(cfa.colors).reshape(period),
        np.array([params.vignetting, *DEFAULT_K], np.float64),
        np.array([sensor.profile.black_level, sensor.profile.white_level], np.float64),
        kernels.MODEL_CODES[noise.model],
        kernels.noise_vector(noise, sensor.profile.black_level, dark),
        *kernels.noise_tables(noise),
        *np_key(key),
        bias,
        *kernels.dark_maps(noise, dark),
    )
    for start, stop in [(0, h)] if bands is None else bands:
        rows = slice(start, stop)
        kernels.unprocess_kernel(
            pixels[rows], *run, start, h, noisy[rows], clean_out[rows] if clean else clean_out
        )
    return noisy, clean_out if clean else None


def _dark_draw(levels: NoiseLevels, key: int, h: int, w: int, cfa):
    """:func:`rawsim.noise.models.dark_draw` (the physics model's per-file dark terms,
    drawn by the torch reference's generator), or None where ``levels`` have none:
    then torch is not imported."""
    if not levels.has_dark:
        return None
    from rawsim.noise.models import dark_draw

    return dark_draw(levels, key, h, w, cfa)


@dataclass(frozen=True)
class UnprocessOptions:
    """Options of the files job, the same for every file of a run.

    Attributes:
        profile: the sensor profile.
        iso: fixed ISO, or None when ``iso_range`` is given.
        iso_range: (min, max) for log-uniform ISO per file.
        randomize: sample Brooks et al.'s matrix, gains and brightness per file, and
            the noise levels around the profile's fits (ELD).
        clean: also write the noise-free mosaic.
        formats: output formats, a subset of ("dng", "npz").
        noise: noise model name.
        tone, transfer: display decoding of 8/16-bit inputs.
        exposure_ev: exposure in stops applied to linear light (all inputs).
        vignetting: strength of the added lens shading (0 = none).
        safe_white_balance: highlight-preserving inverse white balance (False: the
            exact one, the default).
        device: ``cpu``, ``cuda`` or ``auto``.
        seed: the run's seed (recorded in the sidecar).
        sensor: ``rgb`` (the profile's CFA: Bayer, X-Trans or any periodic layout;
            :meth:`~rawsim.cameras.profiles.SensorProfile.with_cfa` gives a profile another)
            or ``mono`` (no filter, the profile's levels and noise).
        strip_metadata: write none of the input's metadata (EXIF, GPS, XMP) into
            the DNGs; they keep only what the simulation sets (camera, ISO, lens).
        lens: the lens whose distortion, lateral chromatic aberration and
            vignetting are added (lensfun's, :mod:`rawsim.io.lensfun`), or None;
            its tags go into the DNG.
        illuminant: the light spectral scenes are rendered under (``--illuminant``:
            a name of :data:`rawsim.spectral.tables.ILLUMINANTS` or a file), in
            place of the one a scene carries; None: the scene's own (D65 for a
            reflectance that has none). Images (RGB) do not use it.
    """

    profile: SensorProfile
    iso: float | None = None
    iso_range: tuple[float, float] | None = None
    randomize: bool = False
    clean: bool = False
    formats: tuple[str, ...] = ("dng",)
    noise: str = "poisson-gaussian"
    tone: str = "none"
    transfer: str = "srgb"
    exposure_ev: float = 0.0
    vignetting: float = 0.0
    safe_white_balance: bool = False
    device: str = "cpu"
    seed: int = 0
    sensor: str = "rgb"
    strip_metadata: bool = False
    lens: LensParams | None = None
    illuminant: str | None = None

    def __post_init__(self) -> None:
        if self.lens is not None:  # a record (LensParams.to_dict()), e.g. from a sidecar
            object.__setattr__(self, "lens", LensParams.of(self.lens))
        if self.safe_white_balance and self.sensor == "mono":
            raise ParameterError(
                "--wb-inverse safe inverts a white balance; the mono sensor has none (it "
                "records grey): drop one of them"
            )

    def scene_linear_warning(self) -> list[str]:
        """The warning for a scene-linear input (EXR, float TIFF) where options that
        decode display-referred 8/16-bit inputs only were given (``--tone``,
        ``--transfer``, where not none and srgb): they cannot act on it."""
        given = [("--tone", self.tone, "none"), ("--transfer", self.transfer, "srgb")]
        given = [f"{flag} {value}" for flag, value, default in given if value != default]
        if not given:
            return []
        return [
            f"{' and '.join(given)} decode{'s' * (len(given) == 1)} 8/16-bit display-referred "
            "images; this one is scene-linear (floats): not applied"
        ]

    def with_cfa(self, cfa: str | None) -> UnprocessOptions:
        """These options with the profile's CFA replaced by ``cfa`` (``--cfa``: a Bayer
        name, ``XTRANS`` or rows); None keeps it. Raises :class:`ParameterError` for
        a layout :class:`~rawsim.cfa.CFA` refuses, or with the ``mono`` sensor."""
        if cfa is None:
            return self
        if self.sensor == "mono":
            raise ParameterError(f"a CFA ({cfa}) needs the rgb sensor: mono has no colour filter")
        return replace(self, profile=self.profile.with_cfa(cfa))

    def make_sensor(self) -> ProfileSensor:
        """The sensor simulated, for the torch reference: :class:`~rawsim.sensors.RGBSensor`
        or :class:`~rawsim.sensors.MonoSensor`."""
        from rawsim.sensors import MonoSensor, RGBSensor

        check_choice("sensor", self.sensor, SENSOR_KINDS)
        return (MonoSensor if self.sensor == "mono" else RGBSensor)(self.profile)

    def layout(self) -> SensorLayout:
        """The same sensor for the compiled engine (no torch)."""
        check_choice("sensor", self.sensor, SENSOR_KINDS)
        return SensorLayout(self.profile, mono=self.sensor == "mono")

    def check_isos(self) -> None:
        """Before any file is read: the ISO, or both ends of the ISO range, must lie in
        the profile's range, with parameters of the noise model there (a profile may
        lack the physics model's). Raises :class:`ParameterError`."""
        for value in (self.iso,) if self.iso is not None else self.iso_range:
            self.profile.check_iso(value)
            self.profile.noise.levels(self.noise, value)

    def output_suffixes(self) -> dict[str, str]:
        """Output kinds of every file → file-name suffixes."""
        out = {"json": ".json"}
        if "dng" in self.formats:
            out["dng"] = ".dng"
            if self.clean:
                out["clean_dng"] = ".clean.dng"
        if "npz" in self.formats:
            out["npz"] = ".npz"
        return out


def image_tensor(pixels: np.ndarray, device="cpu") -> torch.Tensor:
    """A decoded image's (H, W, 3) pixels → (1, 3, H, W) for :func:`unprocess_tensor`.

    uint16 codes become int32 (few kernels take uint16; the codes fit).
    """
    import torch

    image = torch.from_numpy(pixels).to(device).permute(2, 0, 1).unsqueeze(0)
    return image.to(torch.int32) if image.dtype == torch.uint16 else image


@dataclass(frozen=True)
class Simulation:
    """One simulated capture: mosaics (1, 1, H, W) of integer DN, and the values drawn.

    The mosaics are tensors: uint16 from the engine (float32 where :func:`simulate`
    wrote them into ``out`` tensors), float32 from the torch reference (same values);
    or uint16 NumPy arrays where :func:`simulate` wrote the engine's into ``out``
    arrays (the files job, which imports no torch). :meth:`codes` gives any of
    them as a uint16 (H, W) array.
    """

    noisy: torch.Tensor | np.ndarray
    clean: torch.Tensor | np.ndarray | None
    params: UnprocessParams
    levels: NoiseLevels

    @staticmethod
    def codes(mosaic: torch.Tensor | np.ndarray) -> np.ndarray:
        m = _plane(mosaic)
        return m if m.dtype == np.uint16 else m.astype(np.int32).astype(np.uint16)


def use_engine(image) -> bool:
    """Whether :func:`simulate` runs ``image`` on the compiled engine: a CPU image that
    needs no gradient, where numba is installed."""
    from rawsim import engine

    if not isinstance(image, np.ndarray) and (image.device.type != "cpu" or image.requires_grad):
        return False
    return engine.available()


def simulate(
    sensor: ProfileSensor | None,
    image: torch.Tensor | np.ndarray,
    options: UnprocessOptions,
    seed: int,
    *,
    display_referred: bool = True,
    code_max: int | None = None,
    engine: bool | None = None,
    out: tuple[torch.Tensor | np.ndarray, torch.Tensor | np.ndarray | None] | None = None,
    bands: Iterable[tuple[int, int]] | None = None,
    camera: tuple[np.ndarray, np.ndarray] | None = None,
) -> Simulation:
    """Simulate one image as the files job does, from its ``seed``.

    ``sensor``: the sensor simulated, or None for the options' own (its
    :meth:`~UnprocessOptions.layout` on the engine, which needs no torch, else
    :meth:`~UnprocessOptions.make_sensor`). ``image`` is (1, 3, H, W) on any
    device, or a decoded (H, W, 3) array.
    Parameters come from a generator seeded with ``derive_seed(seed, "params")``
    (then, under ``randomize``, the noise levels from the same generator), the
    noise from the counter-based generator keyed by ``derive_seed(seed, "noise")``.
    The files job passes ``derive_seed(run_seed, key)``: the same seed gives the
    same capture through the files or the Python API, on any device. ``engine``
    picks the compiled engine (True) or the torch reference (False); None
    chooses by :func:`use_engine`. Either reads ``image`` in its own layout
    (channels-first, channels-last or a crop; no copy). ``out``: float32
    (1, 1, H, W) tensors on the image's device for the noisy and (with
    ``options.clean``, else None) clean mosaics, written in place and returned
    in the :class:`Simulation` (the same values); on the engine also uint16
    (1, 1, H, W) arrays. ``bands``: the rows of an
    image array still being decoded, as they are written (see
    :func:`engine_unprocess`); the torch reference waits for the last.

    ``camera``: ``image`` is float raw camera RGB, a spectral scene's
    (:mod:`rawsim.spectral.render`), and this is its (XYZ → camera matrix, (3,)
    white-balance gains), which the params record in place of the profile's: the
    image skips the matrix and the inverse white balance (``camera_rgb`` of
    :func:`unprocess_tensor`). It takes neither ``options.randomize`` (which draws
    sRGB's matrix and gains) nor the mono sensor.
    """
    if camera is not None and (options.randomize or options.sensor == "mono"):
        given = "--randomize" if options.randomize else "--sensor mono"
        raise ParameterError(
            f"{given} does not apply to a spectral scene (its colour comes from the "
            f"camera's curves, through R, G and B filters): drop {given}"
        )
    layout = options.layout()  # the engine's sensor where none is given
    params_gen = None  # only draws need one (and torch)
    if options.randomize or options.iso_range is not None:
        import torch

        params_gen = torch.Generator().manual_seed(derive_seed(seed, "params"))
    params = sample_params(
        options.profile,
        iso=options.iso,
        iso_range=options.iso_range,
        randomize=options.randomize,
        generator=params_gen,
        exposure_ev=options.exposure_ev,
        tone=options.tone if display_referred else "none",
        transfer=options.transfer if display_referred else "linear",
        vignetting=options.vignetting,
        safe_white_balance=options.safe_white_balance,
    )
    if camera is not None:
        matrix, gains = camera
        params = replace(
            params,
            xyz_to_camera=tuple(tuple(float(v) for v in row) for row in matrix),
            wb_gains=tuple(float(g) for g in gains),
            safe_white_balance=False,
            ccm_bias=None,
        )
    if options.randomize:  # drawn after the params, from the same generator
        levels = options.profile.noise.sample_levels(options.noise, params.iso, params_gen)
    else:
        levels = (sensor or layout).noise_levels(params.iso, options.noise)
    run = dict(
        noise=levels,
        key=noise_key(seed),
        display_referred=display_referred,
        code_max=code_max,
        clean=options.clean,
        lens=options.lens,
        camera_rgb=camera is not None,
    )
    if use_engine(image) if engine is None else engine:
        pixels = image if isinstance(image, np.ndarray) else image[0].permute(1, 2, 0).numpy()
        arrays = None if out is None else tuple(None if t is None else _plane(t) for t in out)
        sensor = sensor or layout
        noisy, clean = engine_unprocess(sensor, pixels, params, **run, out=arrays, bands=bands)
        if out is not None:
            return Simulation(out[0], out[1] if options.clean else None, params, levels)
        import torch

        as_tensor = lambda m: None if m is None else torch.from_numpy(m)[None, None]  # noqa: E731
        return Simulation(as_tensor(noisy), as_tensor(clean), params, levels)
    for _ in bands or ():  # every row decoded first
        pass
    if isinstance(image, np.ndarray):
        image = image_tensor(image)
    sensor = sensor or options.make_sensor()
    noisy, clean = unprocess_tensor(sensor, image, params, **run, out=out)
    return Simulation(noisy, clean, params, levels)


def _plane(mosaic: torch.Tensor | np.ndarray) -> np.ndarray:
    """The (H, W) array of a (1, 1, H, W) array or tensor (no copy on the CPU)."""
    return mosaic[0, 0] if isinstance(mosaic, np.ndarray) else mosaic[0, 0].cpu().numpy()


def noise_key(seed: int) -> int:
    """The noise seed (Philox key) of a file whose seed is ``seed``."""
    return derive_seed(seed, "noise")


#: Decodes the next image of a batch while this one is unprocessed (:func:`read_ahead`).
_reader = ReadAhead()
#: The samples of a batch's last image, once unprocessed, for a later one of the same
#: size to be decoded into (:func:`~rawsim.io.images.read_image`).
_inputs = Spare()


def read_ahead(task: Task, options: UnprocessOptions) -> None:
    """Begin decoding ``task``'s image in a thread, for the :func:`unprocess_file` call
    that follows this one's (a batch's next file): OpenImageIO decodes while the
    engine unprocesses this image and the DNG writer writes it."""
    if is_spectral(task.source):
        _reader.start(task.source, read_spectral, task.source)
    else:
        _reader.start(task.source, read_image, task.source, _inputs)


def unprocess_file(task: Task, options: UnprocessOptions) -> dict:
    """Unprocess one image file into the outputs named by ``task``.

    The outputs are put in place as one set (:func:`~rawsim.io.outputs.atomic_outputs`).
    Returns the sidecar's metadata.
    """
    decoded, sim, out, seen = _decode_and_simulate(task, options)
    params, levels = sim.params, sim.levels
    metadata = _metadata(task, options, decoded, params, levels, seen)
    h, w = decoded.pixels.shape[:2]
    draw = _dark_draw(levels, noise_key(task.seed), h, w, options.layout().cfa)
    if draw is not None:  # where the dark-shading crop lies and the black-level offset
        metadata["noise"]["dark_draw"] = draw.to_dict()
    noisy_np = Simulation.codes(sim.noisy)
    clean_np = None if sim.clean is None else Simulation.codes(sim.clean)
    info = _dng_info(options, params, levels, decoded.orientation, _photo(task, options, decoded))
    if seen is not None:
        info = replace(info, colour=seen.dng_colour())
    with atomic_outputs(task.outputs) as tmp:
        if "dng" in tmp:
            write_dng(tmp["dng"], noisy_np, info)
        if "clean_dng" in tmp:
            write_dng(tmp["clean_dng"], clean_np, replace(info, noise_profile=None))
        if "npz" in tmp:
            with open_empty(tmp["npz"]) as fh:
                np.savez(fh, **npz_arrays(options, noisy_np, clean_np, metadata))
        tmp["json"].write_text(json.dumps(metadata, indent=2) + "\n")
    if out is not None:
        _spare.keep((*decoded.pixels.shape[:2], options.clean), out)
    _inputs.keep_array(decoded.pixels)
    return metadata


unprocess_file.read_ahead = read_ahead  # type: ignore[attr-defined]

#: Rows the engine waits for, at least, before it unprocesses a band of an image
#: being decoded (:func:`_decode_and_simulate`): a band of a 6000-wide image is
#: 4–5 ms of compute, against about 50 µs to start the kernel's threads.
BAND_ROWS = 256


def _decode_and_simulate(task: Task, options: UnprocessOptions):
    """Decode ``task``'s image and simulate its capture: (decoded image, simulation,
    the engine's output mosaics or None, the :class:`Seen` of a spectral scene or None).
    A spectral scene (:func:`~rawsim.io.spectral.is_spectral`) goes to :func:`_see_and_simulate`.

    An image that was not read ahead (a single file, a batch's first) is decoded in
    a reader thread while the engine unprocesses the rows decoded so far, where
    the decode gives the engine's input as it is (8/16-bit RGB of even size) on
    the CPU without a lens: the decode and the compute overlap. Otherwise the
    image is decoded (or its read ahead taken) first.
    """
    if is_spectral(task.source):
        return _see_and_simulate(task, options)
    device = resolve_device(options.device)
    decoding = progress = None
    if _reader.pending(task.source) or str(device) != "cpu" or options.lens is not None:
        decoded = _reader.take(task.source, read_image, task.source, _inputs)
    else:
        progress = DecodeProgress()
        decoding = _reader.run(read_image, task.source, _inputs, progress)
        pixels = progress.pixels()
        if pixels is None or not use_engine(pixels):  # decoded whole first
            decoded, progress = decoding.result(), None
    if progress is not None:  # the rows as they are decoded
        image, display_referred, code_max = pixels, True, CODE_MAX[pixels.dtype]
    else:
        pixels = decoded.pixels
        image = pixels if str(device) == "cpu" else image_tensor(pixels, device)
        display_referred, code_max = not decoded.is_float, decoded.code_max
    out = _mosaics(*pixels.shape[:2], options.clean) if use_engine(image) else None
    sim = simulate(
        None,  # the options' sensor
        image,
        options,
        task.seed,
        display_referred=display_referred,
        code_max=code_max,
        out=out,
        bands=None if progress is None else progress.bands(BAND_ROWS),
    )
    if progress is not None:
        decoded = decoding.result()  # raises why, if the decode failed
    return decoded, sim, out, None


@dataclass(frozen=True)
class Seen:
    """How a spectral scene was seen: the ``scene`` as read, the camera's ``curves``
    (:class:`~rawsim.cameras.spectra.Curves`), the ``light``
    (:class:`~rawsim.spectral.render.Light`), the DNG's ``matrices`` (XYZ → camera
    under A and under D65) and the camera's ``neutral`` (3,) under the light."""

    scene: SpectralScene
    curves: Curves
    light: Light
    matrices: tuple[np.ndarray, np.ndarray]
    neutral: np.ndarray

    def dng_colour(self) -> DngColour:
        """ColorMatrix1 under standard light A, ColorMatrix2 under D65."""
        from rawsim.spectral.render import ILLUMINANT_A, ILLUMINANT_D65

        a, d65 = self.matrices
        return DngColour({1: (ILLUMINANT_A, a), 2: (ILLUMINANT_D65, d65)}, {}, None)

    def to_dict(self) -> dict:
        """The sidecar's ``spectral`` record (:func:`rawsim.spectral.render.record`)."""
        from rawsim.spectral.render import record

        s = self.scene
        return record(s.kind, s.wavelengths, self.curves, self.light, self.neutral, self.matrices)


def _see_and_simulate(task: Task, options: UnprocessOptions):
    """Read ``task``'s spectral scene, see it through the profile's camera curves under
    its light (:mod:`rawsim.spectral.render`: raw camera RGB, white at G = 1) and
    simulate the capture from there (mosaic, levels, noise): the return of
    :func:`_decode_and_simulate`."""
    from rawsim import engine
    from rawsim.spectral import render

    # The scene is read in a reader thread (an npz mapped, its values checked: numpy
    # reductions, without the GIL) while this one fits the camera's DNG matrices
    # (once per camera and process) and imports the engine: 0.2-0.4 s each.
    ahead = _reader.pending(task.source)
    reading = None if ahead else _reader.run(read_spectral, task.source)
    curves = render.curves_for(options.profile)
    matrices = render.dng_matrices(curves)
    engine.available()
    scene = _reader.take(task.source, read_spectral, task.source) if ahead else reading.result()
    light, warning = render.light_of(
        scene.illuminant, options.illuminant, scene.wavelengths, scene.kind, str(task.source)
    )
    pixels = render.camera_rgb(
        scene.spectra, scene.wavelengths, curves.rgb, light.spectrum, scene.kind
    )
    neutral = render.neutral(curves.rgb, light.spectrum)
    decoded = DecodedImage(
        pixels=pixels,
        code_max=None,
        orientation=1,
        source_size=scene.source_size,
        dropped_channels=scene.dropped_channels,
        format_name=f"{scene.format_name} (spectral)",
        warnings=(warning,) if warning else (),
    )
    device = resolve_device(options.device)
    image = pixels if str(device) == "cpu" else image_tensor(pixels, device)
    out = _mosaics(*pixels.shape[:2], options.clean) if use_engine(image) else None
    sim = simulate(
        None,
        image,
        options,
        task.seed,
        display_referred=False,
        out=out,
        camera=(matrices[1], 1.0 / neutral),
    )
    return decoded, sim, out, Seen(scene, curves, light, matrices, neutral)


#: The engine's output mosaics of a batch's last file, once written, for the next
#: file of the same size to write over (:func:`_mosaics`).
_spare = Spare()


def _mosaics(h: int, w: int, clean: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """uint16 (1, 1, h, w) noisy and (with ``clean``) clean mosaics for the engine to
    write: the last file's, if it was this size, else new ones."""

    def new():
        mosaic = lambda: np.empty((1, 1, h, w), np.uint16)  # noqa: E731
        return mosaic(), mosaic() if clean else None

    return _spare.take((h, w, clean), new)


def _iso_warning(options: UnprocessOptions) -> list[str]:
    """A fixed ISO that is not a whole number is rounded in the DNG (an integer tag)."""
    iso = options.iso
    if iso is None or float(iso).is_integer():
        return []
    return [
        f"ISO {iso:g} is written as {round(iso)} in the DNG (an integer tag); "
        f"the sidecar keeps {iso:g}"
    ]


def _colour_warning(options: UnprocessOptions) -> list[str]:
    """A colour sensor simulated with a profile that has no colour matrix."""
    warning = options.profile.colour_warning
    return [warning] if warning and options.sensor != "mono" else []


def _illuminant_warning(options: UnprocessOptions) -> list[str]:
    """``--illuminant`` given for an RGB image, which it cannot act on."""
    if options.illuminant is None:
        return []
    return [
        f"--illuminant {options.illuminant} lights spectral scenes only: this image is "
        "RGB (its light is in its white balance), so it is not used"
    ]


#: The smallest X-Trans image LibRaw demosaics with its default interpolation, rows
#: and columns alike. Measured with rawpy 0.28 / LibRaw 0.22.2 (tests/test_startup.py
#: checks it): 510 × 900 and 900 × 510 DNGs fail with an I/O error in
#: ``postprocess()``, 512 × 512 ones render; LibRaw treats any 6 × 6
#: CFARepeatPatternDim as X-Trans. Its half-size and linear renders take any size.
LIBRAW_XTRANS_MIN = 512


def _libraw_size_warning(options: UnprocessOptions, h: int, w: int) -> list[str]:
    """Why LibRaw (rawpy, and the tools built on it) cannot render an h × w X-Trans
    DNG with its default demosaic, and what to do; none where it can."""
    if "dng" not in options.formats or options.sensor == "mono":
        return []
    if tuple(options.profile.cfa.period) != (6, 6) or min(h, w) >= LIBRAW_XTRANS_MIN:
        return []
    return [
        f"{w}×{h} X-Trans DNG: LibRaw (rawpy) cannot demosaic one under "
        f"{LIBRAW_XTRANS_MIN}×{LIBRAW_XTRANS_MIN} (its postprocess() fails with an I/O "
        "error; half_size or a linear demosaic work): give larger images, or a Bayer "
        "profile or --cfa RGGB"
    ]


def npz_planes(options: UnprocessOptions) -> tuple[str, ...]:
    """The names of the npz mosaic's planes (its axis 0): ``R, Gr, Gb, B`` for a Bayer
    CFA, :data:`MOSAIC_PLANE` for any other (the whole mosaic), ``Y`` for mono."""
    if options.sensor == "mono":
        return ("Y",)
    return PACKED_PLANES if options.profile.cfa.is_bayer else (MOSAIC_PLANE,)


def npz_arrays(
    options: UnprocessOptions, noisy: np.ndarray, clean: np.ndarray | None, metadata: dict
) -> dict[str, np.ndarray]:
    """The arrays of ``<stem>.npz``, from (H, W) uint16 codes.

    ``mosaic`` (and ``clean``): uint16 (4, H/2, W/2) R, Gr, Gb, B planes for a Bayer
    CFA (:meth:`~rawsim.cfa.CFA.pack`); (1, H, W), the mosaic as the sensor records
    it, for any other CFA and for mono. ``planes``: their names
    (:func:`npz_planes`). A CFA that is not Bayer adds ``cfa_pattern`` (the
    :class:`~rawsim.cfa.CFA` string, rows joined by ``/``) and ``cfa_colors``,
    uint8 (ph, pw), the colour (R=0, G=1, B=2) of each site of one period from the
    top-left pixel. ``metadata``: the sidecar as JSON.
    """
    cfa = options.layout().cfa
    whole = cfa is None or not cfa.is_bayer
    arrange = (lambda m: m[None]) if whole else cfa.pack_array  # noqa: E731
    arrays = {"mosaic": arrange(noisy)}
    if clean is not None:
        arrays["clean"] = arrange(clean)
    arrays["planes"] = np.array(npz_planes(options))
    if cfa is not None and whole:
        arrays["cfa_pattern"] = np.array(cfa.pattern)
        arrays["cfa_colors"] = np.array(cfa.colors, np.uint8).reshape(cfa.period)
    arrays["metadata"] = np.array(json.dumps(metadata))
    return arrays


def _photo(task: Task, options: UnprocessOptions, decoded) -> PhotoMetadata:
    """The input's EXIF, GPS and XMP for its DNGs (none with ``strip_metadata``); the
    capture time OpenImageIO found (an EXR header's) where exiv2 finds none."""
    if options.strip_metadata:
        return PhotoMetadata()
    photo = read_metadata(task.source, libraw=False)
    if decoded.datetime and not photo.get("Exif.Photo.DateTimeOriginal"):
        time = ("Exif.Photo.DateTimeOriginal", decoded.datetime)
        photo = PhotoMetadata((time, *photo.exif), photo.xmp, photo.source)
    return photo


def _dng_info(
    options: UnprocessOptions, params: UnprocessParams, levels, orientation, photo
) -> DngInfo:
    profile = options.profile
    return DngInfo(
        cfa=options.layout().cfa,
        black_level=profile.black_level,
        white_level=profile.white_level,
        xyz_to_camera=params.xyz_to_camera,
        as_shot_neutral=tuple(1.0 / g for g in params.wb_gains),
        make=profile.make,
        model=profile.model,
        unique_model=f"{profile.make} {profile.model}",
        iso=params.iso,
        noise_profile=None
        if levels.model == "none"
        else levels.noise_profile(profile.black_level, profile.white_level),
        baseline_exposure=params.baseline_exposure,
        orientation=orientation if 1 <= orientation <= 8 else 1,
        software=f"rawsim {__version__}",
        metadata=photo,
        lens=options.lens,
    )


def _metadata(
    task: Task, options: UnprocessOptions, decoded, params, levels, seen: Seen | None = None
) -> dict:
    """The sidecar. A spectral scene's (``seen``) is of input kind ``spectral``, with a
    ``spectral`` record (:meth:`Seen.to_dict`), and no warning about the profile's
    matrix: its colour comes from the curves."""
    profile, cfa = options.profile, options.layout().cfa
    h, w = decoded.pixels.shape[:2]
    kind = "scene-linear" if decoded.is_float else "display-referred"
    meta = {
        "rawsim_version": __version__,
        "input": task.key,
        "input_kind": "spectral" if seen is not None else kind,
        "input_format": decoded.format_name,
        "code_max": decoded.code_max,
        "crop": decoded.crop,
        "dropped_channels": list(decoded.dropped_channels),
        "warnings": list(decoded.warnings)
        + (options.scene_linear_warning() if decoded.is_float else [])
        + _iso_warning(options)
        + (_colour_warning(options) + _illuminant_warning(options) if seen is None else [])
        + _libraw_size_warning(options, h, w),
        "orientation": decoded.orientation,
        "width": w,
        "height": h,
        "profile": {
            "name": profile.name,
            "make": profile.make,
            "model": profile.model,
            "path": profile.path,
            "noise_kind": profile.noise_kind,  # measured, estimated, or None (unstated)
            "noise_source": profile.source.get("noise.gain"),
        },
        "sensor": options.sensor,
        "cfa_pattern": None if cfa is None else cfa.pattern,
        "packed_planes": list(npz_planes(options)),
        "bit_depth": profile.bit_depth,
        "black_level": profile.black_level,
        "white_level": profile.white_level,
        "seed": options.seed,
        "file_seed": task.seed,
        "randomize": options.randomize,
        "params": params.to_dict(),
        "baseline_exposure": params.baseline_exposure,
        "as_shot_neutral": [1.0 / g for g in params.wb_gains],
        "noise": levels.to_dict(),
        "outputs": {k: p.name for k, p in task.outputs.items()},
    }
    if options.lens is not None:  # absent without one: outputs as before
        meta["lens"] = options.lens.to_dict()
    if seen is not None:
        meta["spectral"] = seen.to_dict()
    if levels.model != "none":
        span = profile.white_level - profile.black_level
        a, b = levels.affine_variance(span)
        meta["noise"]["variance_dn2"] = {"per_dn_above_black": a, "offset": b}
        meta["noise"]["noise_profile"] = list(
            levels.noise_profile(profile.black_level, profile.white_level)
        )
    return meta
