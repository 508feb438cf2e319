"""Batch unprocessing and processing for training pipelines.

:func:`unprocess` simulates a batch of captures, each from its own seed, exactly
as ``rawsim unprocess`` simulates a file (:func:`unprocess_spectral` one spectral
scene); :func:`process` renders the mosaics
back to RGB through the ISP. Both are differentiable where the maths allows.
Shapes: images (B, 3, H, W) with H, W even; mosaics (B, 1, H, W) in DN.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import torch

from rawsim import memory
from rawsim.errors import ParameterError, RawsimWarning, check_choice
from rawsim.io.lensfun import LensParams
from rawsim.io.raw import RawImage
from rawsim.isp.config import IspConfig
from rawsim.isp.pipeline import build_isp
from rawsim.noise.seeds import derive_seed
from rawsim.pipelines.process import render_float
from rawsim.pipelines.unprocess import INTEGER_TYPES, UnprocessOptions, element_type, simulate
from rawsim.sensors import MonoSensor, ProfileSensor


def file_seed(run_seed: int, key: str) -> int:
    """The seed ``rawsim unprocess --seed RUN_SEED`` gives the input whose key is ``key``.

    The key is the file's path relative to the input folder given on the
    command line (or its name, for a file given directly), with ``/`` separators.
    """
    return derive_seed(run_seed, key)


def unprocess(
    images: torch.Tensor,
    sensor: ProfileSensor,
    seeds: Sequence[int],
    *,
    iso: float | Sequence[float] | None = None,
    iso_range: tuple[float, float] | None = None,
    randomize: bool = False,
    noise: str = "poisson-gaussian",
    tone: str = "none",
    transfer: str = "srgb",
    exposure_ev: float = 0.0,
    vignetting: float = 0.0,
    safe_white_balance: bool = False,
    display_referred: bool = True,
    code_max: int | None = None,
    lens: LensParams | dict | None = None,
    out: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, list[dict]]:
    """Simulate the raw captures of a batch: returns ``(noisy, clean, metadata)``.

    Args:
        images: (B, 3, H, W) on any device: integer codes (uint8/uint16/int32, with
            ``code_max`` the full-scale code) or floats, display-referred in [0, 1]
            unless ``display_referred`` is False (then scene-linear).
        sensor: an :class:`~rawsim.sensors.RGBSensor` (a mosaic in its CFA: Bayer,
            X-Trans or any periodic layout, e.g. ``RGBSensor(profile, cfa="XTRANS")``)
            or a :class:`~rawsim.sensors.MonoSensor` (grey).
        seeds: one int per sample. Sample i is bit for bit what the files job
            writes for a file whose seed is ``seeds[i]`` (see :func:`file_seed`),
            on the same device.
        iso: one ISO for all, one per sample, or None with ``iso_range``
            (log-uniform per sample, from its seed).
        iso_range: (MIN, MAX) for ``iso=None``, as ``--iso-range``.
        randomize: as ``--randomize``.
        noise: as ``--noise``.
        tone: as ``--tone``.
        transfer: as ``--transfer``.
        exposure_ev: as ``--exposure``.
        vignetting: as ``--vignetting``.
        safe_white_balance: True for ``--wb-inverse safe``, False for ``exact`` (the
            default).
        display_referred: False for scene-linear float images (as EXR inputs).
        code_max: the full-scale code of integer ``images`` (255 for 8-bit).
        lens: as ``--lens``, ``--focal-length``, ``--aperture``: a
            :class:`~rawsim.io.lensfun.LensParams` (:func:`~rawsim.io.lensfun.lens_params`
            builds one) or its record; each image is the whole frame the lens saw.
        out: float32 (B, 1, H, W) tensors on the images' device for ``noisy`` and
            ``clean``, written and returned (not with gradients). Without
            ``out``, new CPU tensors take the memory of earlier outputs that
            nothing refers to any more (:mod:`rawsim.memory`), which spares the
            fresh memory's first touch (0.05–0.2 s for a 24 MP batch of one).

    Returns:
        ``noisy`` and ``clean``: float32 (B, 1, H, W) integer DN in [0, white];
        ``metadata``: one dict per sample (seed, ISO, sampled parameters, noise
        levels, levels and CFA). If ``images`` requires grad (floats only),
        ``clean`` is the unrounded DN with its graph and ``noisy`` is ``clean``
        plus the sampled noise (held constant), so gradients reach the images.
        Without gradients the kernel reads ``images`` in their own layout
        (channels-first or -last, crops: any strides) and writes each sample
        straight into its slice of the returned tensors (on the CPU, tensors
        whose storage cannot grow: ``resize_`` beyond their size fails).
    """
    b = images.shape[0] if images.ndim == 4 else 0
    if len(seeds) != b:
        raise ParameterError(f"need one seed per image: {len(seeds)} seeds for a batch of {b}")
    isos = list(iso) if isinstance(iso, Sequence) else [iso] * b
    if len(isos) != b:
        raise ParameterError(f"need one ISO per image: {len(isos)} ISOs for a batch of {b}")
    grad = torch.is_grad_enabled() and images.requires_grad
    options = UnprocessOptions(
        profile=sensor.profile,
        iso_range=iso_range,
        randomize=randomize,
        clean=not grad,  # with gradients, clean comes from the differentiable stages
        noise=noise,
        tone=tone,
        transfer=transfer,
        exposure_ev=exposure_ev,
        vignetting=vignetting,
        safe_white_balance=safe_white_balance,
        sensor="mono" if isinstance(sensor, MonoSensor) else "rgb",
        lens=lens,
    )
    for warning in [] if display_referred else options.scene_linear_warning():
        warnings.warn(warning, RawsimWarning, stacklevel=2)
    if grad and element_type(images) in INTEGER_TYPES:
        raise ParameterError("gradients need float images")
    noisy, clean, metadata = [], [], []
    if not grad:  # written in place by each sample's kernel: no copies, no concatenation
        noisy, clean = _outputs(out, (b, 1, *images.shape[-2:]), images.device)
    elif out is not None:
        raise ParameterError("out= is for unprocessing without gradients")
    for i in range(b):
        sim = simulate(
            sensor,
            images[i : i + 1].detach(),
            replace(options, iso=isos[i]),
            int(seeds[i]),
            display_referred=display_referred,
            code_max=code_max,
            out=None if grad else (noisy[i : i + 1], clean[i : i + 1]),
        )
        if grad:
            in_type = "rgb" if display_referred else "linear_rgb"
            camera = sensor.unprocess(images[i : i + 1], in_type, sim.params, options.lens)
            c = sensor.linrgb2raw(camera, sim.params)
            noisy.append(sim.noisy.float() + (c - c.detach()))  # the capture's values, c's graph
            clean.append(c)
        metadata.append(capture_metadata(sensor, options, int(seeds[i]), sim))
    if grad:
        return torch.cat(noisy), torch.cat(clean), metadata
    return noisy, clean, metadata


def unprocess_spectral(
    spectra: np.ndarray,
    wavelengths: Sequence[float],
    sensor: ProfileSensor,
    seed: int,
    *,
    kind: str = "reflectance",
    illuminant: str | np.ndarray | None = None,
    iso: float | None = None,
    iso_range: tuple[float, float] | None = None,
    noise: str = "poisson-gaussian",
    exposure_ev: float = 0.0,
    vignetting: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Simulate the raw capture of one spectral scene, exactly as ``rawsim unprocess``
    does for a spectral ``.npz`` whose seed is ``seed``: returns ``(noisy, clean,
    metadata)``.

    Args:
        spectra: (H, W, N) float32 (any strides), finite and ≥ 0: reflectance, or
            radiance with ``kind="radiance"``; an odd last row or column is left out,
            as the command leaves it.
        wavelengths: (N,) nm, increasing, spanning 400–700.
        sensor: an :class:`~rawsim.sensors.RGBSensor` whose profile's camera has
            spectral sensitivities (measured or estimated: :mod:`rawsim.cameras.spectra`).
        seed: the capture's seed (:func:`file_seed` of the run's seed and a key).
        kind: ``"reflectance"`` or ``"radiance"``.
        illuminant: the light, as ``--illuminant`` takes it (a name of
            :data:`rawsim.spectral.tables.ILLUMINANTS` or a file) or an (N,) spectrum
            on ``wavelengths``; None: D65 for a reflectance (a radiance needs one).
        iso: the ISO, as :func:`unprocess` takes one (None with ``iso_range``).
        iso_range: as :func:`unprocess`.
        noise: as :func:`unprocess`.
        exposure_ev: as :func:`unprocess`.
        vignetting: as :func:`unprocess`.

    Returns:
        ``noisy`` and ``clean``: float32 (1, 1, H, W) DN; ``metadata``: as
        :func:`unprocess`'s, with ``spectral``: the curves, the light, the camera's
        neutral and the XYZ → camera matrices fitted for A and D65 (a DNG's
        ColorMatrix1 and 2), as the sidecar's.
    """
    from rawsim.io.spectral import KINDS, SpectralScene, checked
    from rawsim.spectral import render

    scene = np.asarray(spectra)
    if scene.ndim != 3 or scene.dtype != np.float32:
        raise ParameterError(f"spectra must be float32 (H, W, N), got {scene.dtype} {scene.shape}")
    nm = np.asarray(wavelengths, dtype=np.float64)
    if nm.shape != (scene.shape[2],):
        raise ParameterError(f"need one wavelength per band: {nm.shape[0]} for {scene.shape[2]}")
    check_choice("kind", kind, KINDS)
    size = (scene.shape[1], scene.shape[0])
    given_scene = SpectralScene(scene, nm, kind, illuminant, "array", size)
    scene = checked("spectra", given_scene).spectra  # NaN, negative values, size: refused
    carried = illuminant if isinstance(illuminant, np.ndarray) else None
    given = None if carried is not None else illuminant
    curves = render.curves_for(sensor.profile)
    light, _ = render.light_of(carried, given, nm, kind, "the scene")
    pixels = render.camera_rgb(scene, nm, curves.rgb, light.spectrum, kind)
    neutral = render.neutral(curves.rgb, light.spectrum)
    matrices = render.dng_matrices(curves)
    options = UnprocessOptions(
        profile=sensor.profile,
        iso=iso,
        iso_range=iso_range,
        clean=True,
        noise=noise,
        exposure_ev=exposure_ev,
        vignetting=vignetting,
    )
    image = torch.from_numpy(pixels).permute(2, 0, 1)[None]  # channels-last, no copy
    noisy, clean = _outputs(None, (1, 1, *pixels.shape[:2]), image.device)
    sim = simulate(
        sensor,
        image,
        options,
        int(seed),
        display_referred=False,
        out=(noisy, clean),
        camera=(matrices[1], 1.0 / neutral),
    )
    spectral = render.record(kind, nm, curves, light, neutral, matrices)
    return noisy, clean, capture_metadata(sensor, options, int(seed), sim) | {"spectral": spectral}


