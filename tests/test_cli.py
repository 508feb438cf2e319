"""The command line: outputs, batch behaviour, errors and exit codes, determinism."""

import datetime
import hashlib
import json
import re
import shutil
import subprocess
import sys

import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
from click.testing import CliRunner

from rawsim.cameras.profiles import load_profile
from rawsim_cli.main import cli
from tests.conftest import DATA, ROOT


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def digest(folder):
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture
def photos(tmp_path):
    """A small input tree: two photos at the top, one in a sub-folder, one non-image."""
    root = tmp_path / "in"
    (root / "sub").mkdir(parents=True)
    shutil.copy(DATA / "srgb" / "chelsea.png", root / "chelsea.png")
    shutil.copy(DATA / "srgb" / "rocket.jpg", root / "rocket.jpg")
    shutil.copy(DATA / "srgb16" / "painted_figure_16bit.tif", root / "sub" / "figure.tif")
    (root / "notes.txt").write_text("not an image, and not picked up from a folder")
    return root


def test_help_does_not_import_torch():
    code = (
        "import sys; from click.testing import CliRunner; from rawsim_cli.main import cli; "
        "r = CliRunner().invoke(cli, ['--help']); assert r.exit_code == 0, r.output; "
        "assert 'unprocess' in r.output; assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_version_and_command_help():
    assert run("--version").output.startswith("rawsim, version ")
    out = run("unprocess", "--help").output
    assert "Example:" in out and "U(1.9, 2.4)" in out and "--iso-range" in out


def test_unprocess_mirrors_tree_and_writes_sidecars(photos, tmp_path):
    out = tmp_path / "out"
    r = run(
        "unprocess",
        photos,
        "-o",
        out,
        "--profile",
        "sony_a7s2",
        "--iso",
        1600,
        "--clean",
        "--format",
        "both",
    )
    assert r.exit_code == 0, r.output
    assert "3 done, 0 skipped, 0 failed" in r.output
    names = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert names == sorted(
        f"{s}{x}"
        for s in ("chelsea", "rocket", "sub/figure")
        for x in (".dng", ".clean.dng", ".json", ".npz")
    )
    meta = json.loads((out / "chelsea.json").read_text())
    assert meta["crop"] == {
        "x": 0,
        "y": 0,
        "width": 450,
        "height": 300,
        "source_width": 451,
        "source_height": 300,
    }
    for key in ("profile", "params", "noise", "seed", "file_seed", "black_level", "white_level"):
        assert key in meta
    assert meta["noise"]["gain_dn_per_electron"] == pytest.approx(1.52543)
    assert meta["params"]["transfer"] == "srgb" and meta["params"]["tone"] == "none"
    npz = np.load(out / "sub" / "figure.npz")
    assert npz["mosaic"].shape == (4, 221, 145) and npz["mosaic"].dtype == np.uint16
    assert list(npz["planes"]) == ["R", "Gr", "Gb", "B"]
    assert json.loads(str(npz["metadata"]))["input"] == "sub/figure.tif"
    with rawpy.imread(str(out / "sub" / "figure.dng")) as raw:
        packed = np.stack(
            [
                raw.raw_image[0::2, 0::2],
                raw.raw_image[0::2, 1::2],
                raw.raw_image[1::2, 0::2],
                raw.raw_image[1::2, 1::2],
            ]
        )
    assert np.array_equal(packed, npz["mosaic"])  # RGGB: R, Gr, Gb, B sites


def test_existing_outputs_are_skipped_unless_overwrite(photos, tmp_path):
    out = tmp_path / "out"
    args = ("unprocess", photos, "-o", out, "-p", "nikon_d850", "--iso", 800)
    assert run(*args).exit_code == 0
    before = digest(out)
    r = run(*args)
    assert r.exit_code == 0 and "0 done, 3 skipped" in r.output and "skip:" in r.output
    r = run(*args, "--overwrite")
    assert "3 done, 0 skipped" in r.output and digest(out) == before


def test_bad_files_are_reported_and_the_batch_goes_on(photos, tmp_path):
    (photos / "empty.png").write_bytes(b"")
    good = (DATA / "srgb" / "coffee.png").read_bytes()
    (photos / "truncated.png").write_bytes(good[: len(good) // 3])
    (photos / "text.jpg").write_text("hello")
    shutil.copy(DATA / "raw" / "canon_eos60d_mlv.dng", photos / "raw.dng")
    out = tmp_path / "out"
    r = run(
        "unprocess",
        photos,
        photos / "raw.dng",
        tmp_path / "missing.png",
        "-o",
        out,
        "-p",
        "sony_a7s2",
        "--iso",
        400,
    )
    assert r.exit_code == 1
    errors = [line for line in r.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 5, r.output
    for name in ("empty.png", "truncated.png", "text.jpg", "raw.dng", "missing.png"):
        assert sum(name in e for e in errors) == 1
    assert "0 bytes" in r.output and "camera raw" in r.output
    assert "Traceback" not in r.output
    assert "3 done, 0 skipped, 5 failed" in r.output
    leftovers = [p.name for p in out.rglob("*") if ".tmp" in p.name or p.name.startswith(".")]
    assert leftovers == []
    assert not (out / "truncated.dng").exists() and not (out / "empty.json").exists()
    assert (photos / "empty.png").read_bytes() == b""  # inputs untouched


def test_debug_shows_tracebacks(photos, tmp_path):
    (photos / "empty.png").write_bytes(b"")
    r = run(
        "--debug",
        "unprocess",
        photos / "empty.png",
        "-o",
        tmp_path / "o",
        "-p",
        "sony_a7s2",
        "--iso",
        100,
    )
    assert r.exit_code == 1 and "Traceback" in r.output


def test_usage_errors_exit_2(photos, tmp_path):
    out = tmp_path / "out"
    r = run("unprocess", photos, "-o", out, "-p", "sony_a7s2")
    assert r.exit_code == 2 and "no ISO given: add --iso N" in r.output
    r = run("unprocess", photos, "-o", out, "-p", "nikon_d850", "--iso", 51200)
    assert r.exit_code == 2 and "outside the range" in r.output
    r = run("unprocess", photos, "-o", out, "-p", "no_such_camera", "--iso", 100)
    assert r.exit_code == 2 and "bundled:" in r.output
    bad = tmp_path / "bad.json"
    profile = json.loads((ROOT / "rawsim/cameras/sensor_profiles/sony_a7s2.json").read_text())
    profile["white_level"] = "lots"
    bad.write_text(json.dumps(profile))
    r = run("unprocess", photos, "-o", out, "-p", bad, "--iso", 100)
    assert r.exit_code == 2 and str(bad) in r.output and "'white_level'" in r.output
    r = run("unprocess", tmp_path / "nothing", "-o", out, "-p", "sony_a7s2", "--iso", 100)
    assert r.exit_code == 2 and "nothing: no such folder" in r.output
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("x")
    r = run("unprocess", tmp_path / "empty", "-o", out, "-p", "sony_a7s2", "--iso", 100)
    assert r.exit_code == 2 and "no input images in" in r.output and ".txt ×1" in r.output
    blocked = tmp_path / "a_file"
    blocked.write_text("x")
    r = run("unprocess", photos, "-o", blocked / "out", "-p", "sony_a7s2", "--iso", 100)
    assert r.exit_code == 2 and r.output.count("cannot write to") == 1, r.output
    assert "a_file is a file, not a folder: give another --output" in r.output
    r = run("unprocess", photos, "-o", out, "-p", "sony_a7s2", "--iso", 100, "--transfer", "pq")
    assert r.exit_code == 2 and "transfer" in r.output
    assert not out.exists()


def test_same_seed_gives_identical_files_for_any_jobs_order_and_split(photos, tmp_path):
    common = (
        "-p",
        "sony_a7s2",
        "--iso-range",
        100,
        6400,
        "--randomize",
        "--clean",
        "--format",
        "both",
        "--seed",
        11,
    )
    a, b, c, d = (tmp_path / n for n in "abcd")
    assert run("unprocess", photos, "-o", a, *common, "--jobs", 1).exit_code == 0
    assert run("unprocess", photos, "-o", b, *common, "--jobs", 2).exit_code == 0
    assert digest(a) == digest(b)
    # Another order of the same inputs, given as files relative to the same root.
    files = [photos / "sub" / "figure.tif", photos / "rocket.jpg", photos / "chelsea.png"]
    for shard in ("2/2", "1/2"):
        assert run("unprocess", photos, "-o", c, *common, "--shard", shard).exit_code == 0
    assert digest(c) == digest(a)
    assert run("unprocess", *files, "-o", d, *common).exit_code == 0
    assert digest(d)["rocket.dng"] == digest(a)["rocket.dng"]
    other = tmp_path / "e"
    assert run("unprocess", photos, "-o", other, *common[:-1], 12).exit_code == 0
    assert digest(other)["rocket.dng"] != digest(a)["rocket.dng"]


def test_randomize_samples_brooks_ranges_per_file(photos, tmp_path):
    out = tmp_path / "out"
    r = run(
        "unprocess", photos, "-o", out, "-p", "sony_a7s2", "--iso-range", 200, 3200, "--randomize"
    )
    assert r.exit_code == 0
    metas = [json.loads(p.read_text()) for p in sorted(out.rglob("*.json"))]
    gains = {tuple(m["params"]["wb_gains"]) for m in metas}
    assert len(gains) == 3
    for m in metas:
        red, green, blue = m["params"]["wb_gains"]
        assert 1.9 <= red <= 2.4 and green == 1 and 1.5 <= blue <= 1.9
        assert 200 <= m["params"]["iso"] <= 3200
        assert m["baseline_exposure"] == pytest.approx(np.log2(m["params"]["brightness"]))


def _write_image(path, pixels, fmt, **attrs):
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    for k, v in attrs.items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(pixels)
    out.close()


def test_input_kinds(tmp_path):
    rng = np.random.default_rng(0)
    src = tmp_path / "in"
    src.mkdir()
    _write_image(src / "rgba.png", (rng.random((31, 40, 4)) * 255).astype(np.uint8), oiio.UINT8)
    _write_image(src / "grey.png", (rng.random((20, 22, 1)) * 65535).astype(np.uint16), oiio.UINT16)
    _write_image(
        src / "tiled.exr",
        rng.random((64, 48, 3)).astype(np.float16),
        oiio.HALF,
        tile_width=16,
        tile_height=16,
    )
    _write_image(src / "sky.hdr", (rng.random((24, 26, 3)) * 4).astype(np.float32), oiio.FLOAT)
    _write_image(
        src / "grey_alpha.png", (rng.random((22, 24, 2)) * 255).astype(np.uint8), oiio.UINT8
    )
    _write_image(
        src / "rotated.jpg",
        (rng.random((32, 48, 3)) * 255).astype(np.uint8),
        oiio.UINT8,
        Orientation=6,
    )
    out = tmp_path / "out"
    r = run("unprocess", src, "-o", out, "-p", "canon_eos_70d", "--iso", 3200)
    assert r.exit_code == 0, r.output
    rgba = json.loads((out / "rgba.json").read_text())
    assert rgba["dropped_channels"] == ["A"] and rgba["height"] == 30
    assert json.loads((out / "tiled.json").read_text())["input_kind"] == "scene-linear"
    assert json.loads((out / "grey.json").read_text())["code_max"] == 65535
    assert json.loads((out / "sky.json").read_text())["input_kind"] == "scene-linear"
    assert json.loads((out / "grey_alpha.json").read_text())["dropped_channels"] == ["A"]
    with rawpy.imread(str(out / "rotated.dng")) as raw:
        assert raw.sizes.flip != 0  # orientation passed through to the DNG


def test_profiles_commands():
    r = run("profiles", "list")
    assert r.exit_code == 0 and "sony_a7s2" in r.output and "nikon_d850" in r.output
    rows = json.loads(run("profiles", "list", "--json").output)
    assert {row["name"] for row in rows} >= {"sony_a7s2", "nikon_d850", "canon_eos_70d"}
    shown = json.loads(run("profiles", "show", "sony_a7s2", "--iso", 1600, "--json").output)
    assert shown["K"] == pytest.approx(1.52543)
    assert shown["models"]["poisson-gaussian"]["read_sigma_dn"] == pytest.approx(6.30)
    assert shown["tukey_lambda"] == pytest.approx(
        load_profile("sony_a7s2").noise.tukey_lambda(1.52543)
    )
    assert shown["read_std_dn"] == pytest.approx(6.30)  # the default model's read std
    physics = shown["models"]["physics"]  # the Tukey scale is named apart from the std
    assert physics["tukey_scale_dn"] == shown["tukey_scale_dn"] < physics["read_std_dn"]
    assert "read_sigma_dn" not in physics
    assert "source[noise.gain]" in run("profiles", "show", "nikon_d850").output
    assert run("profiles", "show", "nope").exit_code == 2


def test_json_records_on_stdout(photos, tmp_path):
    r = CliRunner().invoke(
        cli,
        [
            "unprocess",
            str(photos / "rocket.jpg"),
            "-o",
            str(tmp_path / "o"),
            "-p",
            "sony_a7s2",
            "--iso",
            "100",
            "--json",
        ],
    )
    records = [json.loads(line) for line in r.stdout.splitlines() if line.startswith("{")]
    assert records and records[0]["status"] == "done"
    record = records[0]  # the file, its outputs, and what was drawn for it
    assert record["params"]["iso"] == 100 and record["file_seed"] and record["noise"]
    assert record["warnings"] == [] and record["outputs"]["dng"].endswith("rocket.dng")


def test_cli_choices_match_the_core():
    # The CLI lists them literally so that its --help needs no torch import.
    from rawsim.isp.tone import TONE_CURVES
    from rawsim.noise.models import NOISE_MODELS
    from rawsim_cli import unprocess

    assert set(unprocess.TONES) == set(TONE_CURVES)
    assert set(unprocess.NOISES) == set(NOISE_MODELS)


def test_output_flags_after_the_subcommand_and_friendly_options(tmp_path):
    raws = DATA / "raw" / "canon_eos60d_mlv.dng"
    r = run("process", raws, "-o", tmp_path / "a", "--format", "TIF", "-v")
    assert r.exit_code == 0 and "done: " in r.output, r.output  # -v after the command
    assert (tmp_path / "a" / "canon_eos60d_mlv.tif").is_file()  # tif, any case
    r = run("process", DATA / "raw" / "apple_quicktake150.qtk", "-o", tmp_path / "b", "-q")
    assert r.exit_code == 0 and "warning" not in r.output, r.output  # -q after the command
    r = run("process", raws, "-o", tmp_path / "c", "--format", "jpeg")
    assert r.exit_code == 0 and (tmp_path / "c" / "canon_eos60d_mlv.jpg").is_file()
    photo = DATA / "srgb" / "chelsea.png"
    r = run("unprocess", photo, "-o", tmp_path / "d", "-p", "sony_a7s9", "--iso", 100)
    assert r.exit_code == 2 and "did you mean sony_a7s2?" in r.output
    r = run("unprocess", photo, "-o", tmp_path / "d", "-p", "SONY_A7S2", "--iso", 1234.5)
    assert r.exit_code == 0, r.output
    assert "ISO 1234.5 is written as 1234 in the DNG" in r.output
    assert json.loads((tmp_path / "d" / "chelsea.json").read_text())["params"]["iso"] == 1234.5


def test_dng_takes_the_capture_time_of_the_photo(tmp_path):
    buf = oiio.ImageBuf(str(DATA / "srgb" / "rocket.jpg"))
    buf.specmod().attribute("Exif:DateTimeOriginal", "2021:06:05 14:03:09")
    assert buf.write(str(tmp_path / "shot.jpg"))
    for out in ("a", "b"):
        r = run(
            "unprocess",
            tmp_path / "shot.jpg",
            "-o",
            tmp_path / out,
            "-p",
            "sony_a7s2",
            "--iso",
            400,
        )
        assert r.exit_code == 0, r.output
    dng = tmp_path / "a" / "shot.dng"
    assert dng.read_bytes() == (tmp_path / "b" / "shot.dng").read_bytes()  # no time of writing
    with rawpy.imread(str(dng)) as raw:  # LibRaw reads it back
        when = raw.other.timestamp
    if not isinstance(when, datetime.datetime):
        when = datetime.datetime.fromtimestamp(when)
    assert when.strftime("%Y:%m:%d %H:%M:%S") == "2021:06:05 14:03:09"


def test_profiles_print_readably_and_flags_errors_speak_in_flags(tmp_path):
    r = run("profiles", "list")
    lines = r.output.splitlines()
    at = lines[0].index("cfa")  # every row's CFA starts under the header's
    assert all(line[at - 2 : at] == "  " and line[at] != " " for line in lines[1:])
    assert {line[at:].split()[0] for line in lines[1:]} >= {"RGGB", "BGGR", "XTRANS"}
    assert "100 only" in r.output and not re.search(r"(?<!\d)100–100(?!\d)", r.output)
    r = run("profiles", "show", "sony_a7s2")
    assert "{" not in r.output and "table by ISO (DN): 100 → 1.01" in r.output
    r = run("process", DATA / "raw" / "canon_eos60d_mlv.dng", "-o", tmp_path, "--wb", "foo")
    assert r.exit_code == 2 and "--wb 'foo': valid: camera, daylight, auto" in r.output
    assert "stage" not in r.output


@pytest.mark.slow
def test_slurm_array_shards_union_is_the_single_run(photos, tmp_path):
    """Three real processes with a Slurm array's variables (indices 4, 6, 8: --array=4-8:2)
    and --shard auto: each file is done once, and the union is the single run's bytes."""
    import os
    import subprocess
    import sys

    common = ["-p", "sony_a7s2", "--iso", "800", "--seed", "5", "-q"]
    single = tmp_path / "single"
    assert run("unprocess", photos, "-o", single, *common).exit_code == 0
    shards = tmp_path / "shards"
    cli_command = [sys.executable, "-c", "from rawsim_cli.main import main; main()"]
    outputs = []
    for task in (4, 6, 8):
        env = {**os.environ, "SLURM_ARRAY_TASK_ID": str(task), "SLURM_ARRAY_TASK_MIN": "4"}
        env |= {"SLURM_ARRAY_TASK_STEP": "2", "SLURM_ARRAY_TASK_COUNT": "3"}
        before = set(digest(shards)) if shards.exists() else set()
        args = ["unprocess", str(photos), "-o", str(shards), *common, "--shard", "auto"]
        done = subprocess.run([*cli_command, *args], env=env, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        outputs.append(set(digest(shards)) - before)
    assert all(outputs) and sum(map(len, outputs)) == len(set().union(*outputs))
    assert digest(shards) == digest(single)
    r = CliRunner().invoke(
        cli,
        ["unprocess", str(photos), "-o", str(tmp_path / "x"), *common, "--shard", "auto"],
        env={"SLURM_ARRAY_TASK_ID": None},
    )
    assert r.exit_code == 2 and "needs a Slurm array job" in r.output


def test_a_closed_pipe_stops_quietly():
    """`rawsim info … | head -1`: the reader of stdout leaves; no internal error, 141."""
    proc = subprocess.Popen(
        ["rawsim", "info", str(DATA / "raw")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    proc.stdout.close()  # gone before anything is written: every write fails
    stderr = proc.stderr.read()
    assert proc.wait() == 141, stderr
    assert "internal error" not in stderr and "Traceback" not in stderr
