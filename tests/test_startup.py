"""A first hour without surprises: usage errors answered before anything heavy loads,
each on one line naming what was given, what is wrong and what to do; no output
folder for a run that writes nothing; the summary's wall time; X-Trans DNGs LibRaw
cannot render."""

import json
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

from rawsim_cli.main import cli
from tests.conftest import DATA, ROOT

#: Modules a usage error must not wait for.
HEAVY = ("torch", "numba", "rawpy", "OpenImageIO", "scipy", "matplotlib")


def rawsim(*args, cwd=None):
    """Run ``rawsim ARGS`` as a fresh process, as the installed script does, with
    ``-X importtime``: (exit code, the lines it printed, the modules it imported)."""
    code = "import sys; from rawsim_cli.main import main; sys.argv[0] = 'rawsim'; main()"
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code, *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
        timeout=120,
    )
    lines, modules = [], set()
    for line in (done.stdout + done.stderr).splitlines():
        if line.startswith("import time:"):
            modules.add(line.rsplit("|", 1)[1].strip())
        else:
            lines.append(line)
    return done.returncode, lines, modules


def error_line(lines):
    """The one message line of a usage error (click's ``Error: …``, or rawsim's own)."""
    messages = [line for line in lines if line.startswith(("Error:", "rawsim:"))]
    assert len(messages) == 1, lines
    assert not any("Traceback" in line for line in lines), lines
    return messages[0]


@pytest.fixture
def places(tmp_path):
    """An empty folder, a folder of one non-raw image, a plain file, a missing path."""
    (tmp_path / "empty").mkdir()
    (tmp_path / "one").mkdir()
    shutil.copy(DATA / "srgb" / "chelsea.png", tmp_path / "one" / "a.png")
    (tmp_path / "afile").write_text("x")
    return tmp_path


