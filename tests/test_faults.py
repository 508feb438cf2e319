"""A fault campaign: both commands over a generated corpus of bad and odd inputs.

The corpus is made by :func:`image_corpus` and :func:`raw_corpus` from a few good
files (nothing is stored): truncated, bit-flipped, zero-byte, mislabelled, huge
declared sizes, 1×1, NaN/Inf, folders named like images, symlink loops, odd
names. Each command runs once over it, as a user would run it, in a subprocess:
no traceback, no hang, one line per failure naming its file, no temporary or
partial output left, every good file written, exit 1.
"""

from __future__ import annotations

import os
import random
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
import tifffile

from tests.conftest import DATA

GOOD, BAD, EITHER = "good", "bad", "either"


def _small(src: Path, dst: Path, width: int = 48, height: int = 32) -> bytes:
    buf = oiio.ImageBufAlgo.resize(oiio.ImageBuf(str(src)), roi=oiio.ROI(0, width, 0, height))
    assert buf.write(str(dst)), oiio.geterror()
    return dst.read_bytes()


def _png_header_size(data: bytes, width: int, height: int) -> bytes:
    """``data`` (a PNG) with its IHDR declaring width × height (CRC fixed)."""
    ihdr = bytearray(data[12:29])
    ihdr[4:12] = struct.pack(">II", width, height)
    return data[:12] + bytes(ihdr) + struct.pack(">I", zlib.crc32(ihdr)) + data[33:]


def _flipped(data: bytes, rng: random.Random, count: int) -> bytes:
    out = bytearray(data)
    for _ in range(count):
        at = rng.randrange(len(out))
        out[at] ^= 1 << rng.randrange(8)
    return bytes(out)


