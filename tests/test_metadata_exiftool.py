"""ISO, exposure time, aperture, focal length and capture time as exiftool reads them,
against what ``rawsim info`` reports and what rendered outputs carry: every vendored
raw, Canon CRW files (built here: the CIFF records a Canon D30 writes), and a DNG
whose placeholders are zeros. Where exiftool has no value, rawsim has none either."""

import json
import struct
import subprocess
import time
from pathlib import Path

import exiv2
import numpy as np
import pytest
from click.testing import CliRunner

from rawsim.cfa import CFA
from rawsim.io import raw as raw_module
from rawsim.io.dng import DngInfo, write_dng
from rawsim.io.images import write_image
from rawsim.io.lensfun import raw_lens
from rawsim.io.metadata import PhotoMetadata, read_metadata
from rawsim.io.raw import read_raw
from rawsim_cli.main import cli
from tests.conftest import DATA, require_tool

RAWS = sorted((DATA / "raw").iterdir())
#: exiftool's tag → (rawsim's EXIF key, the name ``rawsim info`` shows it under).
FIELDS = {
    "ISO": ("Exif.Photo.ISOSpeedRatings", "ISOSpeedRatings"),
    "ExposureTime": ("Exif.Photo.ExposureTime", "ExposureTime"),
    "FNumber": ("Exif.Photo.FNumber", "FNumber"),
    "FocalLength": ("Exif.Photo.FocalLength", "FocalLength"),
    "DateTimeOriginal": ("Exif.Photo.DateTimeOriginal", "DateTimeOriginal"),
}
#: The same fields as exiftool names them in an OpenEXR header.
EXR_NAMES = {
    "ISO": "ISO",
    "ExposureTime": "ExposureTime",
    "FNumber": "Aperture",
    "FocalLength": "NominalFocalLength",
    "DateTimeOriginal": "DateTimeOriginal",
}


def exiftool(*paths, tags=(*FIELDS, "ModifyDate")) -> dict[str, dict]:
    """exiftool's numeric values (-n) of ``tags`` for each path (its name → tags)."""
    out = subprocess.run(
        [require_tool("exiftool"), "-j", "-n", *(f"-{t}" for t in tags), *map(str, paths)],
        capture_output=True,
        text=True,
        check=True,
    )
    return {Path(r["SourceFile"]).name: r for r in json.loads(out.stdout)}


def expected(tags: dict) -> dict:
    """The five fields of exiftool's reading of a raw, a placeholder 0 taken as none; the
    capture time is DateTimeOriginal, else IFD0's DateTime (ModifyDate), which raws
    without the EXIF tag (Kodak DC50, the 60D's MLV DNG) record it in."""
    out = {k: tags[k] for k in FIELDS if k in tags and tags[k] not in (0, "0")}
    if "DateTimeOriginal" not in out and tags.get("ModifyDate"):
        out["DateTimeOriginal"] = tags["ModifyDate"]
    return out


def number(text: str) -> float:
    """A value as exiv2 prints it for ``rawsim info`` ("1/60 s", "F5.6", "65.0 mm") or as
    EXIF text ("56/10")."""
    text = text.removeprefix("F").removesuffix(" s").removesuffix(" mm").strip()
    head, _, tail = text.partition("/")
    return float(head) / float(tail) if tail else float(head)


def agrees(ours: dict, theirs: dict, what: str) -> None:
    """Same fields present; numbers within 0.1 % (exiftool's values computed from Canon's
    codes: within the rounding a camera's EXIF applies, 1 %); the same capture time."""
    assert set(ours) == set(theirs), what
    for key, value in theirs.items():
        if key == "DateTimeOriginal":
            assert str(ours[key])[:19] == value[:19], (what, key)
        else:
            assert float(ours[key]) == pytest.approx(float(value), rel=1e-2), (what, key)
            assert float(ours[key]) > 0, (what, key)


# ------------------------------------------------------------------ vendored raws
@pytest.fixture(scope="module")
def vendored_tags():
    return exiftool(*RAWS)


