"""``rawsim process --format dng``: the raw's mosaic back as a raw, read by real readers
(rawpy/LibRaw, tifffile, exiftool) and editors (darktable-cli, rawtherapee-cli)."""

import json
import shutil
import subprocess

import numpy as np
import pytest
import rawpy
import tifffile
from click.testing import CliRunner

from rawsim_cli.main import cli
from tests.conftest import DATA, psnr, require_tool

#: The real raws of tests/data with a CFA (the LinearRaw DNG has none).
RAWS = [
    DATA / "raw" / "canon_eos60d_mlv.dng",
    DATA / "raw" / "kodak_dc50_grbg.kdc",
    DATA / "raw" / "apple_quicktake150.qtk",
    DATA / "raw" / "synthetic_colorchecker_bggr.dng",
    *sorted((DATA / "highlights").glob("*.dng")),
]
LINEAR = DATA / "raw" / "canon_eos6d_linear_raw_no_cfa.dng"


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def libraw_render(path) -> np.ndarray:
    """LibRaw's render with the file's white balance, bilinear, clipped highlights,
    linear 16-bit, unrotated, at the file's white level (no lowering of it to the
    data's maximum, a guess that reads a mosaic and camera RGB differently): (H, W,
    3) in [0, 1]."""
    with rawpy.imread(str(path)) as raw:
        rgb = raw.postprocess(
            adjust_maximum_thr=0.0,
            use_camera_wb=True,
            no_auto_bright=True,
            output_bps=16,
            gamma=(1, 1),
            user_flip=0,
            demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR,
            highlight_mode=rawpy.HighlightMode.Clip,
        )
    return rgb.astype(np.float64) / 65535


