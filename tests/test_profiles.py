import json

import numpy as np
import pytest

from rawsim.cameras.profiles import (
    PHYSICS_KEYS,
    SOURCED_KEYS,
    list_profiles,
    load_profile,
    profile_dir,
)
from rawsim.errors import ParameterError, ProfileError


def test_bundled_profiles_load_with_sources():
    names = list_profiles()
    assert {
        "sony_a7s2",
        "nikon_d850",
        "canon_eos_70d",
        "canon_eos_700d",
        "canon_eos_5d_mark_iv",
        "nikon_d800e",
        "oppo_reno10x",
    } <= set(names)
    for name in names:
        p = load_profile(name)
        assert p.name == name == name.lower()
        assert p.cfa.name in ("RGGB", "BGGR", "GRBG", "GBRG", "XTRANS")
        assert 0 <= p.black_level < p.white_level <= 2**p.bit_depth - 1
        assert all(isinstance(p.source[k], str) for k in SOURCED_KEYS)
        lo, hi = p.iso_range
        for iso in (lo, hi):
            levels = p.noise.levels("poisson-gaussian", iso)
            assert levels.gain > 0 and levels.read_sigma > 0
        if hi > lo:
            assert (
                p.noise.levels("poisson-gaussian", hi).gain
                > p.noise.levels("poisson-gaussian", lo).gain
            )
        if p.noise.has_physics:
            assert all(isinstance(p.source[k], str) for k in PHYSICS_KEYS)
        assert p.white_balance[1] == 1.0


def test_sony_a7s2_published_numbers():
    p = load_profile("sony_a7s2")
    k = p.noise.levels("poisson-gaussian", 1600).gain
    assert k == pytest.approx(1.53, abs=0.01)  # PMN: ISO 1600 → K 1.53
    assert (p.black_level, p.white_level) == (512, 16383)


@pytest.mark.parametrize("iso", [100, 250, 1000, 1600, 4000, 6400])
def test_oppo_reno10x_follows_the_pmrid_polynomials(iso):
    """PMRID (ECCV 2020) publishes K(ISO) and the read variance B(ISO) for the phone."""
    p = load_profile("oppo_reno10x")
    levels = p.noise.levels("poisson-gaussian", iso)
    assert levels.gain == pytest.approx(0.0005995267 * iso + 0.00868861, rel=1e-6)
    variance = 7.11772e-7 * iso**2 + 6.514934e-4 * iso + 0.11492713
    assert levels.read_sigma == pytest.approx(variance**0.5, rel=0.02)  # table, log-interpolated
    assert (p.black_level, p.white_level, p.cfa.pattern) == (64, 1023, "BGGR")


def _write(tmp_path, data, name="p.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


@pytest.fixture
def sony_json():
    return json.loads((profile_dir() / "sony_a7s2.json").read_text())


def test_user_profile_by_path(tmp_path, sony_json):
    sony_json["name"] = "mine"
    sony_json["cfa_pattern"] = "GBRG"
    p = load_profile(_write(tmp_path, sony_json))
    assert p.name == "mine" and p.cfa.pattern == "GBRG"


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda d: d.pop("black_level"), "black_level"),
        (lambda d: d.update(white_level="high"), "white_level"),
        (lambda d: d.update(white_level=100), "white_level"),
        (lambda d: d.update(cfa_pattern="RG/GR"), "cfa_pattern"),  # no blue
        (lambda d: d.update(xyz_to_camera=[[1, 0], [0, 1]]), "xyz_to_camera"),
        (lambda d: d["noise"]["gain"].update(model="cubic"), "noise.gain.model"),
        (lambda d: d["noise"]["row_sigma"].pop("bias"), "noise.row_sigma.bias"),
        (lambda d: d["noise"]["read_sigma"].update(sigma=[1, 2]), "noise.read_sigma.sigma"),
        (lambda d: d["noise"].pop("row_sigma"), "noise.row_sigma"),
        (lambda d: d["noise"]["tukey_lambda"].update(k=[5, 1]), "noise.tukey_lambda.k"),
        (
            lambda d: d["noise"]["tukey_lambda"].update(**{"lambda": [0, -0.7]}),
            "noise.tukey_lambda.lambda",
        ),
        (lambda d: d["source"].pop("noise.tukey_sigma"), "source.noise.tukey_sigma"),
        (lambda d: d["noise"].update(channel_bias=[1, 2]), "noise.channel_bias"),
        (
            lambda d: d["noise"].update(gain={"model": "table", "iso": [100, 800], "k": [1, 0.5]}),
            "noise.gain.k",
        ),
        (lambda d: d["noise"].update(gain={"model": "linear", "slope": -1}), "noise.gain.slope"),
        (lambda d: d["source"].pop("noise.gain"), "source.noise.gain"),
        (lambda d: d.update(iso_range=[800, 100]), "iso_range"),
        (lambda d: d.update(bit_depth=20), "bit_depth"),
    ],
)
def test_malformed_profile_names_file_and_key(tmp_path, sony_json, edit, key):
    edit(sony_json)
    path = _write(tmp_path, sony_json)
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    assert str(path) in str(err.value) and repr(key) in str(err.value)


def test_unreadable_profiles(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    with pytest.raises(ProfileError, match="not valid JSON"):
        load_profile(bad)
    with pytest.raises(ProfileError, match="not found"):
        load_profile(tmp_path / "missing.json")
    with pytest.raises(ProfileError, match="bundled: "):
        load_profile("no_such_camera")


def test_iso_outside_declared_range_is_an_error():
    p = load_profile("nikon_d850")
    assert p.check_iso(25600) == 25600  # no cap below what the profile declares
    with pytest.raises(ParameterError, match="outside the range"):
        p.check_iso(51200)


def test_seed_config_keys(tmp_path):
    seed = {
        "sensor_size": [36, 24],
        "sensor_res": [5472, 3648],
        "bit": 10,
        "black_level": 64,
        "bayer_pattern": "bggr",
        "white_balance_d50": [2.0, 1.0, 1.8],
        "color_matrix_d50": [
            [1.6, -0.4, -0.2],
            [-0.2, 1.5, -0.3],
            [0.0, -0.5, 1.5],
            [0.01, 0.0, -0.01],
        ],
        "gamma_param": 2.2,
        "iso_base": 100,
        "read_noise_std": 0.5,
        "shot_noise_std_alpha": 0.4,
        "shot_noise_std_beta": 0.0,
    }
    p = load_profile(_write(tmp_path, seed, "seed.json"))
    assert p.cfa.pattern == "BGGR" and p.white_level == 1023 and p.black_level == 64
    assert p.ccm_bias == (0.01, 0.0, -0.01)
    assert p.iso_range is None and p.check_iso(409600) == 409600
    gauss = p.noise.levels("gaussian", 400)
    assert gauss.read_sigma == pytest.approx(2.0)  # σ_read · g
    pg = p.noise.levels("poisson-gaussian", 400)
    assert pg.gain == pytest.approx(0.16 * 4) and pg.read_sigma == pytest.approx(2.0)
    from rawsim.color import srgb_from_camera

    assert np.allclose(srgb_from_camera(p.xyz_to_camera), seed["color_matrix_d50"][:3], atol=1e-9)
    seed["bogus_key"] = 1
    with pytest.raises(ProfileError, match="'bogus_key'"):
        load_profile(_write(tmp_path, seed, "seed2.json"))