def _outputs(out, shape: tuple[int, ...], device: torch.device) -> tuple[torch.Tensor, ...]:
    """The (noisy, clean) tensors to write: ``out``, checked, or two new ones."""
    if out is None:
        return tuple(memory.empty(shape, torch.float32, device) for _ in range(2))
    if len(out) != 2 or any(
        t.shape != shape or t.dtype != torch.float32 or t.device != device for t in out
    ):
        got = [(tuple(t.shape), t.dtype, str(t.device)) for t in out]
        raise ParameterError(f"out must be two float32 tensors {shape} on {device}, got {got}")
    return tuple(out)


def capture_metadata(sensor: ProfileSensor, options: UnprocessOptions, seed: int, sim) -> dict:
    """What a simulated capture drew and used: seed, ISO, CFA, levels, parameters, noise."""
    p = sensor.profile
    mono = options.sensor == "mono"
    return {
        "seed": seed,
        "iso": sim.params.iso,
        "sensor": options.sensor,
        "cfa_pattern": None if mono else p.cfa.pattern,
        "black_level": p.black_level,
        "white_level": p.white_level,
        "params": sim.params.to_dict(),
        "noise": sim.levels.to_dict(),
    } | ({} if options.lens is None else {"lens": options.lens.to_dict()})


def process(
    mosaics: torch.Tensor,
    sensor: ProfileSensor,
    metadata: Sequence[dict],
    config: IspConfig | list[dict] | None = None,
    **changes,
) -> torch.Tensor:
    """Render mosaics from :func:`unprocess` back to images through the ISP.

    Args:
        mosaics: (B, 1, H, W) DN.
        sensor: the sensor that recorded them.
        metadata: :func:`unprocess`'s dicts: each sample's white balance and
            matrix are used (``white_balance`` mode ``camera``), and its baseline
            exposure (the DNG's BaselineExposure) unless the config ignores it.
        config: an ISP config (see ``rawsim isp show``), typed or as its TOML tables;
            default: the default ISP.
        changes: stage overrides as ``rawsim process`` takes them, e.g.
            ``demosaic="bilinear"``.

    Returns:
        (B, 3, H, W) display-referred sRGB (B, 1, H, W for a mono sensor).
        Differentiable when gradients are enabled (the ISP then runs full frame).
        Without gradients, CPU mosaics of whole DN render on the compiled engine
        (within 1e-5 of the reference).

    What ``rawsim process`` would warn (e.g. ``denoise="profiled"`` for a mono sensor,
    which has no mosaic to denoise) is warned once per call as a
    :class:`~rawsim.errors.RawsimWarning`.
    """
    if mosaics.ndim != 4 or mosaics.shape[1] != 1 or len(metadata) != mosaics.shape[0]:
        raise ParameterError(
            f"need mosaics (B, 1, H, W) and one metadata dict each, got "
            f"{tuple(mosaics.shape)} and {len(metadata)}"
        )
    config = IspConfig.of(config) if config is not None else IspConfig.default()
    if changes:
        config = config.override(**changes)
    mono = isinstance(sensor, MonoSensor)
    p = sensor.profile
    outs, said = [], {}
    for i, meta in enumerate(metadata):
        params = meta["params"]
        raw = RawImage(
            data=np.empty((0, 0, 1) if mono else (0, 0), dtype=np.uint16),
            cfa=None if mono else p.cfa,
            black_level=np.full((1,) if mono else p.cfa.period, p.black_level),
            white_level=p.white_level,
            as_shot_wb=None if mono else tuple(params["wb_gains"]),
            daylight_wb=None,
            xyz_to_camera=None if mono else np.asarray(params["xyz_to_camera"]),
            camera_to_srgb=None,
            orientation=1,
            iso=meta["iso"],
            baseline_exposure=math.log2(params["brightness"]) - params["exposure_ev"],
            make=p.make,
            model=p.model,
            path="<tensor>",
        )
        grad = torch.is_grad_enabled() and mosaics.requires_grad
        codes = None if grad else _codes(mosaics[i, 0])
        if codes is not None:
            out, info = render_float(replace(raw, data=codes[..., None] if mono else codes), config)
            outs.append(out.to(mosaics.device))
        else:
            isp = build_isp(config, raw).to(mosaics.device)
            outs.append(isp(mosaics[i : i + 1]))
            info = isp.info
        said.update(dict.fromkeys(info["warnings"]))
    for warning in said:  # each once, not once per sample
        warnings.warn(warning, RawsimWarning, stacklevel=2)
    return outs[0] if len(outs) == 1 else torch.cat(outs)  # one sample: its render, uncopied


def _codes(mosaic: torch.Tensor) -> np.ndarray | None:
    """A CPU (H, W) mosaic of whole DN in [0, 65535] as uint16 codes (what the compiled
    engine reads), else None. One cast and one comparison: a value that is not a
    whole number in range (or NaN) casts to a code unequal to it."""
    if mosaic.device.type != "cpu":
        return None
    values = mosaic.detach()
    values = values.numpy() if values.dtype != torch.bfloat16 else values.float().numpy()
    with np.errstate(invalid="ignore"):  # out of range: any code, unequal to the value
        codes = values.astype(np.uint16)
    return codes if np.array_equal(codes, values) else None