def block_means(a: np.ndarray, n: int = 16) -> np.ndarray:
    h, w = a.shape[0] // n * n, a.shape[1] // n * n
    return a[:h, :w].reshape(h // n, n, w // n, n, -1).mean((1, 3))


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Every raw of :data:`RAWS` as a mosaic DNG, no denoise: {source: (dng, sidecar)}."""
    out = tmp_path_factory.mktemp("dng")
    for src in RAWS:
        r = run("process", src, "-o", out, "--format", "dng")
        assert r.exit_code == 0, r.output
    return {
        src: (out / f"{src.stem}.dng", json.loads((out / f"{src.stem}.process.json").read_text()))
        for src in RAWS
    }


@pytest.mark.parametrize("src", RAWS, ids=lambda p: p.name)
def test_libraw_renders_the_dng_as_the_original(written, src):
    """Only the writing differs: LibRaw's render of the DNG equals the original's."""
    dng, _ = written[src]
    a, b = libraw_render(src), libraw_render(dng)
    assert a.shape == b.shape
    assert psnr(a, b) >= 50


def test_the_mosaic_and_levels_are_the_raws(written):
    src = DATA / "raw" / "canon_eos60d_mlv.dng"
    dng, meta = written[src]
    with rawpy.imread(str(src)) as a, rawpy.imread(str(dng)) as b:
        assert np.array_equal(a.raw_image_visible, b.raw_image_visible)
        assert list(a.black_level_per_channel) == list(b.black_level_per_channel)
        assert a.white_level == b.white_level
        assert np.array_equal(a.raw_pattern, b.raw_pattern)
        assert np.allclose(
            np.array(a.camera_whitebalance[:3]) / a.camera_whitebalance[1],
            np.array(b.camera_whitebalance[:3]) / b.camera_whitebalance[1],
            rtol=1e-4,
        )
    assert meta["format"] == "dng" and meta["dng"] == "mosaic"
    assert meta["raw_denoise"] == "none" and meta["noise_left"] is None


def test_a_dngs_own_colour_tags_are_kept(written):
    src = DATA / "raw" / "canon_eos60d_mlv.dng"
    dng, meta = written[src]
    codes = (50721, 50722, 50778, 50779, 50723, 50724, 50727, 50730)
    with tifffile.TiffFile(src) as a, tifffile.TiffFile(dng) as b:
        ta, tb = a.pages.first.tags, b.pages.first.tags
        present = [c for c in codes if c in ta]
        assert 50721 in present
        for code in present:
            va = np.asarray(ta[code].value, np.float64).ravel()
            vb = np.asarray(tb[code].value, np.float64).ravel()
            if va.size == 2 * vb.size or va.size == vb.size and code not in (50778, 50779):
                va, vb = _numbers(va), _numbers(vb)
            assert np.allclose(va, vb, atol=1e-4), code
    assert meta["colour_tags"].startswith("the file's own")


def test_the_dng_embeds_a_preview_of_the_result(written, tmp_path):
    """LibRaw finds the preview (IFD1, sRGB) as a file browser would, and it is the
    default render at half size, unrotated: the mean of each colour within 2 codes of
    rawsim's own half-size PNG of the original."""
    src = DATA / "raw" / "canon_eos60d_mlv.dng"
    dng, meta = written[src]
    with rawpy.imread(str(dng)) as raw:
        thumb = raw.extract_thumb()
    assert thumb.format == rawpy.ThumbFormat.BITMAP
    assert thumb.data.shape == (meta["preview"]["height"], meta["preview"]["width"], 3)
    with tifffile.TiffFile(dng) as tif:
        assert tif.pages[1].tags["NewSubfileType"].value == 1
        assert tif.pages[1].tags[50970].value == 2  # PreviewColorSpace: sRGB
    r = run("process", src, "-o", tmp_path, "--half-size")
    assert r.exit_code == 0, r.output
    ours = np.asarray(__import__("PIL.Image").Image.open(tmp_path / f"{src.stem}.png"))
    assert ours.shape == thumb.data.shape
    assert np.abs(ours.mean((0, 1)) - thumb.data.mean((0, 1))).max() < 2


def test_a_dngs_mirrored_orientation_is_kept(written):
    """The GoPro crops say Orientation 2 (mirrored), which LibRaw's flip has no value for:
    the DNG written back says 2 as well, so an editor that honours it (RawTherapee)
    shows it as the original."""
    src = DATA / "highlights" / "gopro_hero6_sky.dng"
    dng, meta = written[src]
    with tifffile.TiffFile(src) as a, tifffile.TiffFile(dng) as b:
        assert a.pages.first.tags["Orientation"].value == 2
        assert b.pages.first.tags["Orientation"].value == 2
    assert meta["orientation"] == 2


def _numbers(v: np.ndarray) -> np.ndarray:
    """(S)RATIONAL pairs as numbers."""
    return v[0::2] / v[1::2] if v.size % 2 == 0 and v.size > 1 else v


def test_exiftool_reads_the_camera_and_capture(written):
    exiftool = require_tool("exiftool")
    src = DATA / "highlights" / "nikon_d1_roofs.dng"
    dng, _ = written[src]
    keys = ["Make", "Model", "ISO", "ExposureTime", "FNumber", "DateTimeOriginal", "Orientation"]
    read = [
        json.loads(
            subprocess.run(
                [exiftool, "-j", *(f"-{k}" for k in keys), str(p)],
                capture_output=True,
                check=True,
                text=True,
            ).stdout
        )[0]
        for p in (src, dng)
    ]
    for key in keys:
        if key in read[0]:
            assert read[1].get(key) == read[0][key], key
    assert read[1]["Make"] and read[1]["Model"]
    with tifffile.TiffFile(dng) as tif:
        tags = tif.pages.first.tags
        assert tags["PhotometricInterpretation"].value == 32803
        assert tags["Software"].value.startswith("rawsim")


@pytest.fixture(scope="module")
def noisy_pairs(tmp_path_factory):
    """A photo unprocessed at ISO 6400, Bayer (Nikon D850) and X-Trans (the X-T3), with
    its clean twin."""
    out = tmp_path_factory.mktemp("pairs")
    photo = DATA / "srgb" / "chelsea.png"
    for profile in ("nikon_d850", "fujifilm_xt3"):
        r = run(
            "unprocess", photo, "-o", out / profile, "--profile", profile,
            "--iso", 6400, "--clean", "--seed", 3,
        )  # fmt: skip
        assert r.exit_code == 0, r.output
    return out


def test_denoised_dng_is_closer_to_the_clean_raw_through_libraw(noisy_pairs, tmp_path):
    folder = noisy_pairs / "nikon_d850"
    noisy, clean = folder / "chelsea.dng", folder / "chelsea.clean.dng"
    r = run("process", noisy, "-o", tmp_path, "--format", "dng", "--denoise", "profiled")
    assert r.exit_code == 0, r.output
    truth = libraw_render(clean)
    before = psnr(libraw_render(noisy), truth)
    after = psnr(libraw_render(tmp_path / "chelsea.dng"), truth)
    assert after >= before + 3, (before, after)
    meta = json.loads((tmp_path / "chelsea.process.json").read_text())
    assert meta["raw_denoise"] == "profiled"
    assert all(0 < share < 0.5 for share in meta["noise_left"])
    with tifffile.TiffFile(noisy) as a, tifffile.TiffFile(tmp_path / "chelsea.dng") as b:
        s_in = np.asarray(a.pages.first.tags["NoiseProfile"].value)
        s_out = np.asarray(b.pages.first.tags["NoiseProfile"].value).reshape(3, 2)
        assert (s_out[:, 0] < 0.5 * s_in[0]).all()  # S per colour: what is left
        num, den = b.pages.first.tags[50935].value  # NoiseReductionApplied
        assert num / den == pytest.approx(1 - np.mean(meta["noise_left"]), abs=1e-3)
        assert 50935 not in a.pages.first.tags


def test_xtrans_dng_keeps_its_6x6_pattern(noisy_pairs, tmp_path):
    noisy = noisy_pairs / "fujifilm_xt3" / "chelsea.dng"
    r = run("process", noisy, "-o", tmp_path, "--format", "dng")
    assert r.exit_code == 0, r.output
    out = tmp_path / "chelsea.dng"
    with tifffile.TiffFile(noisy) as a, tifffile.TiffFile(out) as b:
        ta, tb = a.pages.first.tags, b.pages.first.tags
        assert tuple(tb["CFARepeatPatternDim"].value) == (6, 6)
        assert bytes(tb["CFAPattern"].value) == bytes(ta["CFAPattern"].value)
        assert tuple(tb["BlackLevelRepeatDim"].value) == (6, 6)
    assert psnr(libraw_render(out), libraw_render(noisy)) >= 50


def test_the_same_bytes_every_run(noisy_pairs, tmp_path):
    src = noisy_pairs / "nikon_d850" / "chelsea.dng"
    for name in ("a", "b"):
        r = run("process", src, "-o", tmp_path / name, "--format", "dng", "--denoise", "profiled")
        assert r.exit_code == 0, r.output
    assert (tmp_path / "a" / "chelsea.dng").read_bytes() == (
        tmp_path / "b" / "chelsea.dng"
    ).read_bytes()
    again = run("process", src, "-o", tmp_path / "a", "--format", "dng")
    assert again.exit_code == 0 and "1 skipped" in again.output


@pytest.mark.parametrize(
    "extra, said",
    [
        (["--tone", "reinhard"], "--tone reinhard shapes a render"),
        (["--highlights", "clip"], "--highlights clip shapes a render"),
        (["--output-space", "display-p3"], "shapes a render"),
        (["--resize", "100"], "drop --resize"),
        (["--bits", "8"], "--format dng takes --bits 16"),
    ],
)
def test_options_that_shape_a_render_are_refused(tmp_path, extra, said):
    r = run("process", RAWS[0], "-o", tmp_path, "--format", "dng", *extra)
    assert r.exit_code != 0
    assert said in r.output
    assert not list(tmp_path.glob("*.dng"))


def test_the_mosaic_kind_of_a_linear_raw_is_refused_in_one_line(tmp_path):
    r = run("process", LINEAR, "-o", tmp_path, "--format", "dng", "--dng", "mosaic")
    assert r.exit_code != 0
    line = next(s for s in r.output.splitlines() if "LinearRaw" in s)
    assert LINEAR.name in line and "--dng linear" in line
    assert "Traceback" not in r.output
    assert not list(tmp_path.glob("*.dng"))


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    """Every raw of :data:`RAWS` and the LinearRaw DNG as a linear DNG: {source: dng}."""
    out = tmp_path_factory.mktemp("linear")
    for src in [*RAWS, LINEAR]:
        r = run("process", src, "-o", out, "--format", "dng", "--dng", "linear")
        assert r.exit_code == 0, r.output
    return {src: out / f"{src.stem}.dng" for src in [*RAWS, LINEAR]}


@pytest.mark.parametrize("src", [*RAWS, LINEAR], ids=lambda p: p.name)
def test_libraw_renders_the_linear_dng_as_the_original(linear, src):
    """rawsim's demosaic in camera RGB (LinearRaw): LibRaw's render agrees with its
    render of the original on 16 × 16 block means (the demosaics differ within a
    block) ≥ 40 dB where no pixel of the block clipped, and ≥ 38 dB over all blocks
    (where a colour clipped, LibRaw clips the mosaic before its demosaic, and rawsim's
    demosaic reads the unclipped colours: the blown-highlight crops and the chart
    with a clipped green, 38.9–39.9 dB); the LinearRaw DNG given back is the same
    data."""
    a, b = libraw_render(src), libraw_render(linear[src])
    assert a.shape == b.shape
    means_a, means_b = block_means(a), block_means(b)
    n = 16
    h, w = a.shape[0] // n * n, a.shape[1] // n * n
    clipped = (a[:h, :w] >= 0.99).any(-1).reshape(h // n, n, w // n, n).any((1, 3))
    assert psnr(means_a[~clipped], means_b[~clipped]) >= (100 if src == LINEAR else 40)
    assert psnr(means_a, means_b) >= 38
    with tifffile.TiffFile(linear[src]) as tif:
        tags = tif.pages.first.tags
        assert tags["PhotometricInterpretation"].value == 34892  # LinearRaw
        assert tags["SamplesPerPixel"].value == 3
        assert 50721 in tags and "CFAPattern" not in tags


def test_the_raws_own_preview_is_kept_beside_the_render(linear, written):
    """The Canon 6D DNG's JPEG preview is the DNG's third image, byte for byte (IFD2,
    its colour space unknown), after rawsim's render (IFD1, sRGB); the Kodak DC50's
    bitmap likewise; a raw without one gets the render alone."""
    from rawsim.io.thumbnail import read_thumbnail

    with tifffile.TiffFile(linear[LINEAR]) as tif:
        assert [p.tags[50970].value for p in tif.pages[1:]] == [2, 0]
        page = tif.pages[2]
        jpeg = tif.filehandle
        jpeg.seek(page.dataoffsets[0])
        assert jpeg.read(page.databytecounts[0]) == read_thumbnail(LINEAR).jpeg
    kdc = DATA / "raw" / "kodak_dc50_grbg.kdc"
    with tifffile.TiffFile(written[kdc][0]) as tif:
        assert np.array_equal(tif.pages[2].asarray(), read_thumbnail(kdc).bitmap)
    with tifffile.TiffFile(written[RAWS[0]][0]) as tif:
        assert len(tif.pages) == 2  # the 60D DNG holds no preview of its own


def test_a_linear_raw_takes_the_linear_kind_by_default(tmp_path):
    r = run("process", LINEAR, "-o", tmp_path, "--format", "dng")
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / f"{LINEAR.stem}.process.json").read_text())["dng"] == "linear"
    r = run("process", LINEAR, "-o", tmp_path / "m", "--format", "dng", "--dng", "mosaic")
    assert r.exit_code != 0 and "--dng linear" in r.output