def image_corpus(folder: Path) -> dict[str, str]:
    """Write the images corpus into ``folder``: file name → good / bad / either."""
    rng = random.Random(7)
    folder.mkdir()
    work = folder.parent / "work"
    work.mkdir()
    good = {
        ".png": _small(DATA / "srgb" / "chelsea.png", work / "a.png"),
        ".jpg": _small(DATA / "srgb" / "rocket.jpg", work / "a.jpg"),
        ".tif": _small(DATA / "srgb16" / "painted_figure_16bit.tif", work / "a.tif"),
        ".exr": _small(DATA / "exr" / "img2601_float_zip.exr", work / "a.exr"),
        ".bmp": _small(DATA / "srgb" / "coffee.png", work / "a.bmp"),
    }
    expect: dict[str, str] = {}

    def put(name: str | bytes, data: bytes, kind: str) -> None:
        path = Path(os.fsdecode(os.path.join(os.fsencode(folder), os.fsencode(name))))
        path.write_bytes(data)
        expect[path.name] = kind

    for ext, data in good.items():
        kind = ext[1:]  # in the stem too: a.png and a.jpg would clash (tested elsewhere)
        put(f"good_{kind}{ext}", data, GOOD)
        for frac in (0.05, 0.3, 0.6, 0.9, 0.99):  # truncated
            put(f"trunc{int(frac * 100)}_{kind}{ext}", data[: int(len(data) * frac)], EITHER)
        for i in range(12):  # bit flips, from one to many
            put(f"flip{i}_{kind}{ext}", _flipped(data, rng, 1 + i * i), EITHER)
        put(f"zero_{kind}{ext}", b"", BAD)
        put(f"text_{kind}{ext}", b"just some text\n" * 20, BAD)
        for other in good:  # the content of another format under this extension
            if other != ext:
                put(f"{other[1:]}_as_{kind}{ext}", good[other], GOOD)
    put("huge.png", _png_header_size(good[".png"], 200_000, 200_000), BAD)
    put("wide.png", _png_header_size(good[".png"], 2**31 - 1, 1), BAD)
    for w, h in ((1, 1), (1, 2), (2, 1), (3, 3), (2, 2)):
        img = np.full((h, w, 3), 128, np.uint8)
        for ext in (".png", ".tif"):
            path = work / f"s{w}x{h}{ext}"
            assert oiio.ImageBuf(img).write(str(path))
            ok = GOOD if w > 1 and h > 1 else BAD
            put(f"small{w}x{h}_{ext[1:]}{ext}", path.read_bytes(), ok)
    for value, label in ((np.nan, "nan"), (np.inf, "inf"), (-np.inf, "neginf")):
        img = np.full((8, 8, 3), 0.5, np.float32)
        img[3, 4, 1] = value
        path = work / f"{label}.exr"
        assert oiio.ImageBuf(img).write(str(path))
        put(f"{label}.exr", path.read_bytes(), BAD)
        tifffile.imwrite(work / f"{label}.tif", img, photometric="rgb")
        put(f"{label}_tif.tif", (work / f"{label}.tif").read_bytes(), BAD)
    put("raw_as.png", (DATA / "raw" / "kodak_dc50_grbg.kdc").read_bytes(), BAD)
    put("dng_as.tif", (DATA / "raw" / "canon_eos60d_mlv.dng").read_bytes(), BAD)
    put("dng2_as.jpg", (DATA / "raw" / "synthetic_colorchecker_bggr.dng").read_bytes(), BAD)
    names = [
        b"caf\xe9.png",  # not UTF-8
        "new\nline.png",
        "tab\there.png",
        " leading space.png",
        "-leading-dash.png",
        "ünïcødé 写真.png",
        "a" * 245 + ".png",  # its output a…a.json is 250 bytes
        "quote'\"s.png",
        "semi;colon $HOME.png",
    ]
    for name in names:
        put(name, good[".png"], GOOD)
    put("b" * 251 + ".png", good[".png"], BAD)  # 255 bytes: no room for its outputs' names
    for name in ("dir.png", "dir2.jpg"):  # folders named like images, with a file inside
        (folder / name).mkdir()
        (folder / name / "inner.png").write_bytes(good[".png"])
        expect[f"{name}/inner.png"] = GOOD
    os.symlink("loop_b.png", folder / "loop_a.png")
    os.symlink("loop_a.png", folder / "loop_b.png")
    os.symlink("nowhere.png", folder / "dangling.png")
    os.symlink("good_png.png", folder / "link.png")
    expect |= {"loop_a.png": BAD, "loop_b.png": BAD, "dangling.png": BAD, "link.png": GOOD}
    (folder / "noext").write_bytes(good[".png"])  # not taken: no image extension
    (folder / "notes.txt").write_text("not an image\n")
    return expect


def raw_corpus(folder: Path) -> dict[str, str]:
    """Write the raws corpus into ``folder``: file name → good / bad / either."""
    rng = random.Random(11)
    folder.mkdir()
    expect: dict[str, str] = {}
    good = (DATA / "raw" / "synthetic_colorchecker_bggr.dng").read_bytes()

    def put(name: str, data: bytes, kind: str) -> None:
        (folder / name).write_bytes(data)
        expect[name] = kind

    put("good.dng", good, GOOD)
    put("good_kdc.kdc", (DATA / "raw" / "kodak_dc50_grbg.kdc").read_bytes(), GOOD)
    for frac in (0.001, 0.01, 0.05, 0.2, 0.5, 0.8, 0.95, 0.999):
        put(f"trunc{frac}.dng", good[: int(len(good) * frac)], EITHER)
    for i in range(30):
        put(f"flip{i}.dng", _flipped(good, rng, 1 + i * i), EITHER)
    for ext in (".dng", ".cr2", ".nef", ".crw", ".arw"):
        put(f"zero_{ext[1:]}{ext}", b"", BAD)
        put(f"text_{ext[1:]}{ext}", b"RAW? no.\n" * 50, BAD)
        put(f"png_as_{ext[1:]}{ext}", (DATA / "srgb" / "chelsea.png").read_bytes(), BAD)
    put("new\nline.dng", good, GOOD)
    put("a" * 240 + ".dng", good, GOOD)
    put("b" * 251 + ".dng", good, BAD)
    put("-dash.dng", good, GOOD)
    return expect


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    done = subprocess.run(
        [sys.executable, "-m", "rawsim_cli.main", *args],
        cwd=cwd,
        capture_output=True,
        timeout=600,
    )
    done.stderr_text = done.stderr.decode(errors="replace")
    return done