@pytest.mark.parametrize("path", RAWS, ids=lambda p: p.name)
def test_info_reports_what_exiftool_reads(path, vendored_tags):
    theirs = expected(vendored_tags[path.name])
    done = CliRunner().invoke(cli, ["info", "--json", str(path)])
    assert done.exit_code == 0, done.output
    record = json.loads(done.output)
    shown = record["metadata"]
    ours = {}
    for tag, (_, name) in FIELDS.items():
        if name in shown:
            ours[tag] = shown[name] if tag == "DateTimeOriginal" else number(shown[name])
    agrees(ours, theirs, path.name)
    # LibRaw's ISO: none where it read none (never a 0); the file's where it has one
    assert record["iso"] != 0
    if "ISO" in theirs:
        assert record["iso"] == theirs["ISO"]


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["jpg", "tiff", "png", "exr"])
def test_renders_carry_what_exiftool_reads(fmt, vendored_tags, tmp_path):
    """Every vendored raw rendered by ``rawsim process``: its output, read by exiftool,
    has the raw's fields as exiftool reads them, and none that the raw lacks."""
    done = CliRunner().invoke(
        cli, ["process", str(DATA / "raw"), "-o", str(tmp_path), "--format", fmt]
    )
    assert done.exit_code == 0, done.output
    names = EXR_NAMES if fmt == "exr" else {k: k for k in FIELDS}
    suffix = {"jpg": ".jpg", "tiff": ".tif", "png": ".png", "exr": ".exr"}[fmt]
    outputs = {p.stem: p for p in tmp_path.iterdir() if p.suffix == suffix}
    assert set(outputs) == {p.stem for p in RAWS}
    read = exiftool(*outputs.values(), tags=names.values())
    for raw in RAWS:
        tags = read[outputs[raw.stem].name]
        ours = {field: tags[name] for field, name in names.items() if name in tags}
        agrees(ours, expected(vendored_tags[raw.name]), f"{raw.name} → {fmt}")


# ------------------------------------------------------------------ Canon CRW
def _heap(records) -> bytes:
    """A CIFF heap: the records' values, then their table (count, then tag, size and
    offset a record), then the table's offset."""
    body, table = b"", []
    for tag, value in records:
        table.append(struct.pack("<HII", tag, len(value), len(body)))
        body += value + b"\0" * (len(value) % 2)
    return body + struct.pack("<H", len(table)) + b"".join(table) + struct.pack("<I", len(body))


def _canon_array(values: dict, n: int) -> bytes:
    """A Canon maker-note array of ``n`` int16: element 0 its size in bytes."""
    out = [0] * n
    out[0] = 2 * n
    for i, v in values.items():
        out[i] = v
    return struct.pack(f"<{n}h", *out)


def make_crw(path, shot: dict, camera_iso: int, focal: int, when: int) -> Path:
    """A CRW file's metadata as a Canon EOS D30 records it (CIFF: MakeModel, TimeStamp,
    ImageInfo, and ShotInfo, CameraSettings and FocalLength in ExifInformation), no
    image. ``shot``: ShotInfo element → int16 code (2 BaseISO, 1 AutoISO, 21 FNumber,
    22 ExposureTime; Canon's 1/32 EV codes); ``camera_iso``: CameraSettings' ISO code."""
    exif = _heap(
        [
            (0x102A, _canon_array(shot, 30)),  # ShotInfo
            (0x102D, _canon_array({16: camera_iso, 25: 1}, 40)),  # CameraSettings, FocalUnits
            (0x1029, struct.pack("<4h", 1, focal, 0, 0)),  # FocalType, FocalLength
        ]
    )
    props = _heap(
        [
            (0x2807, _heap([(0x080A, b"Canon\0Canon EOS D30\0")])),
            (0x180E, struct.pack("<IiI", when, 0, 0)),  # seconds of the camera's clock
            (0x1810, struct.pack("<IIfiiii", 2160, 1440, 1.0, 0, 8, 8, 1)),
            (0x300B, exif),
        ]
    )
    head = b"II" + struct.pack("<I", 26) + b"HEAPCCDR" + struct.pack("<III", 0x10002, 0, 0)
    path.write_bytes(head + _heap([(0x300A, props)]))
    return path


#: D30 shots: 5 s at f/5.6 ISO 100 (its exposure code negative: longer than 1 s);
#: Tv 8 (1/256 s, as exiftool gives it), Auto ISO (BaseISO 100 × AutoISO 200 % = 200),
#: no aperture recorded;
#: a code of 0: 1 s in a CRW.
CRWS = {
    "five_seconds": dict(shot={2: 160, 21: 160, 22: -76}, camera_iso=17, focal=50),
    "auto_iso": dict(shot={1: 32, 2: 160, 21: 0, 22: 256}, camera_iso=15, focal=35),
    "one_second": dict(shot={2: 192, 21: 192, 22: 0}, camera_iso=18, focal=0),
}
WHEN = 1017829200  # 2002-04-03 10:20:00 on the camera's clock