def test_the_linear_kind_takes_the_demosaic_and_refuses_the_rest(tmp_path):
    ok = run("process", RAWS[0], "-o", tmp_path, "--format", "dng", "--dng", "linear",
             "--demosaic", "menon")  # fmt: skip
    assert ok.exit_code == 0, ok.output
    meta = json.loads((tmp_path / f"{RAWS[0].stem}.process.json").read_text())
    assert {"name": "demosaic", "ran": True} in [
        {k: st[k] for k in ("name", "ran")} for st in meta["linear"]["stages"]
    ]
    assert meta["config"][[t["name"] for t in meta["config"]].index("demosaic")]["method"] == (
        "menon"
    )
    no = run("process", RAWS[0], "-o", tmp_path / "b", "--format", "dng", "--dng", "linear",
             "--tone", "reinhard")  # fmt: skip
    assert no.exit_code != 0 and "--tone reinhard shapes a render" in no.output
    alone = run("process", RAWS[0], "-o", tmp_path / "c", "--dng", "linear")
    assert alone.exit_code != 0 and "--format dng" in alone.output


def _editor_render(editor: str, src, out, tmp):
    if editor == "darktable-cli":
        command = [editor, str(src), str(out), "--core", "--configdir", str(tmp / "dt")]
        command += ["--conf", "plugins/imageio/format/tiff/bpp=16"]
    else:
        command = [editor, "-o", str(out), "-t", "-b16", "-Y", "-c", str(src)]
    subprocess.run(command, check=True, capture_output=True, timeout=600)
    return tifffile.imread(out).astype(np.float64) / 65535