def _check(done, expect: dict[str, str], out: Path, suffixes: tuple[str, ...]) -> None:
    err = done.stderr_text
    assert done.returncode == 1, err[-3000:]
    assert "Traceback" not in err and "internal error" not in err, err[-3000:]
    lines = err.splitlines()
    for line in lines:  # every line is rawsim's, one message each
        assert re.match(r"^(error|warning|skip|rawsim|not taken): ", line), line
    failures = [line for line in lines if line.startswith("error: ")]
    summary = re.search(r"(\d+) done, (\d+) skipped, (\d+) failed", err)
    assert summary and int(summary[3]) == len(failures), err[-2000:]
    written = {p.relative_to(out) for p in out.rglob("*") if p.is_file()}
    assert not [p for p in written if p.name.startswith(".")], "temporary files left"
    for name, kind in expect.items():
        stem = Path(name).with_suffix("")
        stem = stem.with_name(("_" if stem.name.startswith(".") else "") + stem.name)
        names = {stem.with_name(stem.name + s) for s in suffixes}
        outputs = {p for p in written if p in names}
        shown = repr(name)[1:-1] if not name.isprintable() else name
        failed = any(shown.split("/")[-1] in line for line in failures)
        if kind == GOOD:
            assert outputs and not failed, f"{name!r} was not written: {err[-2000:]}"
        elif kind == BAD:
            assert failed and not outputs, f"{name!r} should fail alone: {outputs}"
        else:  # either way, whole
            assert failed != bool(outputs), f"{name!r}: failed={failed}, outputs={outputs}"
        assert not outputs or outputs == names, f"{name!r}: a partial set {outputs}"


@pytest.mark.slow
@pytest.mark.parametrize("jobs", ["2"])
def test_unprocess_fault_campaign(tmp_path, jobs):
    expect = image_corpus(tmp_path / "in")
    assert len(expect) >= 150
    out = tmp_path / "out"
    done = _run(
        ["unprocess", "in", "-o", "out", "-p", "sony_a7s2", "--iso", "800", "--jobs", jobs],
        tmp_path,
    )
    _check(done, expect, out, (".dng", ".json"))
    assert "not taken for their extension: 2 files" in done.stderr_text
    assert "clash" not in done.stderr_text


@pytest.mark.slow
def test_process_fault_campaign(tmp_path):
    expect = raw_corpus(tmp_path / "in")
    assert len(expect) >= 50
    done = _run(["process", "in", "-o", "out", "--format", "tiff", "--jobs", "2"], tmp_path)
    _check(done, expect, tmp_path / "out", (".tif", ".process.json"))
    assert "clash" not in done.stderr_text
    assert "it is a PNG image: use 'rawsim unprocess'" in done.stderr_text


def _outcome(path: Path) -> str:
    from rawsim.errors import RawsimError
    from rawsim.io.raw import read_raw

    try:
        raw = read_raw(path)
    except RawsimError as err:
        return f"error: {err}"
    return f"{raw.data.shape} {hash(raw.data.tobytes())} {raw.white_level} {raw.warnings}"


def test_reading_a_raw_does_not_depend_on_the_files_read_before(tmp_path):
    """LibRaw state must not leak between files: each file's outcome (its data or its
    error) is the same whatever was read before it in the process."""
    raw_corpus(tmp_path / "in")
    files = sorted((tmp_path / "in").iterdir())
    forward = {p.name: _outcome(p) for p in files}
    backward = {p.name: _outcome(p) for p in reversed(files)}
    shuffled = list(files)
    random.Random(3).shuffle(shuffled)
    assert forward == backward == {p.name: _outcome(p) for p in shuffled}
