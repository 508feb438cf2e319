"""LibRaw's own rendering of a --clean DNG reproduces the source image.

LibRaw renders at half size (each 2×2 CFA tile → one pixel: its R site, the
mean of its G sites, its B site), so no demosaicking error enters. The
reference is the source image sampled the same way: the camera's view of
each tile (sRGB → camera RGB at each site), back to sRGB.
"""

import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
import torch

from rawsim.cameras.profiles import load_profile
from rawsim.color import camera_from_srgb
from rawsim.io.task import Task
from rawsim.isp.transfer import srgb_decode, srgb_encode
from rawsim.pipelines.unprocess import UnprocessOptions, unprocess_file
from tests.conftest import DATA, psnr

PHOTOS = [
    "srgb/astronaut.png",
    "srgb/coffee.png",
    "srgb/chelsea.png",
    "srgb/rocket.jpg",
    "srgb16/hdr_room_16bit.png",
    "srgb16/painted_figure_16bit.tif",
]
RENDER = dict(
    use_camera_wb=True,
    output_color=rawpy.ColorSpace.sRGB,
    no_auto_bright=True,
    output_bps=16,
    highlight_mode=rawpy.HighlightMode.Clip,
    half_size=True,
    user_flip=0,
    adjust_maximum_thr=0.0,
)  # LibRaw otherwise rescales dim images


def _half_size_reference(linear: np.ndarray, profile, gains) -> np.ndarray:
    """Linear sRGB (H, W, 3) → what an ideal half-size render of its raw gives (linear)."""
    a = camera_from_srgb(profile.xyz_to_camera)
    cam = np.einsum("ij,hwj->hwi", a, linear)
    raw = np.clip(cam / gains, 0, 1)  # the sensor saturates at its white level
    acc = np.zeros((cam.shape[0] // 2, cam.shape[1] // 2, 3))
    count = np.zeros(3)
    for i, color in enumerate(profile.cfa.colors):
        acc[..., color] += raw[i // 2 :: 2, i % 2 :: 2, color]
        count[color] += 1
    balanced = np.clip(acc / count * gains, 0, 1)  # LibRaw clips after white balance
    return np.clip(balanced @ np.linalg.inv(a).T, 0, 1)


def _source(src, linear: bool) -> np.ndarray:
    """The file's RGB as float64, cropped to even size like rawsim does; linear light."""
    pixels = oiio.ImageBuf(str(src)).get_pixels(oiio.FLOAT)[:, :, :3].astype(np.float64)
    h, w = pixels.shape[0] // 2 * 2, pixels.shape[1] // 2 * 2
    pixels = pixels[:h, :w]
    return pixels if linear else srgb_decode(torch.from_numpy(pixels)).numpy()


def _unprocess(tmp_path, src, profile, **kw):
    options = UnprocessOptions(profile, iso=800, clean=True, **kw)
    outputs = {k: tmp_path / f"x{v}" for k, v in options.output_suffixes().items()}
    meta = unprocess_file(Task(src, src.name, outputs, 1), options)
    return outputs["clean_dng"], np.array(meta["params"]["wb_gains"])


@pytest.mark.parametrize("photo", PHOTOS)
@pytest.mark.parametrize("wb_inverse", ["safe", "exact"])
def test_libraw_renders_clean_dng_like_the_photo(tmp_path, photo, wb_inverse):
    profile = load_profile("sony_a7s2")
    src = DATA / photo
    dng, gains = _unprocess(tmp_path, src, profile, safe_white_balance=wb_inverse == "safe")
    linear = _source(src, linear=False)
    reference = srgb_encode(torch.from_numpy(_half_size_reference(linear, profile, gains))).numpy()
    with rawpy.imread(str(dng)) as raw:
        rendered = raw.postprocess(gamma=(2.4, 12.92), **RENDER) / 65535.0
    # The safe inverse white balance bends highlights on purpose, the exact one doesn't.
    assert psnr(rendered, reference) >= (35 if wb_inverse == "safe" else 50)


@pytest.mark.parametrize("name", ["nikon_d850", "canon_eos_70d"])
def test_libraw_render_other_profiles(tmp_path, name):
    profile = load_profile(name)
    src = DATA / "srgb/chelsea.png"
    dng, gains = _unprocess(tmp_path, src, profile)
    linear = _source(src, linear=False)
    reference = srgb_encode(torch.from_numpy(_half_size_reference(linear, profile, gains))).numpy()
    with rawpy.imread(str(dng)) as raw:
        rendered = raw.postprocess(gamma=(2.4, 12.92), **RENDER) / 65535.0
    assert psnr(rendered, reference) >= 35


@pytest.mark.parametrize("exr", ["exr/cannon_half_b44.exr", "exr/img2601_float_zip.exr"])
def test_libraw_renders_scene_linear_exr(tmp_path, exr):
    profile = load_profile("nikon_d850")
    src = DATA / exr
    dng, gains = _unprocess(tmp_path, src, profile, exposure_ev=-1.0, safe_white_balance=False)
    reference = _half_size_reference(_source(src, linear=True) * 0.5, profile, gains)
    with rawpy.imread(str(dng)) as raw:
        rendered = raw.postprocess(gamma=(1, 1), **RENDER) / 65535.0
    assert psnr(rendered, reference) >= 45
