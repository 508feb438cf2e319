"""Options that cannot act on a file say so: a one-line warning naming the option, the
reason and the outcome, and the sidecar's ``stages`` record of what did not run."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from click.testing import CliRunner

import rawsim
from rawsim.cameras.profiles import load_profile
from rawsim.errors import ParameterError, RawsimWarning
from rawsim.io.raw import read_raw
from rawsim.isp.config import IspConfig, resolve
from rawsim.pipelines.process import ProcessOptions
from rawsim.pipelines.unprocess import UnprocessOptions
from rawsim_cli.main import cli
from tests.conftest import DATA

LINEAR = DATA / "raw" / "canon_eos6d_linear_raw_no_cfa.dng"
BAYER = DATA / "raw" / "synthetic_colorchecker_bggr.dng"


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    return r


def idle(meta: dict) -> dict:
    """Stage name → why, for the stages the sidecar records as not run."""
    return {s["name"]: s["why"] for s in meta["stages"] if not s["ran"]}


@pytest.fixture(scope="module")
def linear_raw():
    return read_raw(LINEAR)


@pytest.fixture(scope="module")
def mono_raw(linear_raw):
    """The LinearRaw DNG's green as a monochrome raw (H, W, 1)."""
    return replace(
        linear_raw,
        data=np.ascontiguousarray(linear_raw.data[..., 1:2]),
        black_level=linear_raw.black_level[:1],
        as_shot_wb=None,
        daylight_wb=None,
        xyz_to_camera=None,
        camera_to_srgb=None,
        warnings=(),
    )


def test_denoise_on_a_linear_raw_dng_warns_and_changes_nothing(tmp_path):
    plain = run("process", LINEAR, "-o", tmp_path / "plain")
    assert plain.exit_code == 0, plain.output
    asked = run("process", LINEAR, "-o", tmp_path / "denoised", "--denoise", "profiled")
    assert asked.exit_code == 0, asked.output
    line = (
        f"warning: {LINEAR}: --denoise profiled acts on a CFA mosaic; this LinearRaw DNG "
        "has none: not denoised (--denoise bilateral smooths its pixels instead)"
    )
    assert line in asked.output.splitlines()
    assert "--denoise" not in plain.output  # a default that cannot act is no news
    stem = LINEAR.stem
    same = (tmp_path / "plain" / f"{stem}.png").read_bytes()
    assert (tmp_path / "denoised" / f"{stem}.png").read_bytes() == same
    meta = json.loads((tmp_path / "denoised" / f"{stem}.process.json").read_text())
    assert idle(meta)["raw_denoise"] == "acts on a CFA mosaic; this LinearRaw DNG has none"
    assert next(t for t in meta["config"] if t["name"] == "raw_denoise")["enabled"]
    assert line.split(": ", 2)[2] in meta["warnings"]
    # the default demosaic cannot act either: recorded, not warned
    plain_meta = json.loads((tmp_path / "plain" / f"{stem}.process.json").read_text())
    assert set(idle(plain_meta)) == {"demosaic"}
    assert not any("acts on" in w for w in plain_meta["warnings"])


@pytest.mark.parametrize(
    "flags, said",
    [
        ({"denoise": "learned"}, "--denoise learned acts on a CFA mosaic"),
        ({"demosaic": "half"}, "--half-size acts on a CFA mosaic; this LinearRaw DNG has none: "),
        ({"demosaic": "wcd"}, "--demosaic wcd acts on a CFA mosaic"),  # the default, asked
        ({"demosaic_domain": "linear"}, "--demosaic-domain linear acts on a CFA mosaic"),
    ],
)
def test_each_mosaic_option_on_a_linear_raw_says_so(linear_raw, flags, said):
    info = resolve(IspConfig.default().override(**flags), linear_raw).info
    (warning,) = [w for w in info["warnings"] if "acts on" in w]
    assert warning.startswith(said)


def test_stages_a_config_turns_on_are_named_as_the_configs(linear_raw):
    tables = IspConfig.default().to_tables()
    for table in tables:
        if table["name"] in ("dead_pixel", "anti_aliasing"):
            table["enabled"] = True
    info = resolve(tables, linear_raw).info
    assert [w for w in info["warnings"] if "acts on" in w] == [
        "the config's 'dead_pixel' stage acts on a CFA mosaic; this LinearRaw DNG has none: "
        "no pixel corrected",
        "the config's 'anti_aliasing' stage acts on a CFA mosaic; this LinearRaw DNG has "
        "none: not blurred",
    ]
    assert {"dead_pixel", "anti_aliasing", "demosaic"} == set(idle(info))


