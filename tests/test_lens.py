"""Lens correction from lensfun (distortion, TCA, vignetting), both ways, both backends.

* The correction agrees with lensfun's own ``Modifier`` (its coordinates, its
  devignetting) on a photo; vignetting gains match lensfun's.
* The compiled engine equals the torch reference: the remap functions, and whole
  renders through the process pipeline (Bayer, X-Trans, half size, orientations,
  strips and tiles).
* gradcheck in float64; adding the lens then correcting it gives the photo back.
* Lookups: the metadata's lens, a named lens, and one-line warnings and errors.
* ``rawsim process --lens-correction auto`` and ``--lens`` on DNGs built here.
"""

from __future__ import annotations

import json
from dataclasses import replace

import exiv2
import lensfunpy
import numpy as np
import pytest
import torch
from click.testing import CliRunner
from PIL import Image
from scipy.ndimage import gaussian_filter

from rawsim.cfa import CFA
from rawsim.engine import lens as engine_lens
from rawsim.errors import ParameterError
from rawsim.io.dng import DngInfo, write_dng
from rawsim.io.lensfun import (
    LensParams,
    database,
    lens_field,
    lens_params,
    raw_lens,
    tca_field,
    without_tca,
)
from rawsim.io.metadata import PhotoMetadata
from rawsim.isp.config import IspConfig, LensCorrectionStage, default_config, override
from rawsim.isp.lens import (
    PADDINGS,
    LensCorrection,
    MosaicTca,
    add_lens,
    correct_lens,
    correct_mosaic_tca,
    remap_lens,
)
from rawsim.isp.pipeline import build_isp
from rawsim.pipelines.process import engine_plan, engine_render, render, render_float
from rawsim_cli.main import cli
from tests.conftest import DATA, numba_threads, psnr, thread_counts
from tests.test_engine_process import _assert_close, _both, base_config, synthetic_raw

#: A kit zoom with strong barrel distortion at its widest (8 % at the corners),
#: lateral CA (poly3) and vignetting in lensfun, on the APS-C camera it came with.
KIT = dict(lens="E PZ 16-50mm f/3.5-5.6 OSS", make="SONY", model="ILCE-6000")
#: lensfun's other models and conventions: poly3 distortion with poly3 TCA (its √
#: term too); poly5 on a compact; a Four Thirds (4:3) calibration; a full-frame
#: calibration on an APS-C camera.
OTHERS = [
    ("Tamron SP AF 10-24mm f/3.5-4.5 Di II LD Aspherical (IF)", "NIKON CORPORATION",
     "NIKON D7000", 10.0),
    ("Canon PowerShot G12 & compatibles (Standard)", "Canon", "Canon PowerShot G12", 6.1),
    ("Olympus M.Zuiko Digital ED 12-50mm f/3.5-6.3 EZ", "OLYMPUS IMAGING CORP.", "E-M5", 12.0),
    ("Canon EF 24-105mm f/4L IS USM", "Canon", "Canon EOS 700D", 24.0),
]  # fmt: skip


def kit(aperture: float | None = 8.0, focal: float = 16.0, **kw) -> LensParams:
    params, warnings = lens_params(
        KIT["lens"], focal, aperture, None, KIT["make"], KIT["model"], **kw
    )
    assert aperture is None or not warnings
    return params


def photo(name: str = "chelsea.png") -> np.ndarray:
    """A photo as (H, W, 3) float32 in [0, 1] (its values taken as linear)."""
    with Image.open(DATA / "srgb" / name) as im:
        return np.asarray(im.convert("RGB"), np.float32) / 255


def _tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(image).permute(2, 0, 1)[None]


def _numpy(image: torch.Tensor) -> np.ndarray:
    return image[0].permute(1, 2, 0).numpy()


def _centre(a: np.ndarray, share: float = 0.9) -> np.ndarray:
    """The central ``share`` of an (H, W, …) array's width and height."""
    h, w = a.shape[:2]
    mh, mw = round(h * (1 - share) / 2), round(w * (1 - share) / 2)
    return a[mh : h - mh, mw : w - mw]


# ---- agreement with lensfun --------------------------------------------------------------


