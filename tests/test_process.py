"""rawsim process: raw reading, ISP config, agreement with LibRaw, round trip, the CLI."""

import json
import shutil

import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
import torch
from click.testing import CliRunner

from rawsim.cameras.profiles import load_profile
from rawsim.errors import ParameterError, UnsupportedInputError
from rawsim.io.raw import read_raw
from rawsim.io.spare import Spare
from rawsim.io.task import Task
from rawsim.isp.config import (
    STAGES,
    IspConfig,
    OrientationStage,
    config_to_toml,
    default_config,
    load_config,
    load_config_text,
    override,
    validate_config,
)
from rawsim.pipelines.process import render
from rawsim.pipelines.unprocess import UnprocessOptions, unprocess_file
from rawsim_cli.main import cli
from tests.conftest import DATA, psnr

RAW = DATA / "raw"
#: rawsim's demosaic as LibRaw's: bilinear, on linear values.
AS_LIBRAW = {
    "demosaic": "bilinear",
    "demosaic_domain": "linear",
    "highlights": "clip",
    "saturation": "white",  # as LibRaw's adjust_maximum_thr=0 below
    "dng_matrices": "libraw",  # LibRaw takes one of a DNG's two matrices
}
LIBRAW_MATCHED = dict(
    use_camera_wb=True,
    demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR,
    highlight_mode=rawpy.HighlightMode.Clip,
    no_auto_bright=True,
    output_bps=16,
    user_flip=0,
    adjust_maximum_thr=0.0,  # LibRaw's other auto-brightening: off, as in rawsim
)


def _crop(a):
    return a[10:-10, 10:-10]


def _rgb(t: torch.Tensor) -> np.ndarray:
    return t[0].permute(1, 2, 0).numpy()


# ---- reading raws ---------------------------------------------------------------------


def test_read_raw_shared_files():
    canon = read_raw(RAW / "canon_eos60d_mlv.dng")
    assert canon.cfa.pattern == "RGGB" and canon.data.shape == (540, 960)
    assert canon.black_level.tolist() == [[2048] * 2] * 2 and canon.white_level == 15000
    assert canon.as_shot_wb[1] == 1 and canon.xyz_to_camera is not None and not canon.warnings
    assert (canon.make, canon.model) == ("Canon", "Canon EOS 60D")
    kodak = read_raw(RAW / "kodak_dc50_grbg.kdc")
    assert kodak.cfa.pattern == "GRBG" and kodak.as_shot_wb == (1.0, 1.0, 1.0)  # LibRaw uses it
    assert kodak.xyz_to_camera is None and "measured" in kodak.matrix_source
    # LibRaw's own matrix (rows sum to 1: white stays white), which rawpy does not show
    assert np.allclose(kodak.camera_to_srgb.sum(axis=1), 1, atol=2e-3) and not kodak.warnings
    assert kodak.camera_to_srgb[2, 2] == pytest.approx(3.07, abs=0.01)
    quicktake = read_raw(RAW / "apple_quicktake150.qtk")  # multipliers [0, 1, 0, 0]
    assert quicktake.as_shot_wb is None and quicktake.camera_wb_fallback == "auto"
    bggr = read_raw(RAW / "synthetic_colorchecker_bggr.dng")
    assert bggr.cfa.pattern == "BGGR" and bggr.as_shot_wb == pytest.approx((2.0, 1.0, 1.50015))
    linear = read_raw(RAW / "canon_eos6d_linear_raw_no_cfa.dng")
    assert linear.cfa is None and linear.data.shape == (816, 1224, 3)


def test_a_batchs_next_raw_is_copied_into_the_last_ones_samples():
    spare = Spare()
    first = read_raw(RAW / "canon_eos60d_mlv.dng", spare)
    kept = first.data
    spare.keep_array(kept)
    again = read_raw(RAW / "canon_eos60d_mlv.dng", spare)  # the same size: the kept array
    assert np.shares_memory(again.data, kept) and len(spare) == 0
    with rawpy.imread(str(RAW / "canon_eos60d_mlv.dng")) as raw:
        assert np.array_equal(again.data, raw.raw_image_visible)
    spare.keep_array(again.data)
    kodak = read_raw(RAW / "kodak_dc50_grbg.kdc", spare)  # another size: a new array
    assert not np.shares_memory(kodak.data, kept) and len(spare) == 1
    assert np.array_equal(kodak.data, read_raw(RAW / "kodak_dc50_grbg.kdc").data)