@pytest.fixture
def crws(tmp_path):
    return {name: make_crw(tmp_path / f"{name}.crw", **kw, when=WHEN) for name, kw in CRWS.items()}


def _read_in(tz: str, path) -> PhotoMetadata:
    """``read_metadata`` on a machine in time zone ``tz``."""
    import os

    saved = os.environ.get("TZ")
    os.environ["TZ"] = tz
    time.tzset()
    try:
        return read_metadata(path)
    finally:
        if saved is None:
            del os.environ["TZ"]
        else:
            os.environ["TZ"] = saved
        time.tzset()


def test_crw_fields_are_exiftools(crws):
    """ISO (CameraISO, or BaseISO × AutoISO for Auto), exposure times longer than 1 s,
    no made-up f/1 for an unrecorded aperture, the focal length, and the capture time
    whatever the reading machine's time zone."""
    theirs = exiftool(*crws.values())
    assert theirs["five_seconds.crw"]["ExposureTime"] == pytest.approx(5.04, abs=0.01)
    assert theirs["auto_iso.crw"]["ISO"] == 200 and "FNumber" not in theirs["auto_iso.crw"]
    assert theirs["one_second.crw"]["ExposureTime"] == 1
    for name, path in crws.items():
        for tz in ("UTC", "America/New_York", "Asia/Tokyo"):
            meta = _read_in(tz, path)
            ours = {
                tag: meta.get(key) if tag == "DateTimeOriginal" else number(meta.get(key))
                for tag, (key, _) in FIELDS.items()
                if meta.get(key) is not None
            }
            agrees(ours, expected(theirs[path.name]), f"{name} in {tz}")
    meta = read_metadata(crws["five_seconds"])
    assert meta.get("Exif.Photo.ExposureTime") == "5/1"  # as exiftool prints it: 5
    assert meta.get("Exif.Photo.FNumber") == "57/10"
    assert read_metadata(crws["auto_iso"]).get("Exif.Photo.ExposureTime") == "1/256"


@pytest.mark.parametrize("fmt", ["jpg", "tiff", "png", "exr"])
def test_crw_fields_reach_every_output(crws, tmp_path, fmt):
    """A CRW's metadata written as ``rawsim process`` writes it (rawsim.io.images),
    read back by exiftool: the CRW's fields as exiftool reads them."""
    pixels = np.full((8, 12, 3), 128, np.uint8 if fmt != "exr" else np.float32)
    suffix = {"jpg": ".jpg", "tiff": ".tif", "png": ".png", "exr": ".exr"}[fmt]
    outputs = {}
    for name, path in crws.items():
        outputs[name] = tmp_path / f"{name}{suffix}"
        write_image(outputs[name], pixels, fmt, metadata=read_metadata(path))
    names = EXR_NAMES if fmt == "exr" else {k: k for k in FIELDS}
    read = exiftool(*outputs.values(), tags=names.values())
    sources = exiftool(*crws.values())
    for name, out in outputs.items():
        tags = read[out.name]
        ours = {field: tags[n] for field, n in names.items() if n in tags}
        agrees(ours, expected(sources[f"{name}.crw"]), f"{name} → {fmt}")


# ------------------------------------------------------------------ placeholder zeros
PLACEHOLDERS = {
    "Exif.Photo.ExposureTime": "0/10",
    "Exif.Photo.FNumber": "0/100",
    "Exif.Photo.FocalLength": "0/10",
    "Exif.Photo.ISOSpeedRatings": "0",
    "Exif.Photo.FocalLengthIn35mmFilm": "0",
    "Exif.Photo.SubjectDistance": "0/1",
    # zeros that are values: no flash, no exposure bias
    "Exif.Photo.Flash": "0",
    "Exif.Photo.ExposureBiasValue": "0/3",
    "Exif.Photo.DateTimeOriginal": "2024:01:02 03:04:05",
}


@pytest.fixture
def zeros_dng(tmp_path):
    """A DNG (ISO 0 in its TIFF/EP tag too) whose exposure, aperture, focal lengths,
    ISO and distance are placeholder zeros."""
    path = tmp_path / "zeros.dng"
    mosaic = (512 + np.random.default_rng(1).random((32, 48)) * 4000).astype(np.uint16)
    info = DngInfo(CFA("RGGB"), 512, 16383, np.eye(3).tolist(), (1, 1, 1), "Acme", "Z", "Z", 0)
    write_dng(path, mosaic, info)
    image = exiv2.ImageFactory.open(str(path))
    image.readMetadata()
    data = image.exifData()
    for key, value in PLACEHOLDERS.items():
        data[key] = value
    image.writeMetadata()
    return path


