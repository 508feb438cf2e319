"""The Sony IMX686 profile against PMN's published calibration.

The figures are checked against the files PMN publishes (vendored unmodified in
``tests/data/pmn_imx686``, see ``tests/data/SOURCES.md``), not against the profile.
"""

import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from PIL import Image

from rawsim.cameras.profiles import load_profile, profile_from_dict
from rawsim.errors import ProfileError
from rawsim.noise.models import add_noise
from tests.conftest import DATA
from tests.test_cli import run

PMN = DATA / "pmn_imx686"
ISOS = (100, 6400)
#: The profile writes PMN's float32 means to 7 significant digits.
REL = 1e-6
#: The .h5 datasets and the profile's source key that cites each.
PER_CHANNEL = {
    "sigmaGs": "noise.read_sigma",
    "sigmaTL": "noise.tukey_sigma",
    "lam": "noise.tukey_lambda",
    "sigmaR": "noise.row_sigma",
}


def pmn_figures(iso: int) -> dict:
    """The channel-and-frame means of PMN's noiseparam-iso-{iso}.h5 (as PMN's own loader
    takes them), per-channel means, and its levels."""
    with h5py.File(PMN / f"noiseparam-iso-{iso}.h5", "r") as f:
        per_channel = {k: np.asarray(f[k], np.float64).mean(axis=1) for k in PER_CHANNEL}
        return {
            "mean": {k: float(np.asarray(f[k], np.float64).mean()) for k in PER_CHANNEL},
            "channels": per_channel,
            "mean_read": float(np.asarray(f["sigmaRead"], np.float64).mean()),
            "bl": int(f["bl"][()]),
            "wp": int(f["wp"][()]),
        }


def pmn_gain(iso: int) -> float:
    """'Kmax' of IMX686_{iso} in PMN's get_camera_noisy_params_max (process.py excerpt)."""
    text = (PMN / "process_excerpt.txt").read_text()
    block = re.search(rf"\['IMX686_{iso}'\] = \{{(.*?)\}}", text, re.S)
    return float(re.search(r"'Kmax':\s*([0-9.]+)", block.group(1)).group(1))


@pytest.fixture(scope="module")
def profile():
    return load_profile("sony_imx686")


@pytest.mark.parametrize("iso", ISOS)
def test_figures_equal_pmn_calibration(profile, iso):
    pmn = pmn_figures(iso)
    assert (profile.black_level, profile.white_level) == (pmn["bl"], pmn["wp"]) == (64, 1023)
    assert profile.bit_depth == 10 and profile.cfa.name == "RGGB"
    gaussian = profile.noise.levels("poisson-gaussian", iso)
    physics = profile.noise.levels("physics", iso)
    assert gaussian.gain == pytest.approx(pmn_gain(iso), rel=1e-12)
    assert physics.gain == pytest.approx(pmn_gain(iso), rel=1e-12)
    mean = pmn["mean"]
    assert gaussian.read_sigma == pytest.approx(mean["sigmaGs"], rel=REL)
    assert physics.read_sigma == pytest.approx(mean["sigmaTL"], rel=REL)
    assert physics.tukey_lambda == pytest.approx(mean["lam"], rel=REL)
    assert physics.row_sigma == pytest.approx(mean["sigmaR"], rel=REL)


@pytest.mark.parametrize("iso", ISOS)
def test_source_cites_pmn_per_channel_figures(profile, iso):
    """The model takes the channel mean; the source quotes each channel's figure."""
    channels = pmn_figures(iso)["channels"]
    for dataset, key in PER_CHANNEL.items():
        for value in channels[dataset]:
            assert f"{value:.7g}" in profile.source[key], (dataset, key, value)


def test_dark_frame_noise_matches_pmn_read_sigma(profile):
    """A simulated ISO 6400 dark frame has PMN's measured read σ ('sigmaRead', row noise
    included) within 1 %: the Tukey-lambda, row and quantisation terms together."""
    levels = profile.noise.levels("physics", 6400)
    dn = torch.full((1, 1, 512, 512), profile.black_level, dtype=torch.float64)
    noisy = add_noise(dn, profile.black_level, levels, 7, profile.cfa)
    measured = float((noisy.round() - dn).std())
    assert measured == pytest.approx(pmn_figures(6400)["mean_read"], rel=0.01)


def test_lambda_above_one_allowed_but_not_below_minus_half(profile):
    data = json.loads(Path(profile.path).read_text())
    assert profile.noise.tukey_lambda(profile.noise.gain(100)) > 1
    data["noise"]["tukey_lambda"]["lambda"] = [-0.5, 0.1]
    with pytest.raises(ProfileError, match=r"noise\.tukey_lambda\.lambda.*> −0\.5"):
        profile_from_dict(data, "<imx686>")


def test_listed_and_unprocessed_with_physics_noise(tmp_path):
    r = run("profiles", "list")
    assert r.exit_code == 0 and "sony_imx686" in r.output
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (32, 48, 3), dtype=np.uint8)).save(tmp_path / "a.png")
    out = tmp_path / "out"
    args = ("--profile", "sony_imx686", "--iso", 6400, "--noise", "physics", "--format", "npz")
    r = run("unprocess", tmp_path / "a.png", "-o", out, *args)
    assert r.exit_code == 0, r.output
    mosaic = np.load(out / "a.npz")["mosaic"]
    assert mosaic.shape == (4, 16, 24) and mosaic.max() <= 1023
    noise = json.loads((out / "a.json").read_text())["noise"]
    assert noise["model"] == "physics"
    assert noise["tukey_lambda"] == pytest.approx(pmn_figures(6400)["mean"]["lam"], rel=REL)