@pytest.mark.slow
@pytest.mark.parametrize("editor", ["darktable-cli", "rawtherapee-cli"])
def test_editors_open_the_dng_and_render_it_as_the_original(written, tmp_path, editor):
    """darktable and RawTherapee open the mosaic DNGs; where they open the original too,
    their renders agree (16 × 16 block means, ≥ 40 dB)."""
    require_tool(editor)
    opened = 0
    for src in (
        DATA / "highlights" / "nikon_d1_roofs.dng",
        DATA / "raw" / "apple_quicktake150.qtk",
    ):  # noqa: E501
        dng, _ = written[src]
        copy = tmp_path / f"dng_{src.stem}.dng"
        shutil.copy(dng, copy)
        ours = _editor_render(editor, copy, tmp_path / f"dng_{src.stem}.tif", tmp_path)
        assert ours.mean() > 0.01
        try:
            original = tmp_path / f"orig_{src.stem}{src.suffix}"
            shutil.copy(src, original)
            theirs = _editor_render(editor, original, tmp_path / f"orig_{src.stem}.tif", tmp_path)
        except subprocess.CalledProcessError:
            continue  # the editor cannot open the original (QuickTake): the DNG opens
        assert ours.shape == theirs.shape
        assert psnr(block_means(ours), block_means(theirs)) >= 40
        opened += 1
    assert opened >= 1