def test_placeholder_zeros_are_no_values(zeros_dng, tmp_path):
    source = exiftool(zeros_dng, tags=("ExposureTime", "FNumber", "FocalLength", "ISO"))
    assert source["zeros.dng"]["ExposureTime"] == 0 and source["zeros.dng"]["ISO"] == 0
    done = CliRunner().invoke(cli, ["info", "--json", str(zeros_dng)])
    assert done.exit_code == 0, done.output
    record = json.loads(done.output)
    assert record["iso"] is None
    shown = record["metadata"]
    for name in ("ExposureTime", "FNumber", "FocalLength", "ISOSpeedRatings"):
        assert name not in shown, name
    assert "FocalLengthIn35mmFilm" not in shown and "SubjectDistance" not in shown
    assert shown["Flash"] == "No flash" and shown["ExposureBiasValue"] == "0 EV"
    text = CliRunner().invoke(cli, ["info", str(zeros_dng)]).output
    assert "  iso " not in text and " 0 s" not in text and "F0" not in text
    done = CliRunner().invoke(cli, ["process", str(zeros_dng), "-o", str(tmp_path / "o")])
    assert done.exit_code == 0, done.output
    tags = ("ExposureTime", "FNumber", "FocalLength", "ISO", "FocalLengthIn35mmFormat")
    tags += ("SubjectDistance", "Flash", "ExposureCompensation", "DateTimeOriginal")
    (out,) = (tmp_path / "o").glob("zeros.*g")
    carried = exiftool(out, tags=tags)[out.name]
    assert carried.pop("SourceFile")
    assert carried == {
        "Flash": 0,
        "ExposureCompensation": 0,
        "DateTimeOriginal": "2024:01:02 03:04:05",
    }


# ------------------------------------------------------------------ info's wording
def test_info_names_the_camera_once():
    path = DATA / "raw" / "kodak_dc50_grbg.kdc"
    text = CliRunner().invoke(cli, ["info", str(path)]).output
    lines = [line.split()[0] for line in text.splitlines()[1:] if line.strip()]
    assert lines.count("make") == 1 and lines.count("model") == 1
    assert "Make" not in lines and "Model" not in lines
    assert "    FNumber                F6.2" in text  # under the metadata heading
    assert "linear DNG" not in text
    # no ISO in the file: LibRaw's figure for the camera, said to be that
    assert "iso                      84 (LibRaw's figure for this camera" in text


def test_a_raw_without_a_cfa_is_named_for_what_it_is(monkeypatch):
    dng = DATA / "raw" / "canon_eos6d_linear_raw_no_cfa.dng"
    assert "no CFA (a linear DNG): rendered as 3-channel linear data" in read_raw(dng).warnings
    # the same data from a file that is no DNG (old Kodaks LibRaw gives as full colour)
    facts = raw_module._tiff_facts(dng)
    assert facts.dng
    monkeypatch.setattr(
        raw_module,
        "_tiff_facts",
        lambda path: raw_module._TiffFacts(facts.make, facts.model, facts.cfa_rows, dng=False),
    )
    (note,) = [w for w in read_raw(dng).warnings if w.startswith("no CFA")]
    assert "DNG" not in note and "full-colour" in note


def test_lens_warnings_name_a_camera_without_its_make_naturally():
    """A raw whose file names no make: rawsim's "unknown" is no part of the name."""
    lens = (
        ("Exif.Photo.LensModel", "E PZ 16-50mm f/3.5-5.6 OSS"),
        ("Exif.Photo.FocalLength", "16/1"),
    )
    model = "Blackmagic Pocket Cinema Camera 4K"
    _, warnings = raw_lens("unknown", model, PhotoMetadata(lens))
    assert f"lensfun does not know the camera '{model}'" in warnings[0]
    _, warnings = raw_lens("unknown", model, PhotoMetadata())
    assert f"for the {model}:" in warnings[0]
    _, warnings = raw_lens("unknown", "unknown", PhotoMetadata(lens))
    assert "lensfun does not know the camera (the raw names none)" in warnings[0]
    assert not any("unknown" in w for w in warnings)