def test_colour_options_on_a_monochrome_raw_say_so(mono_raw):
    quiet = resolve(IspConfig.default(), mono_raw).info
    assert not any("acts on" in w for w in quiet["warnings"])
    assert set(idle(quiet)) == {"white_balance", "highlights", "demosaic", "color_matrix"}
    config = IspConfig.default().override(wb="daylight", output_space="display-p3")
    warnings = [w for w in resolve(config, mono_raw).info["warnings"] if "acts on" in w]
    assert warnings == [
        "--wb daylight acts on colour; this monochrome raw has one channel: no gains applied",
        "--output-space display-p3 acts on colour; this monochrome raw has one channel: "
        "not converted",
    ]


def test_stages_that_act_change_nothing_and_record_that_they_ran(tmp_path):
    r = run("process", BAYER, "-o", tmp_path, "--denoise", "profiled", "--demosaic", "bilinear")
    assert r.exit_code == 0, r.output
    assert "acts on" not in r.output
    meta = json.loads((tmp_path / f"{BAYER.stem}.process.json").read_text())
    enabled = [t["name"] for t in meta["config"] if t["enabled"]]
    assert meta["stages"] == [{"name": n, "ran": True} for n in enabled]


def test_lens_correction_without_a_lens_is_recorded_as_not_run():
    raw = read_raw(BAYER)  # a synthetic DNG: no LensModel
    info = resolve(IspConfig.default().override(lens_correction="auto"), raw).info
    assert info["lens"] is None
    why = idle(info)["lens_correction"]
    assert "names no lens" in why and "pass --lens NAME" in why


def test_exr_leaves_out_the_tone_curve_asked_for(tmp_path):
    r = run("process", BAYER, "-o", tmp_path, "--format", "exr", "--tone", "reinhard")
    assert r.exit_code == 0, r.output
    assert (
        f"warning: {BAYER}: --tone reinhard shapes display-referred output; --format exr "
        "writes scene-linear light: left out (--format tiff --bits 16 keeps it)"
    ) in r.output.splitlines()
    meta = json.loads((tmp_path / f"{BAYER.stem}.process.json").read_text())
    assert idle(meta) == {"tone": "--format exr is scene-linear"}
    assert ProcessOptions(fmt="exr").left_out() == []  # the defaults say nothing


def test_a_thumbnail_with_render_options_is_a_usage_error(tmp_path):
    r = run("process", BAYER, "-o", tmp_path, "--thumbnail", "--half-size")
    assert r.exit_code == 2
    assert "--thumbnail writes the raw's embedded JPEG, not a render: --half-size" in r.output
    with pytest.raises(ParameterError, match="--denoise profiled does not apply"):
        ProcessOptions(
            config=IspConfig.default().override(denoise="profiled"), fmt="jpg", thumbnail=True
        )


def test_unprocess_options_that_cannot_act(tmp_path):
    with pytest.raises(ParameterError, match="--wb-inverse safe inverts a white balance"):
        UnprocessOptions(load_profile("sony_a7s2"), sensor="mono", safe_white_balance=True)
    exr = DATA / "exr" / "cannon_half_b44.exr"
    args = ["unprocess", exr, "-o", tmp_path, "-p", "sony_a7s2", "--iso", 800]
    r = run(*args, "--tone", "reinhard", "--transfer", "gamma:2.2")
    assert r.exit_code == 0, r.output
    said = (
        "--tone reinhard and --transfer gamma:2.2 decode 8/16-bit display-referred images; "
        "this one is scene-linear (floats): not applied"
    )
    assert f"warning: {exr}: {said}" in r.output.splitlines()
    assert said in json.loads((tmp_path / f"{exr.stem}.json").read_text())["warnings"]


def test_the_python_api_warns_what_the_cli_prints():
    mono = rawsim.MonoSensor.from_profile("canon_eos_70d")
    image = torch.full((1, 3, 16, 16), 0.4)
    noisy, _, meta = rawsim.unprocess(image, mono, [1], iso=800)
    with pytest.warns(RawsimWarning, match="^--denoise profiled acts on a CFA mosaic; this "):
        rawsim.process(noisy, mono, meta, denoise="profiled")
    with pytest.warns(RawsimWarning, match="^--tone aces decodes 8/16-bit"):
        rawsim.unprocess(image, mono, [1], iso=800, tone="aces", display_referred=False)