# (arguments with {t} for the temporary folder, what the message must name, its reason,
# its fix). Every case is a mistake a new user makes in the first hour.
USAGE_ERRORS = {
    "unprocess --iso -5": (
        "unprocess {t}/one -o {t}/out -p sony_a7s2 --iso -5",
        ["'--iso'", "-5"],
        "must be > 0",
        "give a positive ISO (profile 'sony_a7s2' takes 100",
    ),
    "unprocess without --iso": (
        "unprocess {t}/one -o {t}/out -p sony_a7s2",
        ["--iso"],
        "no ISO given",
        "add --iso N or --iso-range MIN MAX (sony_a7s2 takes ISO 100",
    ),
    "unprocess ISO out of range": (
        "unprocess {t}/one -o {t}/out -p nikon_d850 --iso 1e7",
        ["'--iso'", "nikon_d850"],
        "outside the range",
        "give an ISO within it",
    ),
    "unprocess unknown profile": (
        "unprocess {t}/one -o {t}/out -p sony_a7s9 --iso 800",
        ["'--profile'", "'sony_a7s9'"],
        "unknown sensor profile",
        "did you mean sony_a7s2?",
    ),
    "unprocess missing profile file": (
        "unprocess {t}/one -o {t}/out -p {t}/cam.json --iso 800",
        ["'--profile'", "{t}/cam.json"],
        "profile file not found",
        "check the path",
    ),
    "unprocess missing file": (
        "unprocess {t}/nope.png -o {t}/out -p sony_a7s2 --iso 800",
        ["{t}/nope.png"],
        "no such file",
        "check the path",
    ),
    "unprocess empty folder": (
        "unprocess {t}/empty -o {t}/out -p sony_a7s2 --iso 800",
        ["{t}/empty"],
        "it is empty",
        "give folders of .png",
    ),
    "unprocess output is a file": (
        "unprocess {t}/one -o {t}/afile -p sony_a7s2 --iso 800",
        ["'--output'", "{t}/afile"],
        "is a file, not a folder",
        "give a folder",
    ),
    "unprocess output below a file": (
        "unprocess {t}/one -o {t}/afile/out -p sony_a7s2 --iso 800",
        ["{t}/afile/out"],
        "{t}/afile is a file, not a folder",
        "give another --output",
    ),
    "unprocess bad --cfa": (
        "unprocess {t}/one -o {t}/out -p sony_a7s2 --iso 800 --cfa RGBW",
        ["'--cfa'", "RGBW"],
        "",
        "",
    ),
    "unprocess bad --shard": (
        "unprocess {t}/one -o {t}/out -p sony_a7s2 --iso 800 --shard 3/2",
        ["'--shard'", "3/2"],
        "1 ≤ K ≤ N",
        "",
    ),
    "process missing file": (
        "process {t}/nope.dng -o {t}/out",
        ["{t}/nope.dng"],
        "no such file",
        "check the path",
    ),
    "process empty folder": (
        "process {t}/empty -o {t}/out",
        ["{t}/empty"],
        "it is empty",
        "give folders of .3fr",
    ),
    "process folder of images": (
        "process {t}/one -o {t}/out",
        ["{t}/one"],
        "found only 1 file (.png ×1)",
        "name a file to take it whatever its extension",
    ),
    "process output is a file": (
        "process {t}/one -o {t}/afile",
        ["'--output'", "{t}/afile"],
        "is a file, not a folder",
        "give a folder",
    ),
    "process missing config": (
        "process {t}/one -o {t}/out -c {t}/isp.toml",
        ["'--config'", "{t}/isp.toml"],
        "no such file",
        "check the path",
    ),
    "calibrate missing raw": (
        "calibrate {t}/nope.dng -o {t}/cam.json",
        ["{t}/nope.dng"],
        "no such file",
        "check the path",
    ),
    "calibrate empty folder": (
        "calibrate {t}/empty -o {t}/cam.json",
        ["RAWS", "{t}/empty"],
        "no raw files",
        "give raw files",
    ),
    "calibrate output is a folder": (
        "calibrate {t}/one -o {t}/empty",
        ["'--output'", "{t}/empty"],
        "is a folder",
        "give a file name, e.g. {t}/empty/mycam.json",
    ),
    "calibrate dark shading without darks": (
        "calibrate {t}/one -o {t}/cam.json --dark-shading",
        ["--dark-shading"],
        "needs dark frames",
        "add --dark FOLDER",
    ),
    "events missing frames": (
        "events {t}/nope -o {t}/out --fps 30",
        ["{t}/nope"],
        "no such folder",
        "check the path",
    ),
    "events one frame": (
        "events {t}/one -o {t}/out --fps 30",
        ["{t}/one"],
        "1 frame found, events need at least 2",
        "give a folder of frames",
    ),
    "events output is a file": (
        "events {t}/one -o {t}/afile --fps 30",
        ["'--output'", "{t}/afile"],
        "is a file, not a folder",
        "give a folder",
    ),
    "isp check missing file": (
        "isp check {t}/isp.toml",
        ["{t}/isp.toml"],
        "no such file",
        "check the path",
    ),
    "isp check a folder": (
        "isp check {t}/empty",
        ["{t}/empty"],
        "is a folder",
        "give the file in it",
    ),
    "profiles show unknown": (
        "profiles show nikon_d86",
        ["'nikon_d86'"],
        "unknown sensor profile",
        "did you mean nikon_d850?",
    ),
    "profiles show missing file": (
        "profiles show {t}/cam.json",
        ["{t}/cam.json"],
        "profile file not found",
        "check the path",
    ),
    "profiles show plot into a folder": (
        "profiles show sony_a7s2 --plot {t}/empty",
        ["'--plot'", "{t}/empty"],
        "is a folder",
        "give a file name, e.g. {t}/empty/noise.png",
    ),
}


@pytest.mark.parametrize("case", sorted(USAGE_ERRORS))
def test_usage_errors_answer_before_anything_heavy_loads(case, places):
    """Exit 2, one message line naming the option or file, the reason and the fix, and
    none of torch, numba, rawpy, OpenImageIO, SciPy, matplotlib imported; no output
    folder made."""
    args, names, reason, fix = USAGE_ERRORS[case]
    t = str(places)
    code, lines, modules = rawsim(*args.format(t=t).split())
    message = error_line(lines)
    assert code == 2, lines
    for part in (*names, reason, fix):
        assert part.format(t=t) in message, (part, message)
    assert not modules & set(HEAVY), sorted(modules & set(HEAVY))
    assert not (places / "out").exists()


def test_profiles_list_and_show_need_no_torch():
    code, lines, modules = rawsim("profiles", "list")
    assert code == 0 and any(line.startswith("fujifilm_xt3 ") for line in lines), lines
    assert not modules & set(HEAVY), sorted(modules & set(HEAVY))
    code, lines, modules = rawsim("profiles", "show", "sony_a7s2", "--iso", "3200")
    assert code == 0 and any("at ISO 3200 (physics)" in line for line in lines), lines
    assert not modules & set(HEAVY), sorted(modules & set(HEAVY))


def test_help_texts_name_every_layout():
    from rawsim_cli.main import COMMANDS

    assert "X-Trans" in COMMANDS["unprocess"][1]
    out = CliRunner().invoke(cli, ["--help"]).output
    assert "Bayer, X-Trans" in out
    out = CliRunner().invoke(cli, ["unprocess", "--help"]).output
    assert "XTRANS" in out and "made when the first output" in out