def test_read_raw_errors(tmp_path):
    (tmp_path / "empty.dng").write_bytes(b"")
    with pytest.raises(UnsupportedInputError, match="0 bytes"):
        read_raw(tmp_path / "empty.dng")
    shutil.copy(DATA / "srgb" / "chelsea.png", tmp_path / "photo.cr2")
    with pytest.raises(UnsupportedInputError, match="not a raw file"):
        read_raw(tmp_path / "photo.cr2")
    data = (RAW / "canon_eos60d_mlv.dng").read_bytes()
    (tmp_path / "cut.dng").write_bytes(data[: len(data) // 4])
    with pytest.raises(UnsupportedInputError, match="cut.dng"):
        read_raw(tmp_path / "cut.dng")


# ---- config ---------------------------------------------------------------------------


def test_isp_show_round_trips_through_config(tmp_path):
    r = CliRunner().invoke(cli, ["isp", "show"])
    assert r.exit_code == 0
    path = tmp_path / "isp.toml"
    path.write_text(r.output)
    assert load_config(path) == validate_config(default_config())
    assert [s["name"] for s in load_config(path)] == list(STAGES)
    check = CliRunner().invoke(cli, ["isp", "check", str(path)])
    assert check.exit_code == 0 and "demosaic → color_matrix" in check.output


@pytest.mark.parametrize(
    "text, message",
    [
        ('[[stage]]\nname = "sharpen"', "unknown stage 'sharpen'; valid: black_level"),
        (
            '[[stage]]\nname = "demosaic"\nmethod = "ahd"',
            "valid: wcd, learned, menon, malvar, bilinear",
        ),
        ('[[stage]]\nname = "tone"\ncolour = 1', "unknown key 'colour'; valid: enabled, curve"),
        ('[[stage]]\nname = "exposure"\nev = "bright"', "expected stops in [-20, 20] or auto"),
        (
            '[[stage]]\nname = "black_level"\n[[stage]]\nname = "color_matrix"\n[[stage]]\n'
            'name = "demosaic"',
            "'color_matrix' must come after 'demosaic'",
        ),
        ('[[stage]]\nname = "black_level"', "needs an enabled 'demosaic'"),
        ("[[stage]\n", "not valid TOML"),
        ('colour = "vivid"', "unknown top-level key 'colour'; valid: stage"),
        ('[[stage]]\nname = "white_balance"\nmode = "1,2"', "R,G,B"),
    ],
)
def test_bad_configs_are_clear_errors(text, message):
    with pytest.raises(ParameterError, match=message.replace("(", r"\(").replace("[", r"\[")):
        load_config_text(text)


def test_overrides_and_blend_moves_after_demosaic():
    cfg = override(
        default_config(),
        wb="2,1,1.5",
        highlights="blend",
        demosaic="menon",
        exposure=1.0,
        output_space="xyz",
        transfer="gamma:2.2",
        tone="aces",
    )
    names = [s["name"] for s in cfg]
    assert names.index("highlights") == names.index("demosaic") + 1
    by = {s["name"]: s for s in cfg}
    assert by["white_balance"]["mode"] == "2,1,1.5" and by["transfer"]["function"] == "gamma:2.2"
    assert by["exposure"]["ev"] == 1.0 and by["color_matrix"]["output_space"] == "xyz"
    assert load_config_text(config_to_toml(cfg)) == cfg


# ---- rendering ------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["canon_eos60d_mlv.dng", "synthetic_colorchecker_bggr.dng"])
def test_agrees_with_libraw_srgb(name):
    raw = read_raw(RAW / name)
    ours, _ = render(raw, override(default_config(), **AS_LIBRAW))
    with rawpy.imread(str(RAW / name)) as r:
        ref = (
            r.postprocess(output_color=rawpy.ColorSpace.sRGB, gamma=(2.4, 12.92), **LIBRAW_MATCHED)
            / 65535.0
        )
    assert psnr(_crop(np.clip(_rgb(ours), 0, 1)), _crop(ref)) >= 40


def test_agrees_with_libraw_in_camera_space_for_kodak():
    """LibRaw applies a Kodak matrix that rawpy does not expose; the camera data agree."""
    raw = read_raw(RAW / "kodak_dc50_grbg.kdc")
    cfg = override(
        default_config(), **AS_LIBRAW, wb="1,1,1", output_space="camera", transfer="linear"
    )
    ours, _ = render(raw, cfg)
    with rawpy.imread(str(RAW / "kodak_dc50_grbg.kdc")) as r:
        ref = (
            r.postprocess(output_color=rawpy.ColorSpace.raw, gamma=(1, 1), **LIBRAW_MATCHED)
            / 65535.0
        )
    assert psnr(_crop(np.clip(_rgb(ours), 0, 1)), _crop(ref)) >= 40


WB_MODES = {"camera": {"use_camera_wb": True}, "daylight": {}, "auto": {"use_auto_wb": True}}


#: Every real raw of tests/data: tests/data/raw and the blown-highlight crops of
#: tests/data/highlights (GoPro's mirrored: LibRaw does not mirror, so compared unrotated).
EVERY_RAW = sorted([*RAW.iterdir(), *(DATA / "highlights").glob("*.dng")], key=lambda p: p.name)


@pytest.mark.parametrize("wb", WB_MODES)
@pytest.mark.parametrize("path", EVERY_RAW, ids=lambda p: p.name)
def test_colour_agrees_with_libraw_on_every_raw(path, wb):
    """Every raw in tests/data, old cameras included, against LibRaw with matched
    settings: its white-balance rules and scaling, its matrices (also those rawpy
    does not show), for --wb camera, daylight and auto."""
    name = path.name
    raw = read_raw(path)
    matched = {**AS_LIBRAW, "wb": wb, "baseline_exposure": "ignore"}
    config = IspConfig.of(override(default_config(), **matched)).with_disabled(OrientationStage)
    ours, info = render(raw, config)
    with rawpy.imread(str(path)) as r:
        ref = r.postprocess(
            output_color=rawpy.ColorSpace.sRGB,
            gamma=(2.4, 12.92),
            **(LIBRAW_MATCHED | {"use_camera_wb": False} | WB_MODES[wb]),
        )
    ours = np.clip(_rgb(ours), 0, 1)
    h, w = min(ours.shape[0], ref.shape[0]), min(ours.shape[1], ref.shape[1])
    db = psnr(_crop(ours[:h, :w]), _crop(ref[:h, :w] / 65535.0))
    source = info["white_balance_source"].split(":")[0]
    row = f"{name:36} {raw.model[:22]:22} {wb:8} used {source:8} {db:5.1f} dB  {raw.matrix_source}"
    print(row)  # the table: pytest -s -k agrees_with_libraw
    assert db >= 40, row


@pytest.mark.parametrize("name", sorted(p.name for p in RAW.iterdir()))
def test_default_render_agrees_with_libraw_ahd_in_colour(name):
    """rawsim has no AHD: its default wcd against LibRaw's AHD. The demosaics differ at
    edges (28–52 dB at full resolution on these files), so colour is compared on
    9 × 9 local means: ≥ 35 dB (37.9 on the synthetic chart's hard patch edges).
    LibRaw's own default, adjust_maximum_thr 0.75, as rawsim's default finds where each
    colour saturates: the synthetic chart's noise-free brightest patch piles up as
    saturation does, and both take it for white."""
    from scipy.ndimage import uniform_filter

    raw = read_raw(RAW / name)
    ours, _ = render(raw, override(default_config(), baseline_exposure="ignore"))
    with rawpy.imread(str(RAW / name)) as r:
        ahd = LIBRAW_MATCHED | {
            "demosaic_algorithm": rawpy.DemosaicAlgorithm.AHD,
            "adjust_maximum_thr": 0.75,
        }
        ref = r.postprocess(output_color=rawpy.ColorSpace.sRGB, gamma=(2.4, 12.92), **ahd)
    ours = np.clip(_rgb(ours), 0, 1)
    h, w = min(ours.shape[0], ref.shape[0]), min(ours.shape[1], ref.shape[1])
    local = [uniform_filter(x[:h, :w], (9, 9, 1)) for x in (ours, ref / 65535.0)]
    assert psnr(_crop(local[0]), _crop(local[1])) >= 35


def test_white_level_auto_is_libraws_default_render():
    name = "synthetic_colorchecker_bggr.dng"  # maximum 14731 of 16383: LibRaw lowers white
    raw = read_raw(RAW / name)
    ours, info = render(raw, override(default_config(), **AS_LIBRAW, white_level="auto"))
    assert info["white_level"] == raw.data.max() < raw.white_level
    with rawpy.imread(str(RAW / name)) as r:
        matched = LIBRAW_MATCHED | {"adjust_maximum_thr": 0.75}
        ref = r.postprocess(output_color=rawpy.ColorSpace.sRGB, gamma=(2.4, 12.92), **matched)
    assert psnr(_crop(np.clip(_rgb(ours), 0, 1)), _crop(ref / 65535.0)) >= 40
    _, info = render(raw, default_config())
    assert info["white_level"] == raw.white_level  # the file's, by default


def test_white_balance_scales_to_the_smallest_gain_when_clipping():
    raw = read_raw(RAW / "apple_quicktake150.qtk")
    _, clipped = render(raw, override(default_config(), wb="daylight"))
    assert min(clipped["white_balance"]) == 1.0 and clipped["white_balance"][1] > 1
    _, blended = render(raw, override(default_config(), wb="daylight", highlights="blend"))
    assert blended["white_balance"][1] == 1.0
    _, info = render(raw, default_config())
    assert info["white_balance_source"].startswith("auto: the camera's multipliers")
    assert any("using auto, as LibRaw does" in w for w in info["warnings"])


def test_bggr_colours_are_right():
    """The colour checker's patches: red is red, blue is blue, greys are neutral."""
    out, _ = render(read_raw(RAW / "synthetic_colorchecker_bggr.dng"), default_config())
    img = _rgb(out)
    h, w = img.shape[:2]

    def patch(row, col):  # 4 rows × 6 columns of patches
        y, x = int((row + 0.5) * h / 4), int((col + 0.5) * w / 6)
        return img[y - 3 : y + 3, x - 3 : x + 3].reshape(-1, 3).mean(0)

    red, blue, green = patch(2, 2), patch(2, 0), patch(2, 1)
    assert red[0] > 2 * red[1] and red[0] > 2 * red[2]
    assert blue[2] > 2 * blue[0] and blue[2] > blue[1]
    assert green[1] > green[0] and green[1] > green[2]
    for col in range(6):
        grey = patch(3, col)
        assert np.ptp(grey) < 0.05 * grey.max() + 0.01


def test_no_cfa_dng_renders_as_three_channels():
    raw = read_raw(RAW / "canon_eos6d_linear_raw_no_cfa.dng")
    out, info = render(raw, default_config())
    assert out.shape == (1, 3, 816, 1224)
    assert any("no CFA" in w for w in info["warnings"])
    assert 0.01 < float(out.mean()) < 0.9


def test_a_raw_that_is_not_a_flat_mosaic_and_has_no_matrix_is_rendered(tmp_path):
    """LibRaw gives such raws (3-sample LinearRaw; the Kodak C330) as full images and
    refuses ``raw_colors`` ("RAW image is not flat"): no internal error in info or
    process, camera RGB as sRGB, said in a warning."""
    import tifffile

    path = tmp_path / "no_matrix.dng"
    shutil.copy(RAW / "canon_eos6d_linear_raw_no_cfa.dng", path)
    with tifffile.TiffFile(path, mode="r+b") as tif:  # no matrix, a camera LibRaw lacks
        tags = tif.pages.first.tags
        for code in (50721, 50722, 50964, 50965):  # ColorMatrix1/2, ForwardMatrix1/2
            tags[code].overwrite([0, 1] * 9)
        for code, name in ((271, "Nomake"), (272, "Nomodel X1"), (50708, "Nomodel X1")):
            tags[code].overwrite(name)
    with rawpy.imread(str(path)) as libraw:  # what makes it this case
        assert libraw.raw_pattern is None and not libraw.rgb_xyz_matrix.any()
        with pytest.raises(RuntimeError, match="not flat"):
            _ = libraw.raw_colors
    info = CliRunner().invoke(cli, ["info", str(path)])
    assert info.exit_code == 0, info.output
    assert "camera RGB treated as sRGB" in info.output
    done = CliRunner().invoke(cli, ["process", str(path), "-o", str(tmp_path / "out")])
    assert done.exit_code == 0, done.output
    assert "no colour matrix for this camera" in done.output
    assert (tmp_path / "out" / "no_matrix.png").exists()


def test_round_trip_unprocess_then_process(tmp_path):
    """--clean DNG → rawsim process with the same profile returns the photo."""
    results = {}
    for name in ("srgb16/hdr_room_16bit.png", "srgb/chelsea.png"):
        src = DATA / name
        options = UnprocessOptions(
            load_profile("sony_a7s2"), iso=800, clean=True, safe_white_balance=False
        )
        outputs = {k: tmp_path / f"{src.stem}{v}" for k, v in options.output_suffixes().items()}
        unprocess_file(Task(src, src.name, outputs, 1), options)
        raw = read_raw(outputs["clean_dng"])
        photo = oiio.ImageBuf(str(src)).get_pixels(oiio.FLOAT)[:, :, :3]
        photo = photo[: raw.data.shape[0], : raw.data.shape[1]]
        for method in ("bilinear", "wcd"):
            out, _ = render(raw, override(default_config(), demosaic=method))
            results[name, method] = psnr(_crop(np.clip(_rgb(out), 0, 1)), _crop(photo))
    assert results["srgb16/hdr_room_16bit.png", "wcd"] >= 38
    assert results["srgb/chelsea.png", "wcd"] >= 35
    for name in ("srgb16/hdr_room_16bit.png", "srgb/chelsea.png"):
        assert results[name, "wcd"] > results[name, "bilinear"] + 4


def _smooth_photo(path, scale: float, green: float, blue: tuple[float, float]):
    """A smooth 192 × 128 16-bit TIFF: gentle ramps and a sine, no edges to demosaic."""
    y, x = np.mgrid[0:128, 0:192] / scale
    img = np.stack([0.2 + 0.3 * x, 0.3 + green * y, blue[0] + blue[1] * np.sin(3 * x)], -1)
    buf = oiio.ImageBuf(oiio.ImageSpec(192, 128, 3, oiio.UINT16))
    buf.set_pixels(oiio.ROI(), img.astype(np.float32))
    assert buf.write(str(path))
    return path


def _clean_dng(src, tmp_path, **changes):
    options = UnprocessOptions(load_profile("nikon_d850"), iso=100, clean=True, **changes)
    outputs = {k: tmp_path / f"s{v}" for k, v in options.output_suffixes().items()}
    unprocess_file(Task(src, src.name, outputs, 1), options)
    return read_raw(outputs["clean_dng"])


def test_smooth_round_trip_is_exact_but_for_quantisation(tmp_path):
    src = _smooth_photo(tmp_path / "smooth.tif", 128.0, 0.5, (0.5, 0.3))
    raw = _clean_dng(src, tmp_path)
    out, _ = render(raw, default_config())
    photo = oiio.ImageBuf(str(src)).get_pixels(oiio.FLOAT)
    assert psnr(_crop(_rgb(out)), _crop(photo)) >= 50


def test_round_trip_restores_brightness_through_baseline_exposure(tmp_path):
    """unprocess darkens by a stop and writes BaselineExposure +1; process applies it
    (the source's brightness comes back), or renders a stop darker when told to ignore it."""
    src = _smooth_photo(tmp_path / "smooth.tif", 256.0, 0.4, (0.25, 0.1))
    raw = _clean_dng(src, tmp_path, exposure_ev=-1.0)
    assert raw.baseline_exposure == 1.0
    photo = oiio.ImageBuf(str(src)).get_pixels(oiio.FLOAT)
    applied, _ = render(raw, default_config())
    ignored, _ = render(raw, override(default_config(), baseline_exposure="ignore"))
    assert psnr(_crop(_rgb(applied)), _crop(photo)) >= 45
    assert psnr(_crop(_rgb(ignored)), _crop(photo)) < 25


# ---- CLI ------------------------------------------------------------------------------


def test_process_cli_formats_and_sidecars(tmp_path):
    src = tmp_path / "raws"
    (src / "sub").mkdir(parents=True)
    shutil.copy(RAW / "canon_eos60d_mlv.dng", src / "a.dng")
    shutil.copy(RAW / "synthetic_colorchecker_bggr.dng", src / "sub" / "b.dng")
    for fmt, bits, ext, kind in [
        ("png", "8", ".png", "uint8"),
        ("tiff", "16", ".tif", "uint16"),
        ("jpg", "8", ".jpg", "uint8"),
        ("exr", "16", ".exr", "half"),
    ]:
        out = tmp_path / fmt
        r = CliRunner().invoke(
            cli,
            [
                "process",
                str(src),
                "-o",
                str(out),
                "--format",
                fmt,
                "--bits",
                bits,
                "--wb",
                "camera",
            ],
        )
        assert r.exit_code == 0, r.output
        img = oiio.ImageInput.open(str(out / "sub" / f"b{ext}"))
        assert str(img.spec().format) == kind and img.spec().width == 256
        img.close()
        meta = json.loads((out / "a.process.json").read_text())
        assert meta["white_balance"] == pytest.approx([2.338, 1.0, 1.416], abs=1e-3)
        assert load_config_text(meta["config_toml"]) == meta["config"]
    exr_meta = json.loads((tmp_path / "exr" / "a.process.json").read_text())
    assert not next(s for s in exr_meta["config"] if s["name"] == "transfer")["enabled"]


def test_process_cli_config_flags_and_errors(tmp_path):
    cfg = tmp_path / "isp.toml"
    cfg.write_text(
        CliRunner()
        .invoke(cli, ["isp", "show"])
        .output.replace('method = "wcd"', 'method = "malvar"')
    )
    r = CliRunner().invoke(
        cli,
        [
            "process",
            str(RAW),
            "-o",
            str(tmp_path / "o"),
            "-c",
            str(cfg),
            "--tone",
            "hable",
            "--exposure",
            "0.5",
        ],
    )
    assert r.exit_code == 0, r.output
    meta = json.loads((tmp_path / "o" / "kodak_dc50_grbg.process.json").read_text())
    by = {s["name"]: s for s in meta["config"]}
    assert by["demosaic"]["method"] == "malvar" and by["tone"]["curve"] == "hable"
    assert meta["white_balance_source"] == "camera" and "measured" in meta["matrix_source"]
    quicktake = json.loads((tmp_path / "o" / "apple_quicktake150.process.json").read_text())
    assert quicktake["white_balance_source"].startswith("auto: the camera's multipliers")
    assert any("as LibRaw does" in w for w in quicktake["warnings"])
    bad = tmp_path / "bad.toml"
    bad.write_text('[[stage]]\nname = "sharpen"\n')
    r = CliRunner().invoke(cli, ["process", str(RAW), "-o", str(tmp_path / "x"), "-c", str(bad)])
    assert r.exit_code == 2 and "unknown stage 'sharpen'" in r.output
    r = CliRunner().invoke(
        cli, ["process", str(RAW), "-o", str(tmp_path / "x"), "--format", "jpg", "--bits", "16"]
    )
    assert r.exit_code == 2 and "--bits 8" in r.output
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "empty.nef").write_bytes(b"")
    shutil.copy(DATA / "srgb" / "rocket.jpg", junk / "photo.arw")
    shutil.copy(RAW / "canon_eos60d_mlv.dng", junk / "ok.dng")
    r = CliRunner().invoke(cli, ["process", str(junk), "-o", str(tmp_path / "j")])
    assert r.exit_code == 1 and "1 done, 0 skipped, 2 failed" in r.output
    assert "empty.nef" in r.output and "photo.arw" in r.output and "Traceback" not in r.output


def test_cli_choices_match_the_core():
    from rawsim.isp.config import OUTPUT_SPACES
    from rawsim.isp.demosaic import DEMOSAIC_METHODS
    from rawsim.isp.highlights import HIGHLIGHT_MODES
    from rawsim.isp.tone import TONE_CURVES
    from rawsim_cli import process

    assert process.DEMOSAICS == DEMOSAIC_METHODS and process.HIGHLIGHTS == HIGHLIGHT_MODES
    assert process.TONES == TONE_CURVES and process.SPACES == OUTPUT_SPACES


def test_strips_give_the_full_frame_result():
    """Without gradients the ISP runs in strips; every stage must see enough context."""
    from dataclasses import replace

    from rawsim.isp.pipeline import STRIP_ROWS, build_isp

    raw = read_raw(RAW / "canon_eos60d_mlv.dng")
    tall = np.concatenate([raw.data] * 2)[: 2 * STRIP_ROWS + 70]
    raw = replace(raw, data=tall, black_level=np.array([[2040.0, 2048.0], [2050.0, 2056.0]]))
    config = default_config()
    for stage in config:
        stage["enabled"] = stage["name"] != "ycbcr"
    for method in ("wcd", "menon"):
        config = override(config, demosaic=method)
        isp = build_isp(config, raw)
        x = torch.from_numpy(raw.data.astype(np.float32))[None, None]
        with torch.no_grad():
            strips = isp(x)
        full = isp(x).detach()  # gradients on: one pass over the whole frame
        assert torch.allclose(strips, full, atol=1e-5), float((strips - full).abs().max())


def test_process_warns_on_stderr_and_is_identical_for_any_jobs(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    r = CliRunner().invoke(cli, ["process", str(RAW), "-o", str(a), "--jobs", "1"])
    assert r.exit_code == 0
    assert "apple_quicktake150.qtk: camera white balance: the camera's multipliers" in r.output
    assert (
        CliRunner().invoke(cli, ["-q", "process", str(RAW), "-o", str(b), "--jobs", "2"]).exit_code
        == 0
    )
    for png in a.glob("*.png"):
        assert png.read_bytes() == (b / png.name).read_bytes()


def test_minimal_config_without_colour_matrix(tmp_path):
    cfg = tmp_path / "min.toml"
    cfg.write_text(
        '[[stage]]\nname = "black_level"\n[[stage]]\nname = "demosaic"\nmethod = "bilinear"\n'
    )
    r = CliRunner().invoke(
        cli,
        [
            "process",
            str(RAW / "canon_eos60d_mlv.dng"),
            "-o",
            str(tmp_path / "o"),
            "-c",
            str(cfg),
            "--format",
            "tiff",
        ],
    )
    assert r.exit_code == 0, r.output
    img = oiio.ImageInput.open(str(tmp_path / "o" / "canon_eos60d_mlv.tif"))
    assert img.spec().get_string_attribute("oiio:ColorSpace") != "sRGB"  # camera RGB, untagged
    img.close()


def test_info_prints_what_is_read_and_used(tmp_path):
    bad = tmp_path / "bad.dng"
    bad.write_text("not a raw")
    r = CliRunner().invoke(
        cli, ["info", str(RAW / "apple_quicktake150.qtk"), str(RAW / "kodak_dc50_grbg.kdc")]
    )
    assert r.exit_code == 0, r.output
    assert "white_balance_source     auto: the camera's multipliers are unusable" in r.output
    assert "matrix_source            LibRaw's built-in camera matrix" in r.output
    r = CliRunner().invoke(cli, ["info", str(RAW / "canon_eos60d_mlv.dng"), str(bad), "--json"])
    assert r.exit_code == 1 and "bad.dng: truncated or not a raw file" in r.output
    record = json.loads(next(line for line in r.output.splitlines() if line.startswith("{")))
    assert record["model"] == "Canon EOS 60D" and record["white_balance_source"] == "camera"
    assert min(record["white_balance"]) == 1.0 and len(record["color_matrix"]) == 3


def test_baseline_exposure_is_applied_unless_ignored():
    """The 6D's DNG says BaselineExposure +0.25: applied as Adobe's SDK does (a
    brighter render), ignored on request as LibRaw does."""
    raw = read_raw(RAW / "canon_eos6d_linear_raw_no_cfa.dng")
    assert raw.baseline_exposure == 0.25
    cfg = override(default_config(), transfer="linear", tone="none")
    applied, info = render(raw, cfg)
    ignored, info_ignored = render(raw, override(cfg, baseline_exposure="ignore"))
    assert info["exposure_stops"] == 0.25 and info_ignored["exposure_stops"] == 0.0
    inside = ignored < 0.5
    assert torch.allclose(applied[inside], ignored[inside] * 2**0.25, rtol=1e-5, atol=1e-6)


def test_dark_check_counts_codes_as_the_percentile_says():
    """The dark-render check's count of codes at the level gives np.percentile's answer
    (99th, linear), levels at, just below and just above the percentile included."""
    from rawsim.pipelines.process import _percentile_reaches

    rng = np.random.default_rng(1)
    for trial in range(600):
        n, full = int(rng.integers(1, 300)), float(rng.choice([255, 65535]))
        x = rng.integers(0, int(full) + 1, size=n).astype(np.uint8 if full == 255 else np.uint16)
        if trial % 3 == 0:
            x[:] = rng.integers(0, 5, size=n)  # ties around the percentile
        p = float(np.percentile(x, 99)) / full
        for level in (p, np.nextafter(p, 0), np.nextafter(p, 1), rng.random(), 0.0):
            assert _percentile_reaches(x, full, level) == (p >= level), (n, full, level)
    floats = rng.random(1000).astype(np.float32)
    assert _percentile_reaches(floats, 1.0, 0.98) and not _percentile_reaches(floats, 1.0, 0.999)


def test_exposure_auto_brightens_as_libraw_and_dark_renders_warn(tmp_path):
    """A raw shot 4 stops under: the plain render (BaselineExposure ignored) warns and
    names --exposure auto; auto brings the 99th percentile to white, as LibRaw's
    auto-brightness does (same mean within 10 %), in the engine and the reference."""
    outputs = {"dng": tmp_path / "c.dng", "json": tmp_path / "c.json"}
    task = Task(DATA / "srgb" / "coffee.png", "coffee.png", outputs, 1)
    unprocess_file(task, UnprocessOptions(load_profile("sony_a7s2"), iso=800, exposure_ev=-4.0))
    runner = CliRunner()
    base = ["process", str(tmp_path / "c.dng"), "--json", "-q", "--baseline-exposure", "ignore"]
    r = runner.invoke(cli, [*base, "-o", str(tmp_path / "plain")])
    assert r.exit_code == 0, r.output
    (record,) = [json.loads(line) for line in r.stdout.splitlines()]
    assert any("dark render" in w and "--exposure auto" in w for w in record["warnings"])
    lin = ["--transfer", "linear", "--format", "tiff", "--bits", "16", "--exposure", "auto"]
    r = runner.invoke(cli, [*base, *lin, "-o", str(tmp_path / "auto")])
    (record,) = [json.loads(line) for line in r.stdout.splitlines()]
    assert not any("dark render" in w for w in record["warnings"])
    meta = json.loads((tmp_path / "auto" / "c.process.json").read_text())
    assert 3.5 < meta["exposure_stops"] < 4.5
    ours = oiio.ImageBuf(str(tmp_path / "auto" / "c.tif")).get_pixels(oiio.FLOAT)
    with rawpy.imread(str(tmp_path / "c.dng")) as raw:
        libraw = (
            raw.postprocess(gamma=(1, 1), no_auto_bright=False, output_bps=16, use_camera_wb=True)
            / 65535.0
        )
    assert ours.mean() / libraw.mean() == pytest.approx(1.0, abs=0.10)
    raw = read_raw(tmp_path / "c.dng")
    cfg = override(default_config(), exposure="auto")
    _, info = render(raw, cfg)  # the torch reference resolves the same stops
    assert info["exposure_stops"] == pytest.approx(meta["exposure_stops"], abs=1e-6)
    with pytest.raises(ParameterError, match="or auto"):
        override(default_config(), exposure="bright")