@pytest.mark.slow
def test_rawtherapee_renders_the_linear_dng_as_the_original(linear, tmp_path):
    """RawTherapee renders the linear DNG of the Nikon D1 crop as its original (16 × 16
    block means ≥ 40 dB), once the 4-pixel border it trims from a mosaic's render is
    trimmed from the linear one's too."""
    require_tool("rawtherapee-cli")
    src = DATA / "highlights" / "nikon_d1_roofs.dng"
    shutil.copy(src, tmp_path / "orig.dng")
    shutil.copy(linear[src], tmp_path / "linear.dng")
    theirs = _editor_render("rawtherapee-cli", tmp_path / "orig.dng", tmp_path / "o.tif", tmp_path)
    ours = _editor_render("rawtherapee-cli", tmp_path / "linear.dng", tmp_path / "l.tif", tmp_path)
    trim = (ours.shape[0] - theirs.shape[0]) // 2
    assert trim == 4 and ours.shape[1] - theirs.shape[1] == 8
    assert psnr(block_means(ours[trim:-trim, trim:-trim]), block_means(theirs)) >= 40


def _gain_map_opcodes(h: int, w: int, left: float, right: float) -> bytes:
    """An OpcodeList2 of four GainMaps (DNG 1.3 opcode 9), one for each site of the 2 × 2
    period (pitch 2, as cameras write them and darktable reads them), over the whole
    (h, w) image, 2 × 2 points: gain ``left`` at the left edge, ``right`` at the
    right."""
    import struct

    maps = b""
    for top, first in ((0, 0), (0, 1), (1, 0), (1, 1)):
        params = struct.pack(">8I", top, first, h, w, 0, 1, 2, 2)  # area, planes, pitches
        params += struct.pack(">2I4d", 2, 2, 1.0, 1.0, 0.0, 0.0)  # points, spacing, origin
        params += struct.pack(">I4f", 1, left, right, left, right)  # map planes, gains
        maps += struct.pack(">4I", 9, 0x01030000, 0, len(params)) + params
    return struct.pack(">I", 4) + maps