def test_a_run_that_writes_nothing_makes_no_output_folder(tmp_path):
    bad = tmp_path / "in" / "broken.png"
    bad.parent.mkdir()
    bad.write_bytes(b"not a png")
    out = tmp_path / "out" / "deeper"
    args = ["unprocess", bad, "-o", out, "-p", "sony_a7s2", "--iso", 100]
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code == 1 and "1 failed" in r.output, r.output
    assert not (tmp_path / "out").exists()


def test_a_failed_write_removes_the_folders_it_made(tmp_path):
    from rawsim.io import outputs
    from rawsim.io.atomic import atomic_output

    (tmp_path / "kept").mkdir()
    with pytest.raises(RuntimeError), atomic_output(tmp_path / "kept" / "a" / "b" / "x.txt"):
        raise RuntimeError("the writer failed")
    assert [p.name for p in tmp_path.iterdir()] == ["kept"]
    assert list((tmp_path / "kept").iterdir()) == []
    target = {"dng": tmp_path / "o" / "s" / "x.dng", "json": tmp_path / "o" / "s" / "x.json"}
    with pytest.raises(RuntimeError), outputs.atomic_outputs(target) as tmp:
        tmp["dng"].write_bytes(b"x")
        raise RuntimeError("the writer failed")
    assert not (tmp_path / "o").exists()
    # A folder another output is in stays.
    (tmp_path / "kept" / "other.txt").write_text("x")
    with pytest.raises(RuntimeError), atomic_output(tmp_path / "kept" / "y.txt"):
        raise RuntimeError("the writer failed")
    assert [p.name for p in (tmp_path / "kept").iterdir()] == ["other.txt"]
    with atomic_output(tmp_path / "new" / "z.txt") as tmp:  # success: the folder stays
        tmp.write_text("z")
    assert (tmp_path / "new" / "z.txt").read_text() == "z"


def test_the_summary_counts_from_the_start(tmp_path):
    """All skipped: the summary's time is the command's, not the batch loop's 0.0 s."""
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(DATA / "srgb" / "chelsea.png", src / "a.png")
    out = tmp_path / "out"
    args = [str(a) for a in ("unprocess", src, "-o", out, "-p", "sony_a7s2", "--iso", 100)]
    assert CliRunner().invoke(cli, args).exit_code == 0
    r = CliRunner().invoke(cli, args, obj={"started": time.monotonic() - 42.0})
    assert r.exit_code == 0 and "0 done, 1 skipped" in r.output, r.output
    seconds = float(re.search(r"in ([0-9.]+) s", r.output)[1])
    assert 42.0 <= seconds < 100, r.output


def test_xtrans_dngs_below_libraws_minimum_are_warned_about(tmp_path):
    """LibRaw's X-Trans interpolation refuses images under 512 rows or columns: the
    minimum rawsim.pipelines.unprocess.LIBRAW_XTRANS_MIN states, checked against rawpy."""
    import rawpy
    from PIL import Image

    from rawsim.pipelines.unprocess import LIBRAW_XTRANS_MIN

    src = tmp_path / "in"
    src.mkdir()
    low = LIBRAW_XTRANS_MIN - 6  # one X-Trans period less
    sizes = {"small_rows": (900, low), "small_cols": (low, 900), "least": (512, 512)}
    rng = np.random.default_rng(1)
    for name, (w, h) in sizes.items():
        pixels = (rng.random((h, w, 3)) * 180 + 30).astype(np.uint8)
        Image.fromarray(pixels).save(src / f"{name}.png")
    out = tmp_path / "out"
    args = ["unprocess", src, "-o", out, "-p", "fujifilm_xt3", "--iso", 800]
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    warned = [line for line in r.output.splitlines() if "LibRaw (rawpy) cannot demosaic" in line]
    assert len(warned) == 2, r.output
    assert all(("small_rows" in w or "small_cols" in w) and "Bayer profile" in w for w in warned)
    for name in sizes:
        with rawpy.imread(str(out / f"{name}.dng")) as raw:
            assert raw.raw_pattern.shape == (6, 6)
            try:
                raw.postprocess()
                rendered = True
            except rawpy.LibRawIOError:
                rendered = False
        assert rendered == (name == "least"), name
        with rawpy.imread(str(out / f"{name}.dng")) as raw:  # as the warning says
            assert raw.postprocess(half_size=True).ndim == 3
    assert json.loads((out / "least.json").read_text())["width"] == 512
    sidecar = json.loads((out / "small_rows.json").read_text())  # recorded with the file
    assert any("LibRaw (rawpy) cannot demosaic" in w for w in sidecar["warnings"])
    assert not json.loads((out / "least.json").read_text())["warnings"]