def _lensfun(params: LensParams, h: int, w: int, flags: int, reverse: bool = False):
    """lensfun's own Modifier for ``params`` on an image of h × w."""
    lens = next(
        lens
        for lens in database().lenses
        if lens.model == params.lens and abs(lens.crop_factor - params.lens_crop_factor) < 1e-3
    )
    modifier = lensfunpy.Modifier(lens, params.crop_factor, w, h)
    modifier.initialize(
        params.focal_length,
        params.aperture,
        params.distance,
        scale=1.0,
        targeom=lens.type,
        pixel_format=np.float32,
        flags=flags,
        reverse=reverse,
    )
    return modifier


def _lensfun_coordinates(modifier, h: int, w: int) -> np.ndarray:
    """(H, W, 3, 2) lensfun's source coordinates, one point per call: its scalar code.
    (Its rows use SSE's approximate 1/√ and float32 accumulation: 0.2 px off here.)"""
    out = np.empty((h, w, 3, 2), np.float64)
    apply = modifier.apply_subpixel_geometry_distortion
    for y in range(h):
        for x in range(w):
            out[y, x] = apply(float(x), float(y), 1, 1)[0, 0]
    return out


def _lanczos3(plane: np.ndarray, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
    """``plane`` sampled at (sy, sx) by Lanczos-3 (6 × 6 taps, weights normalised per
    axis), 0 outside, kept within the range of the 2 × 2 pixels around the sample (no
    ringing): numpy with exact sinc weights, independent of rawsim's table."""
    h, w = plane.shape
    x0, y0 = np.floor(sx).astype(int), np.floor(sy).astype(int)

    def weights(frac):
        t = frac[..., None] - np.arange(-2, 4)
        k = np.sinc(t) * np.sinc(t / 3)
        return k / k.sum(-1, keepdims=True)

    wx, wy = weights(sx - x0), weights(sy - y0)
    out = np.zeros(plane.shape if sx.shape == plane.shape else sx.shape)
    near = []
    for b in range(6):
        y = y0 - 2 + b
        for a in range(6):
            x = x0 - 2 + a
            inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
            v = np.where(inside, plane[y.clip(0, h - 1), x.clip(0, w - 1)], 0.0)
            out += wy[..., b] * wx[..., a] * v
            if a in (2, 3) and b in (2, 3):
                near = near + [v]
    return np.clip(out, np.minimum.reduce(near), np.maximum.reduce(near))


@pytest.mark.parametrize("lens", ["kit", *[o[0] for o in OTHERS]])
def test_correction_agrees_with_lensfun(lens):
    """lensfun's own correction (devignette the photo, then remap it with lensfun's
    per-pixel coordinates, in numpy) and ours agree to > 60 dB."""
    image = photo()[:, :450]  # 300 × 450: the 3:2 of the cameras
    h, w = image.shape[:2]
    if lens == "kit":
        params = kit()
    else:
        name, make, model, focal = next(o for o in OTHERS if o[0] == lens)
        params, _ = lens_params(name, focal, 8.0, None, make, model)
        assert params.camera, "the camera is in lensfun"
    F = lensfunpy.ModifyFlags
    coords = _lensfun_coordinates(_lensfun(params, h, w, F.DISTORTION | F.TCA), h, w)
    devignetted = image.copy()
    if "vignetting" in params.corrections:
        _lensfun(params, h, w, F.VIGNETTING).apply_color_modification(devignetted)
    ref = np.stack(
        [_lanczos3(devignetted[..., k], coords[..., k, 0], coords[..., k, 1]) for k in range(3)],
        -1,
    )
    ours = _numpy(correct_lens(_tensor(image), params))
    inside = ((coords >= 0) & (coords <= [w - 1, h - 1])).all(axis=(2, 3))
    assert inside.mean() > 0.95
    moved = np.abs(coords[..., 0] - np.arange(w)[None, :, None]).max()
    assert moved > 1.5, "the lens moves pixels"
    assert psnr(ours[inside], ref[inside]) > 60


@pytest.mark.parametrize("aperture", [3.5, 8.0])
def test_vignetting_gains_are_lensfuns(aperture):
    """Vignetting alone: our gains are lensfun's, correcting divides by them and adding
    multiplies (lensfun accumulates its radius in float32: relative 1e-3)."""
    params = kit(aperture, corrections=("vignetting",))
    h, w = 40, 60
    ones = np.ones((h, w, 3), np.float32)
    theirs = ones.copy()
    _lensfun(params, h, w, lensfunpy.ModifyFlags.VIGNETTING).apply_color_modification(theirs)
    gain = correct_lens(_tensor(ones), params)
    np.testing.assert_allclose(_numpy(gain), theirs, rtol=2e-3)
    assert theirs.max() > 3  # strong at the corners of this kit zoom
    added = add_lens(_tensor(ones), params)  # V and 1/V each interpolated in their table
    np.testing.assert_allclose((gain * added).numpy(), 1, rtol=1e-4)


def test_field_is_small_and_follows_the_image():
    """A 24 MP frame needs tables, not full-resolution coordinate maps; the centre is
    lensfun's (pixel centres at integers), and a half-size frame gets its own field."""
    params = kit()
    full = lens_field(params, 4000, 6000)
    assert full.table.nbytes < 200_000 and full.centre == (1999.5, 2999.5)
    half = lens_field(params, 2000, 3000)
    assert half.centre == (999.5, 1499.5)
    # the same relative displacement at a corner, whatever the size
    r_full, r_half = np.hypot(1999.5, 2999.5), np.hypot(999.5, 1499.5)
    ratio_full = np.interp(r_full * full.scale, np.arange(len(full.table)), full.table[:, 1, 0])
    ratio_half = np.interp(r_half * half.scale, np.arange(len(half.table)), half.table[:, 1, 0])
    assert abs(ratio_full - ratio_half) < 1e-3 and ratio_full < 0.93  # barrel: 7 % in


# ---- both backends ----------------------------------------------------------------------


@pytest.mark.parametrize("padding", PADDINGS)
@pytest.mark.parametrize("reverse", [False, True], ids=["correct", "add"])
def test_engine_remap_equals_torch(padding, reverse):
    image = np.random.default_rng(0).random((67, 101, 3)).astype(np.float32) * 2 - 0.25
    field = lens_field(kit(), 67, 101, reverse)
    ours = engine_lens.remap_lens(image, field, padding)
    ref = _numpy(remap_lens(_tensor(image), field, padding))
    np.testing.assert_array_equal(ours, ref)  # the same float32 arithmetic


def _assert_mosaic_close(ours, ref):
    """The renders of a mosaic the engine rebuilt as 16-bit codes (each value within
    half a code, 2e-5 of white, a quarter of a 14-bit raw's step): within 1e-4 (floats)
    or 1 code, but for under 0.1 % of samples where a demosaic's choice of direction
    flips (within 16 codes, 2e-3)."""
    assert ours.shape == ref.shape and ours.dtype == ref.dtype
    diff = np.abs(ours.astype(np.float64) - ref)
    near, far = (1e-4, 2e-3) if ours.dtype.kind == "f" else (1, 16)
    assert diff.max() <= far and (diff > near).mean() < 1e-3, (diff.max(), (diff > near).mean())


def _lens_config(**changes) -> list[dict]:
    return override(base_config(), lens=KIT["lens"], focal_length=16.0, aperture=8.0, **changes)


@pytest.mark.parametrize(
    "pattern, changes, orientation",
    [
        ("RGGB", {}, 1),
        ("GBRG", dict(demosaic="menon", tone="aces", exposure=0.5), 6),
        ("RGGB", dict(demosaic="half"), 3),
        ("XTRANS", dict(highlights="blend"), 8),
    ],
)
def test_engine_render_equals_torch(pattern, changes, orientation):
    """Bayer at full size: lateral CA is taken out of the mosaic, which the engine then
    holds as 16-bit codes (:func:`rawsim.engine.lens.correct_mosaic_tca`): the renders
    agree as the highlight pre-pass's do (:func:`_assert_mosaic_close`)."""
    raw = synthetic_raw(pattern, h=90, w=138, orientation=orientation)
    config = _lens_config(**changes)
    plan = engine_plan(raw, config, "tiff")
    on_mosaic = raw.cfa.is_bayer and changes.get("demosaic") != "half"
    assert (plan.tca is not None) == on_mosaic
    check = _assert_mosaic_close if on_mosaic else _assert_close
    check(*_both(raw, config))
    check(*_both(raw, config, "exr", 32))
    assert plan.lens["lens"] == KIT["lens"] == plan.info["lens"]["lens"]
    assert ("tca" in plan.lens["corrections"]) != on_mosaic
    floats, _ = render_float(raw, config)  # the engine's linear part, then torch's tail
    check(floats[0].permute(1, 2, 0).numpy(), render(raw, config)[0][0].permute(1, 2, 0).numpy())
    # the lens stage moves pixels: without it the render differs
    plain = engine_render(raw, engine_plan(raw, base_config(), "tiff"), "tiff", 16)
    if orientation == 1:
        assert np.abs(plain.astype(int) - engine_render(raw, plan, "tiff", 16)).max() > 1000


def test_tall_image_strips_and_tiles():
    """Torch runs the stages around the lens stage in strips (the image is taller than
    two strips); the engine gives the same bits for every tile size and thread count."""
    raw = synthetic_raw("RGGB", h=600, w=60)
    config = _lens_config()
    base, ref = _both(raw, config)
    _assert_close(base, ref)
    plan = engine_plan(raw, config, "tiff")
    for tile in ((16, 16), (64, 512)):
        for n in thread_counts():
            with numba_threads(n):
                assert np.array_equal(engine_render(raw, plan, "tiff", 16, tile), base)


@pytest.mark.parametrize(
    ("padding", "fast"),
    [*((p, True) for p in PADDINGS), pytest.param("zeros", False, marks=pytest.mark.slow)],
    ids=[*PADDINGS, "zeros-whole"],
)
def test_gradcheck(padding, fast):
    """Random projections of the Jacobian for every padding (``fast_mode``); the whole
    Jacobian for one, in the slow tier."""
    params = kit(3.5)
    x = torch.rand(1, 3, 7, 11, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda t: correct_lens(t, params, padding), (x,), fast_mode=fast
    )
    assert torch.autograd.gradcheck(lambda t: add_lens(t, params, padding), (x,), fast_mode=fast)


def test_module_equals_functions_and_checks_input():
    params = kit()
    x = torch.rand(2, 3, 20, 30)
    module = LensCorrection(params.to_dict())
    assert torch.equal(module(x), correct_lens(x, params))
    assert torch.equal(module.reverse(x), add_lens(x, params))
    assert torch.equal(LensCorrection(None)(x), x)  # a raw whose lens is unknown
    with pytest.raises(ParameterError, match="NaN or infinite"):
        correct_lens(torch.full((1, 3, 8, 8), float("nan")), params)
    with pytest.raises(ParameterError, match="3 channels"):
        correct_lens(torch.rand(1, 2, 8, 8), params)
    grey = correct_lens(x[:, 1:2], params)  # a monochrome raw: the green channel's remap
    assert torch.equal(grey, correct_lens(x, params)[:, 1:2])
    with pytest.raises(ParameterError, match="for 8 × 8 pixels, the image is 9 × 8"):
        remap_lens(torch.rand(1, 3, 9, 8), lens_field(params, 8, 8))
    with pytest.raises(ParameterError, match="padding"):
        correct_lens(x, params, "wrap")
    with pytest.raises(ParameterError, match=r"\(H, W, 3\) float32"):
        engine_lens.correct_lens(np.zeros((8, 8, 3)), params)


# ---- lateral CA on the mosaic ---------------------------------------------------------


def _source(field, y, x, k):
    """Where ``field`` samples channel k for output pixel (y, x) (float64)."""
    cy, cx = field.centre
    t = np.hypot(x - cx, y - cy) * field.scale
    ratio = np.interp(t, np.arange(len(field.table)), field.table[:, k, 0])
    return cy + (y - cy) * ratio, cx + (x - cx) * ratio


@pytest.mark.parametrize("lens", ["kit", OTHERS[0][0]])
def test_tca_then_the_rest_is_the_whole_correction(lens):
    """lensfun's TCA acts on the sensor's coordinates: TCA's field at the point green's
    correction samples is where the whole correction samples red and blue (1e-3 px),
    and the field without TCA moves every colour as green."""
    if lens == "kit":
        params = kit()
    else:
        name, make, model, focal = OTHERS[0]
        params, _ = lens_params(name, focal, 8.0, None, make, model)
    assert "tca" in params.corrections
    h, w = 400, 600
    whole, rest = lens_field(params, h, w), lens_field(without_tca(params), h, w)
    tca = tca_field(params, h, w)
    assert np.array_equal(rest.table[:, 0], rest.table[:, 2])
    assert np.array_equal(rest.table[:, 1, 0], whole.table[:, 1, 0])
    moved = 0.0
    for y, x in [(0, 0), (0, w - 1), (h - 1, 0), (h - 1, w - 1), (123, 456), (h // 2, 0)]:
        gy, gx = _source(rest, y, x, 1)
        for k in (0, 2):
            ty, tx = _source(tca, gy, gx, k)
            assert np.hypot(*np.subtract(_source(whole, y, x, k), (ty, tx))) < 1e-3
            moved = max(moved, np.hypot(ty - gy, tx - gx))
    assert moved > 0.1  # the lens's CA moves red or blue by a tenth of a pixel or more


def _bayer(image: np.ndarray, cfa: CFA) -> np.ndarray:
    """(H, W) mosaic of an (H, W, 3) image."""
    h, w = image.shape[:2]
    colours = np.array(cfa.colors).reshape(2, 2)
    site = colours[np.arange(h)[:, None] % 2, np.arange(w)[None, :] % 2]
    return np.take_along_axis(image, site[..., None], axis=2)[..., 0]


@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_mosaic_tca_puts_red_and_blue_where_green_is(pattern):
    """A photo (blurred by σ = 1.5 px: detail a quarter-size plane can hold) given the
    kit zoom's lateral CA alone (up to 0.24 px), then mosaicked: corrected on the
    mosaic, its red and blue sites come back within a fifth of their RMS error
    before (measured: a ninth), against the photo's own mosaic (central 90 %); green
    sites are kept. (On the sharp photo, resampling a quarter-size plane errs about
    as much as the CA: 0.00069 against 0.00079.)"""
    cfa = CFA(pattern)
    image = gaussian_filter(photo(), (1.5, 1.5, 0)).astype(np.float32)
    params = kit(None)
    add = lens_field(replace(params, corrections=("tca",)), *image.shape[:2], reverse=True)
    aberrated = _numpy(remap_lens(_tensor(image), add, "reflect"))
    mosaic = torch.from_numpy(_bayer(aberrated, cfa))[None, None]
    truth = _bayer(image, cfa)
    fixed = correct_mosaic_tca(mosaic, cfa, params)[0, 0].numpy()
    green = _bayer(np.ones_like(image) * [0, 1, 0], cfa) > 0
    assert np.array_equal(fixed[green], mosaic[0, 0].numpy()[green])
    before = _centre(mosaic[0, 0].numpy() - truth)[_centre(~green)]
    after = _centre(fixed - truth)[_centre(~green)]
    rms = [float(np.sqrt((e**2).mean())) for e in (before, after)]
    assert rms[1] < rms[0] / 5, rms


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR"])
@pytest.mark.parametrize("root", [False, True], ids=["linear", "roots"])
def test_engine_mosaic_tca_equals_torch(pattern, root):
    """The engine's pre-pass gives the reference's mosaic within half a code of its
    re-encoding (a site's range / 131070), through levels, white balance, lens shading
    (a gain that depends on position) and the demosaic's square roots."""
    from rawsim.engine import process as ep
    from rawsim.isp.demosaic import to_root

    raw = synthetic_raw(pattern, h=90, w=138)
    ops = [ep.OP_LEVELS, ep.OP_WB, ep.OP_SHADING] + ([ep.OP_ROOT] if root else [])
    opf = np.zeros((len(ops), 18))
    opf[0, :4], opf[0, 4:8] = raw.black_level.ravel(), 16383 - raw.black_level.ravel()
    opf[1, :3] = (2.1, 1.0, 1.6)
    opf[2, :4] = (-0.3, 0.05, 0.0, 1.0)
    codes, new_ops, numbers = engine_lens.correct_mosaic_tca(
        raw.data, raw.cfa.colors, np.array(ops), opf, kit().to_dict()
    )
    assert new_ops.tolist() == [ep.OP_LEVELS] and codes.dtype == np.uint16
    h, w = raw.data.shape
    site = (np.arange(h)[:, None] % 2) * 2 + np.arange(w)[None, :] % 2
    black, span = numbers[0, :4].astype(np.float32), numbers[0, 4:8].astype(np.float32)
    ours = (codes.astype(np.float32) - black[site]) / span[site]
    linear = np.empty((h, w), np.float32)
    colours, none = np.array(raw.cfa.colors), np.empty((0, 0), np.float32)
    engine_lens._linear_mosaic(raw.data, colours, none, np.array(ops[:3]), opf, linear)
    ref = correct_mosaic_tca(torch.from_numpy(linear)[None, None], raw.cfa, kit())
    if root:
        ref = to_root(ref)
    ref = ref[0, 0].numpy()
    assert np.all(np.abs(ours - ref) <= 0.5 / span[site] + 1e-6)
    assert np.abs(ours - ref).max() < 2e-5 and not np.array_equal(ref, linear)


def test_where_lateral_ca_is_corrected():
    """A Bayer raw at full size: the ``lens_tca`` module just before the demosaic, the
    lens stage without TCA; X-Trans, half size and a lens stage told not to correct
    TCA leave it to the lens stage."""
    raw = synthetic_raw("RGGB", h=60, w=90)
    isp = build_isp(_lens_config(), raw)
    at = isp.names.index("demosaic")
    assert isp.names[at - 1] == "lens_tca" and isinstance(isp.stages[at - 1], MosaicTca)
    stage = isp.stages[isp.names.index("lens_correction")]
    assert stage.params.corrections == ("distortion", "vignetting")
    no_tca = _lens_config()
    next(t for t in no_tca if t["name"] == "lens_correction")["corrections"] = ["distortion"]
    cases = [(synthetic_raw("XTRANS", h=72, w=96), _lens_config()), (raw, no_tca)]
    for case, config in [*cases, (raw, _lens_config(demosaic="half"))]:
        assert "lens_tca" not in build_isp(config, case).names
    with pytest.raises(ParameterError, match="Bayer mosaic"):
        correct_mosaic_tca(torch.rand(1, 3, 8, 8), CFA("RGGB"), kit())
    with pytest.raises(ParameterError, match="Bayer mosaic"):
        correct_mosaic_tca(torch.rand(1, 1, 12, 12), CFA("XTRANS"), kit())


def test_mosaic_tca_gradcheck():
    mosaic = torch.rand(1, 1, 10, 14, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda t: correct_mosaic_tca(t, CFA("GRBG"), kit()), (mosaic,), fast_mode=True
    )


# ---- round trip --------------------------------------------------------------------------


@pytest.mark.parametrize("backend", ["torch", "engine"])
def test_add_then_correct_gives_the_photo_back(backend):
    """The kit zoom at 16 mm added to a photo, then corrected: the photo again (≥ 30 dB
    over the central 90 %), far from the distorted image."""
    image = photo()
    params = kit()
    if backend == "torch":
        distorted = _numpy(add_lens(_tensor(image), params))
        corrected = _numpy(correct_lens(_tensor(distorted), params))
    else:
        distorted = engine_lens.add_lens(image, params)
        corrected = engine_lens.correct_lens(distorted, params)
    back = psnr(_centre(corrected), _centre(image))
    off = psnr(_centre(distorted), _centre(image))
    assert back >= 30 and off < 22, (back, off)
    # without vignetting the distortion alone still costs > 10 dB
    geometric = kit(None)
    moved = _numpy(add_lens(_tensor(image), geometric))
    assert psnr(_centre(moved), _centre(image)) < back - 10


# ---- lookups and messages ----------------------------------------------------------------


def _meta(**tags) -> PhotoMetadata:
    keys = {"lens": "Exif.Photo.LensModel", "focal": "Exif.Photo.FocalLength"}
    keys |= {"f": "Exif.Photo.FNumber", "distance": "Exif.Photo.SubjectDistance"}
    return PhotoMetadata(tuple((keys[k], v) for k, v in tags.items()))


def test_lens_from_metadata():
    meta = _meta(lens="E PZ 16-50mm F3.5-5.6 OSS", focal="160/10", f="56/10", distance="3/1")
    params, warnings = raw_lens("SONY", "ILCE-6000", meta)
    assert not warnings
    assert (params.lens, params.focal_length, params.aperture, params.distance) == (
        KIT["lens"],
        16.0,
        5.6,
        3.0,
    )
    assert params.camera == "Sony ILCE-6000" and params.crop_factor == pytest.approx(1.534)
    assert LensParams.of(json.loads(json.dumps(params.to_dict()))) == params
    # explicit values replace the metadata's
    params, _ = raw_lens("SONY", "ILCE-6000", meta, focal_length=24.0, aperture=11.0)
    assert (params.focal_length, params.aperture) == (24.0, 11.0)


def _one_line(text: str) -> str:
    assert "\n" not in text
    return text


def test_what_cannot_be_corrected_says_why_in_one_line():
    # an old raw: no LensModel
    none, warnings = raw_lens("Canon", "Canon EOS 60D", _meta(focal="50/1"))
    assert none is None and "--lens NAME" in _one_line(*warnings)
    # a lens lensfun does not know, from the metadata: a warning naming the closest
    none, warnings = raw_lens("SONY", "ILCE-6000", _meta(lens="Sony PZ 16-50 Mk IX", focal="16/1"))
    assert none is None and "not in lensfun's database" in _one_line(*warnings)
    assert "the closest is 'E PZ 16-50mm f/3.5-5.6 OSS'" in warnings[0]
    # no focal length
    none, warnings = raw_lens("SONY", "ILCE-6000", _meta(lens=KIT["lens"]))
    assert none is None and "--focal-length MM" in _one_line(*warnings)
    # no aperture: corrected without vignetting
    params, warnings = raw_lens("SONY", "ILCE-6000", _meta(lens=KIT["lens"], focal="16/1"))
    assert params.corrections == ("distortion", "tca") and "--aperture F" in _one_line(*warnings)
    # a camera lensfun does not know: the lens's own sensor, said
    params, warnings = raw_lens("Acme", "X1", _meta(lens=KIT["lens"], focal="16/1", f="8/1"))
    assert params.crop_factor == params.lens_crop_factor and "Acme X1" in _one_line(*warnings)
    # a focal length the lens does not have, from the metadata: not corrected
    none, warnings = raw_lens("SONY", "ILCE-6000", _meta(lens=KIT["lens"], focal="85/1"))
    assert none is None and "outside" in _one_line(*warnings)
    # named by the user: errors
    with pytest.raises(ParameterError, match="not in lensfun's database") as err:
        raw_lens("SONY", "ILCE-6000", _meta(), lens="Nonexistent 17-71mm f/9")
    _one_line(str(err.value))
    with pytest.raises(ParameterError, match="outside"):
        raw_lens("SONY", "ILCE-6000", _meta(lens=KIT["lens"]), focal_length=85.0)
    with pytest.raises(ParameterError, match="missing key 'lens_maker'"):
        LensParams.of({"lens": KIT["lens"]})


def test_config_stage_toml_and_flags():
    config = IspConfig.default()
    stage = config.enabled_stage(LensCorrectionStage)
    assert stage is None, "off by default, as LibRaw"
    toml = config.to_toml()
    assert 'name = "lens_correction"' in toml and IspConfig.from_toml(toml) == config
    on = config.override(lens_correction="auto")
    assert on.enabled_stage(LensCorrectionStage).lens == "auto"
    named = config.override(lens=KIT["lens"], focal_length=16)
    assert named.enabled_stage(LensCorrectionStage).focal_length == 16.0
    assert on.override(lens_correction="off").enabled_stage(LensCorrectionStage) is None
    with pytest.raises(ParameterError, match="--lens-correction off: --lens"):
        config.override(lens_correction="off", lens=KIT["lens"])
    with pytest.raises(ParameterError, match="corrections"):
        LensCorrectionStage(corrections=("coma",))
    # a config without the stage gets it where the default order has it
    tables = [t for t in config.to_tables() if t["name"] != "lens_correction"]
    names = [s.name for s in IspConfig.from_tables(tables).override(lens_correction="auto").stages]
    assert names.index("lens_correction") == names.index("denoise") + 1
    with pytest.raises(ParameterError, match="must come after 'demosaic'"):
        IspConfig.from_tables([{"name": "lens_correction"}, *tables])


# ---- the CLI -----------------------------------------------------------------------------


def _dng(path, image: np.ndarray, lens: str | None, focal: int | None = 16, f: int = 8):
    """A Bayer DNG of ``image`` (RGGB, white balanced) from the kit's camera, with the
    lens tags exiv2 writes into its EXIF (what unprocess records)."""
    h, w = image.shape[:2]
    mosaic = np.empty((h, w))
    mosaic[0::2, 0::2], mosaic[0::2, 1::2] = image[0::2, 0::2, 0], image[0::2, 1::2, 1]
    mosaic[1::2, 0::2], mosaic[1::2, 1::2] = image[1::2, 0::2, 1], image[1::2, 1::2, 2]
    info = DngInfo(CFA("RGGB"), 0, 65535, np.eye(3).tolist(), (1, 1, 1), "SONY", "ILCE-6000",
                   "Sony ILCE-6000", 100)  # fmt: skip
    write_dng(path, np.round(mosaic * 65535).astype(np.uint16), info)
    img = exiv2.ImageFactory.open(str(path))
    img.readMetadata()
    exif = img.exifData()
    if lens:
        exif["Exif.Photo.LensModel"] = lens
    if focal:
        exif["Exif.Photo.FocalLength"] = exiv2.URationalValue([(focal, 1)])
    exif["Exif.Photo.FNumber"] = exiv2.URationalValue([(f, 1)])
    img.writeMetadata()
    return path


def _process(*args):
    return CliRunner().invoke(cli, ["process", *map(str, args)], catch_exceptions=False)


def test_cli_lens_correction(tmp_path):
    image = photo()[:200, :300]
    distorted = engine_lens.add_lens(image, kit())
    tagged = _dng(tmp_path / "kit.dng", distorted, "E PZ 16-50mm F3.5-5.6 OSS")
    bare = _dng(tmp_path / "old.dng", distorted, None)
    common = ["--demosaic", "bilinear", "--output-space", "camera", "--format", "exr"]
    common += ["--bits", "32", "--wb", "1,1,1"]

    def run(src, out, *flags):
        result = _process(src, "-o", tmp_path / out, *common, *flags)
        assert result.exit_code == 0, result.output
        stem = tmp_path / out / src.stem
        meta = json.loads(stem.with_suffix(".process.json").read_text())
        import OpenImageIO as oiio

        return oiio.ImageBuf(str(stem.with_suffix(".exr"))).get_pixels(), meta, result.output

    plain, meta, _ = run(tagged, "plain")
    assert "lens" not in meta  # off by default
    fixed, meta, _ = run(tagged, "auto", "--lens-correction", "auto")
    assert meta["lens"]["lens"] == KIT["lens"] and meta["lens"]["focal_length"] == 16
    assert meta["lens"]["aperture"] == 8 and not meta["warnings"]
    # the lens is gone: the render is the photo again (demosaic aside), not the distorted one
    assert psnr(_centre(fixed), _centre(image)) > psnr(_centre(plain), _centre(image)) + 8
    # an old raw without LensModel: a warning saying what to pass, rendered uncorrected
    same, meta, output = run(bare, "bare", "--lens-correction", "auto")
    assert meta["lens"] is None and "pass --lens NAME" in output
    np.testing.assert_array_equal(same, plain)
    named, meta, _ = run(bare, "named", "--lens", KIT["lens"])
    assert meta["lens"]["lens"] == KIT["lens"]
    np.testing.assert_array_equal(named, fixed)
    # usage errors, in one line, before any file
    bad = _process(bare, "-o", tmp_path / "bad", "--lens", "Nonexistent 17-71mm f/9")
    assert bad.exit_code == 2 and "not in lensfun's database" in bad.output
    both = _process(bare, "-o", tmp_path / "bad", "--lens-correction", "off", "--lens", "x")
    assert both.exit_code == 2 and "--lens-correction off" in both.output
    shown = CliRunner().invoke(cli, ["isp", "show"])
    assert 'name = "lens_correction"' in shown.output


def test_reference_render_of_a_real_dng():
    """A real raw with its lens in the metadata (a linear DNG: the torch reference
    renders it): the stage finds camera and lens, and moves the pixels."""
    from rawsim.io.raw import read_raw

    raw = read_raw(DATA / "raw" / "canon_eos6d_linear_raw_no_cfa.dng")
    config = override(default_config(), lens_correction="auto")
    out, info = render(raw, config)
    assert info["lens"]["lens"] == "Canon EF 24-105mm f/4L IS USM"
    assert info["lens"]["focal_length"] == 65 and info["lens"]["camera"] == "Canon EOS 6D"
    plain, _ = render(raw, default_config())
    assert out.shape == plain.shape and (out - plain).abs().max() > 0.05