@pytest.fixture(scope="module")
def gain_mapped(tmp_path_factory):
    """The Nikon D1 crop rewritten with a GainMap in OpcodeList2 (1× at the left to 2× at
    the right), and its ``--format dng``: (original, ours)."""
    from dataclasses import replace

    from rawsim.io.dng import DngInfo, write_dng
    from rawsim.io.metadata import read_metadata
    from rawsim.io.raw import read_raw
    from rawsim.io.tiff import UNDEFINED

    src = DATA / "highlights" / "nikon_d1_roofs.dng"
    raw = read_raw(src)
    out = tmp_path_factory.mktemp("gainmap")
    h, w = raw.data.shape
    info = DngInfo(
        cfa=raw.cfa,
        black_level=raw.black_level,
        white_level=raw.white_level,
        xyz_to_camera=tuple(map(tuple, raw.xyz_to_camera)),
        as_shot_neutral=tuple(raw.as_shot_wb[1] / g for g in raw.as_shot_wb),
        make=raw.make,
        model=raw.model,
        unique_model=f"{raw.make} {raw.model}",
        iso=raw.iso,
        extra_tags={51009: (UNDEFINED, _gain_map_opcodes(h, w, 1.0, 2.0))},
    )
    original = out / "mapped.dng"
    write_dng(original, raw.data, replace(info), read_metadata(src))
    r = run("process", original, "-o", out / "ours", "--format", "dng")
    assert r.exit_code == 0, r.output
    return original, out / "ours" / "mapped.dng"


def test_a_dngs_rendering_tags_are_kept(written, gain_mapped):
    """DefaultCrop, ForwardMatrix and the like, and the gain maps of OpcodeList2, are
    the DNG's own, byte for byte; the sidecar lists them."""
    src = DATA / "raw" / "canon_eos60d_mlv.dng"
    dng, meta = written[src]
    with tifffile.TiffFile(src) as a, tifffile.TiffFile(dng) as b:
        ta, tb = a.pages.first.tags, b.pages.first.tags
        for name in ("DefaultCropOrigin", "DefaultCropSize", "ForwardMatrix1"):
            assert tb[name].value == ta[name].value, name
    assert {"DefaultCropSize", "ForwardMatrix1"} <= set(meta["dng_tags_kept"])
    original, ours = gain_mapped
    with tifffile.TiffFile(original) as a, tifffile.TiffFile(ours) as b:
        assert b.pages.first.tags[51009].value == a.pages.first.tags[51009].value


@pytest.mark.slow
def test_darktable_applies_the_kept_gain_map_as_on_the_original(gain_mapped, tmp_path):
    """darktable applies a DNG's GainMap: the DNG written back keeps it, so darktable
    renders it as the original (16 × 16 block means ≥ 40 dB), where without it the
    right edge would be a stop darker."""
    require_tool("darktable-cli")
    original, ours = gain_mapped
    a = _editor_render("darktable-cli", original, tmp_path / "a.tif", tmp_path)
    b = _editor_render("darktable-cli", ours, tmp_path / "b.tif", tmp_path)
    shutil.copy(DATA / "highlights" / "nikon_d1_roofs.dng", tmp_path / "plain.dng")
    plain = _editor_render("darktable-cli", tmp_path / "plain.dng", tmp_path / "p.tif", tmp_path)
    assert a.shape == b.shape == plain.shape
    assert psnr(block_means(a), block_means(plain)) < 25  # darktable applied the map
    assert psnr(block_means(a), block_means(b)) >= 40


def test_the_linear_kind_says_it_leaves_the_gain_maps_out(gain_mapped, tmp_path):
    original, _ = gain_mapped
    r = run("process", original, "-o", tmp_path, "--format", "dng", "--dng", "linear")
    assert r.exit_code == 0, r.output
    line = next(s for s in r.output.splitlines() if "OpcodeList2" in s)
    assert line.startswith("warning: ") and "mapped.dng" in line and "--dng mosaic keeps it" in line
    meta = json.loads((tmp_path / "mapped.process.json").read_text())
    assert "OpcodeList2" not in meta["dng_tags_kept"]
    with tifffile.TiffFile(tmp_path / "mapped.dng") as tif:
        assert 51009 not in tif.pages.first.tags


def test_a_batch_with_two_workers_writes_the_same_bytes(tmp_path):
    """--jobs 2 (a pool of worker processes) gives the DNGs and sidecars of one process."""
    folder = DATA / "highlights"
    for name, jobs in (("one", "1"), ("two", "2")):
        r = run("process", folder, "-o", tmp_path / name, "--format", "dng", "--jobs", jobs)
        assert r.exit_code == 0, r.output
    one = sorted((tmp_path / "one").glob("*.dng"))
    assert len(one) == len(list(folder.glob("*.dng")))
    for path in one:
        assert path.read_bytes() == (tmp_path / "two" / path.name).read_bytes(), path.name
