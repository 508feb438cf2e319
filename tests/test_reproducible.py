"""Byte-identical outputs: the same inputs, seed and options give the same files on
every run, for any --jobs, with no time stamps and no run-dependent float sums."""

import shutil
import time

import pytest

from rawsim.cameras.profiles import load_profile
from rawsim.noise.models import NoiseLevels
from tests.conftest import DATA
from tests.test_cli import digest, run

PHOTOS = ("srgb/chelsea.png", "srgb/rocket.jpg", "srgb16/painted_figure_16bit.tif")


@pytest.fixture
def inputs(tmp_path):
    root = tmp_path / "in"
    root.mkdir()
    for name in PHOTOS:
        shutil.copy(DATA / name, root / name.split("/")[1])
    return root


@pytest.mark.parametrize("model", ["gaussian", "poisson-gaussian", "physics"])
def test_noise_profile_figures_are_the_same_bits_every_call(model):
    profile = load_profile("sony_a7s2")
    levels = profile.noise.levels(model, 3200)
    first = levels.noise_profile(profile.black_level, profile.white_level)
    for _ in range(200):
        assert levels.noise_profile(profile.black_level, profile.white_level) == first


def test_gaussian_noise_profile_is_the_least_squares_line():
    levels = NoiseLevels("gaussian", 800, read_sigma=2.0, shot_alpha=0.5, shot_beta=0.3, iso_gain=8)
    a, b = levels.affine_variance(1000.0)
    # var(s) = g(α√s + β)² + σ² + 1/12; the line through it has a > g α² (the √s term
    # bends it) and passes below the curve's mean at the ends.
    assert 8 * 0.25 < a < 8 * 0.25 + 1.0
    assert abs(b - float(levels.variance(0.0))) < 60


def test_unprocess_is_byte_identical_run_to_run_and_for_any_jobs(inputs, tmp_path):
    args = ("unprocess", inputs, "-p", "sony_a7s2", "--iso", 3200, "--seed", 11, "--randomize")
    args += ("--noise", "physics", "--clean", "--format", "both")
    digests = []
    for i in range(5):
        out = tmp_path / f"out{i}"
        jobs = ("--jobs", 2) if i % 2 else ()
        assert run(*args, "-o", out, *jobs).exit_code == 0
        digests.append(digest(out))
    assert len(digests[0]) == 3 * 4  # dng, clean dng, npz, json per photo
    assert all(d == digests[0] for d in digests[1:])


@pytest.mark.parametrize("fmt", ["tiff", "exr", "png"])
def test_process_is_byte_identical_run_to_run(tmp_path, fmt):
    raw = DATA / "raw" / "synthetic_colorchecker_bggr.dng"
    digests = []
    for i in range(3):
        if i:
            time.sleep(1.05)  # a time stamp (1 s resolution) would change between runs
        out = tmp_path / f"out{i}"
        assert run("process", raw, "-o", out, "--format", fmt, "--bits", 16).exit_code == 0
        digests.append(digest(out))
    assert all(d == digests[0] for d in digests[1:])


def test_a_file_is_the_same_bits_after_another_of_its_size(tmp_path):
    """A batch writes each image's mosaics over the last one's (same size): the
    outputs are those of each image run alone."""
    import numpy as np
    import OpenImageIO as oiio

    from rawsim.pipelines import unprocess

    pixels = oiio.ImageBuf(str(DATA / "srgb" / "chelsea.png")).get_pixels(oiio.UINT8)
    both, alone = tmp_path / "both", tmp_path / "alone"
    both.mkdir(), alone.mkdir()
    for name, image in (("a.png", pixels), ("b.png", np.ascontiguousarray(pixels[::-1, ::-1]))):
        buf = oiio.ImageBuf(oiio.ImageSpec(image.shape[1], image.shape[0], 3, oiio.UINT8))
        buf.set_pixels(oiio.ROI(), image)
        assert buf.write(str(both / name))
    shutil.copy(both / "b.png", alone / "b.png")
    args = ("-p", "sony_a7s2", "--iso", 3200, "--noise", "physics", "--clean")
    assert run("unprocess", both, "-o", tmp_path / "out_both", *args).exit_code == 0
    unprocess._spare.clear()
    assert run("unprocess", alone, "-o", tmp_path / "out_alone", *args).exit_code == 0
    for name in ("b.dng", "b.clean.dng"):
        ours = (tmp_path / "out_both" / name).read_bytes()
        assert ours == (tmp_path / "out_alone" / name).read_bytes()
