"""calibrate's uncertainty is honest: the true K lies within the reported 2σ (issue 30).

Photos are unprocessed at camera resolution (the test photos upsampled 4×, as in
test_calibrate) with the Sony A7S II profile's physics noise, and each fitted on
its own with the patch method; the truth is the profile's K at the ISO. Texture
biases the patch method's K upwards by up to ~10 % (ISO 200), several times the
bootstrap's standard error; the reported uncertainty must cover it. Measured on
these 30 fits (27 accepted): 70 % (19) of the accepted ones within 2 statistical
σ, 100 % (27) within 2σ of the reported uncertainty (statistical and systematic;
96 % when the systematic part came from the 6th-order detail alone). These photos
tuned the method; tests/test_calibrate_heldout.py checks it on photos that did not.
"""

import numpy as np
import pytest
import torch

from rawsim.api import unprocess
from rawsim.cameras.calibrate import calibrate_iso, frame_stats
from rawsim.io.images import read_image
from rawsim.io.raw import RawImage
from rawsim.sensors import RGBSensor
from tests.conftest import DATA, simulated_raw

SENSOR = RGBSensor.from_profile("sony_a7s2")
PHOTOS = (
    "srgb/astronaut.png",
    "srgb/chelsea.png",
    "srgb/coffee.png",
    "srgb16/hdr_room_16bit.png",
    "srgb16/painted_figure_16bit.tif",
)
ISOS = (200, 1600, 12800)
SEEDS = (1, 2)
CROP = 256  # source pixels a side: 1024 × 1024 at camera resolution


def _camera_photo(name: str, where: str = "centre") -> torch.Tensor:
    """A crop of a test photo at camera resolution, (1, 3, 4·CROP, 4·CROP) in [0, 1]:
    its centre, or a corner ("top-left", "top-right", "bottom-left", "bottom-right")."""
    decoded = read_image(DATA / name)
    x = torch.from_numpy(decoded.pixels[..., :3].astype(np.float32) / decoded.code_max)
    top, left = (x.shape[0] - CROP) // 2, (x.shape[1] - CROP) // 2
    if where != "centre":
        vertical, horizontal = where.split("-")
        top = 0 if vertical == "top" else x.shape[0] - CROP
        left = 0 if horizontal == "left" else x.shape[1] - CROP
    x = x[top : top + CROP, left : left + CROP].permute(2, 0, 1)[None]
    return torch.nn.functional.interpolate(x, scale_factor=4, mode="bicubic").clamp(0, 1)


def _raw(mosaic: torch.Tensor, iso: float) -> RawImage:
    return simulated_raw(mosaic[0, 0].numpy().astype(np.uint16), SENSOR.profile, iso)


@pytest.fixture(scope="module")
def patch_fits() -> list[tuple[str, float, float, object]]:
    """(photo, ISO, true K, fit) for every photo, ISO and seed: 30 single-photo fits."""
    fits = []
    for name in PHOTOS:
        image = _camera_photo(name)
        for iso in ISOS:
            for seed in SEEDS:
                noisy, _, meta = unprocess(image, SENSOR, [seed], iso=iso, noise="physics")
                stats = frame_stats(_raw(noisy, iso), "patches")
                truth = meta[0]["noise"]["gain_dn_per_electron"]
                fits.append((name, iso, truth, calibrate_iso(iso, [stats], [], "patches")))
    return fits


@pytest.mark.slow
def test_patch_fits_cover_the_true_gain_at_two_sigma(patch_fits):
    assert len(patch_fits) >= 20
    accepted = [f for f in patch_fits if not f[3].problems]
    # Refusing is allowed where the fit cannot promise coverage, but not as the rule.
    assert len(accepted) >= 0.8 * len(patch_fits), [f[3].problems for f in patch_fits]
    covered = [abs(fit.K - truth) <= 2 * fit.errors["K"] for _, _, truth, fit in accepted]
    report = [
        f"{name} ISO {iso}: K {fit.K:.4g} ± {fit.errors['K']:.2g} (truth {truth:.4g})"
        for (name, iso, truth, fit), ok in zip(accepted, covered, strict=True)
        if not ok
    ]
    assert np.mean(covered) >= 0.9, report


@pytest.mark.slow
def test_the_uncertainty_splits_into_statistical_and_systematic(patch_fits):
    for _, _, _, fit in patch_fits:
        e = fit.errors
        assert e["K"] == pytest.approx(np.hypot(e["K_statistical"], e["K_systematic"]))
        assert e["K_statistical"] > 0 and e["K_systematic"] >= 0
        assert fit.to_dict()["uncertainty"]["K_systematic"] == e["K_systematic"]


#: Tuning fits where K's systematic error from the 6th-order detail alone did not cover
#: the truth (issue 42: fine texture reaches the 6th order nearly as much as the 4th):
#: (photo, crop, ISO, seed, K's relative error then).
TEXTURED = (
    ("srgb/astronaut.png", "bottom-left", 200, 1, 0.052),
    ("srgb/astronaut.png", "bottom-right", 12800, 1, -0.053),
    ("srgb/astronaut.png", "bottom-right", 12800, 2, -0.062),
    ("srgb/coffee.png", "centre", 200, 1, 0.072),
    ("srgb/coffee.png", "top-left", 3200, 1, 0.049),
    ("srgb16/hdr_room_16bit.png", "bottom-left", 200, 1, 0.043),
    ("srgb/rocket.jpg", "top-left", 200, 2, 0.045),
    ("srgb/rocket.jpg", "top-left", 800, 2, 0.041),
    ("srgb/rocket.jpg", "bottom-left", 200, 1, 0.086),
)


@pytest.mark.slow
def test_textured_crops_that_the_6th_order_check_missed_are_covered():
    for name, where, iso, seed, _ in TEXTURED:
        image = _camera_photo(name, where)
        noisy, _, meta = unprocess(image, SENSOR, [seed], iso=iso, noise="physics")
        truth = meta[0]["noise"]["gain_dn_per_electron"]
        fit = calibrate_iso(iso, [frame_stats(_raw(noisy, iso), "patches")], [], "patches")
        assert not fit.problems, fit.problems
        assert abs(fit.K - truth) <= 2 * fit.errors["K"], (name, where, iso, seed, fit.K, truth)
