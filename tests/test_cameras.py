"""The camera database (rawsim.cameras): coverage, provenance, names, the noise estimate's
leave-one-out error on the cameras ELD calibrated, and DNGs LibRaw renders for each maker."""

import hashlib
import json
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest
import rawpy
from click.testing import CliRunner

from rawsim import cameras
from rawsim.cameras import database, estimate
from rawsim.cameras.profiles import SOURCED_KEYS, list_profiles, load_profile, profile_dir
from rawsim.errors import ProfileError
from rawsim_cli.main import cli

#: The five cameras ELD (Wei et al., CVPR 2020) calibrated, bundled with their figures.
ELD = ("canon_eos_5d_mark_iv", "canon_eos_700d", "canon_eos_70d", "nikon_d850", "sony_a7s2")
#: The bundled profiles' bytes (sha256, first 16 hex digits): the database leaves them be.
BUNDLED = {
    "canon_eos_5d_mark_iv": "daf812a85d89b176",
    "canon_eos_700d": "e521a3172be6fc77",
    "canon_eos_70d": "7ee3f6444b730030",
    "fujifilm_xt3": "ffb6daa8e413f680",
    "nikon_d800e": "be26fb5002f08971",
    "nikon_d850": "65d1138003c6866d",
    "oppo_reno10x": "95f1587416138a6d",
    "sony_a7s2": "d8b532527cd57f82",
    "sony_imx686": "0df194db3aa96ee9",
}


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_profiles_list_json_has_every_camera_with_every_field_and_its_source():
    r = run("profiles", "list", "--json")
    assert r.exit_code == 0, r.output
    rows = json.loads(r.output)
    assert len(rows) >= 800
    assert len({row["name"] for row in rows}) == len(rows)
    for row in rows:
        for key in ("make", "model", "cfa_pattern", "bit_depth", "xyz_to_camera", "noise"):
            assert row[key] not in (None, "", []), (row["name"], key)
        assert isinstance(row["aliases"], list)
        assert 0 <= row["black_level"] < row["white_level"] < 2 ** row["bit_depth"]
        assert row["noise_kind"] in ("measured", "estimated"), row["name"]
        assert all(row["source"].get(k) for k in SOURCED_KEYS), row["name"]
        assert row["assumed"] == [k for k, v in row["source"].items() if v.startswith("assumed")]
    generated = [row for row in rows if row["name"] not in BUNDLED]
    assert all("cfa_pattern" in row["source"] for row in generated)
    # Every figure of a generated profile names its upstream file and commit, or says
    # it was assumed.
    up = cameras.about()["upstream"]
    commits = tuple(cameras.ref(v) for v in up.values())
    keys = ("xyz_to_camera", "cfa_pattern", "bit_depth", "black_level", "white_level")
    for row in generated:
        for key in (*keys, "iso_range"):
            text = row["source"][key]
            assert (
                text.startswith("assumed")
                or any(c in text for c in commits)
                or ("specification" in text)
            ), (row["name"], key, text)


def test_levels_and_iso_ranges_come_from_the_tables_or_say_they_are_assumed():
    """Each camera's levels fit its bit depth, its ISO range is its own (not one range
    for all), and what no table gives is assumed and says from which cameras."""
    rows = [c.data for c in cameras.cameras()]
    ranges = Counter(tuple(r["iso_range"]) for r in rows)
    assert len(ranges) > 50 and ranges.most_common(1)[0][1] < len(rows) / 5, ranges
    for r in rows:
        assert 0 <= r["black_level"] < r["white_level"] < 2 ** r["bit_depth"], r["name"]
        assert r["white_level"] >= 2 ** (r["bit_depth"] - 1), r["name"]  # the fewest bits
        lo, hi = r["iso_range"]
        assert 0 < lo < hi, r["name"]
        for key in ("bit_depth", "black_level", "white_level", "iso_range"):
            text = r["source"][key]
            if text.startswith("assumed"):
                assert "cameras with one" in text or "of its line" in text or "full scale" in text
    sourced = [r for r in rows if not r["source"]["iso_range"].startswith("assumed")]
    assert len(sourced) > 300
    p = load_profile("Canon EOS R6")  # a CR3 body rawspeed does not read: camconst's white
    assert (p.bit_depth, p.white_level) == (14, 16382)
    assert "camconst.json" in p.source["white_level"]
    assert p.source["black_level"].startswith("assumed") and "black_level" in p.assumed
    # an estimated profile tabulates its read noise over its own ISO range
    for name in ("Canon EOS R6", "Olympus E-M1 Mark III", "Canon PowerShot G7 X"):
        p = load_profile(name)
        assert p.noise.read_sigma.iso[0] == p.iso_range[0]
        assert p.noise.read_sigma.iso[-1] == p.iso_range[1]


def test_every_camera_is_found_by_the_names_libraw_and_its_files_give():
    """Every camera LibRaw lists with a colour matrix: by LibRaw's list name ("OM Digital
    Solutions OM-1") and by the Make and Model its files write, as exiftool shows them
    ("NIKON CORPORATION" "NIKON D850", "RICOH IMAGING COMPANY, LTD." "PENTAX K-1"),
    through both find() (one string) and find_camera() (the two tags). Two cameras whose
    files write the same names (the Leica M (Typ 240) and M (Typ 262): "LEICA M") cannot
    be told apart: find() then names neither, find_camera() one of them."""
    owners = defaultdict(set)
    for cam in cameras.cameras():
        for make, model in cam.data["exif"]:
            owners[(database._fold(make), database._fold(model))].add(cam.name)
    assert len(owners) > len(cameras.cameras())
    for cam in cameras.cameras():
        assert cameras.find(cam.data["libraw"]) == cam, cam.data["libraw"]
        for make, model in cam.data["exif"]:
            both = owners[(database._fold(make), database._fold(model))]
            if len(both) == 1:
                assert cameras.find(f"{make} {model}") == cam, (make, model)
                assert cameras.find_camera(make, model) == cam, (make, model)
            else:
                assert cameras.find(f"{make} {model}") is None, (make, model)
                assert cameras.find_camera(make, model).name in both, (make, model)
    assert cameras.find_camera("RaspberryPi", "RP_imx477") is None  # a maker it lacks


def test_bundled_profiles_keep_their_bytes_and_win_over_the_database():
    for name in list_profiles():
        digest = hashlib.sha256((profile_dir() / f"{name}.json").read_bytes()).hexdigest()
        assert digest[:16] == BUNDLED[name], name
    for name in ELD:
        p = load_profile(name)
        assert p.noise_kind == "measured" and p.noise.has_physics
        assert load_profile(f"{p.make} {p.model}") == p  # by the camera's name: the bundled one
    assert load_profile("fujifilm_xt3").noise_kind == "estimated"  # derived, says its source


@pytest.mark.parametrize(
    "names",
    [
        ("Sony ILCE-7M3", "sony a7 iii", "ILCE-7M3", "SONY ILCE-7M3", "Sony A7 III", "sony a7m3"),
        ("Canon EOS R5", "canon eos r5", "EOS R5", "canon r5"),
        ("Canon EOS 700D", "Canon EOS Rebel T5i", "kiss x7i", "canon_eos_700d"),
        ("Nikon Z 6 II", "nikon z6ii", "Nikon Z 6 Mark II"),
        ("Fujifilm X-T4", "fuji x-t4", "FUJIFILM X-T4"),
        ("Olympus E-M5", "olympus e-m5"),
        ("Olympus E-5", "olympus e 5"),
        ("OM Digital Solutions OM-1", "OM-1", "OM System OM-1", "om digital solutions om-1"),
        ("Olympus E-M1 Mark III", "E-M1MarkIII", "OLYMPUS CORPORATION E-M1MarkIII"),
        ("Pentax K-1", "RICOH IMAGING COMPANY, LTD. PENTAX K-1", "PENTAX K-1"),
        ("Nikon D850", "NIKON CORPORATION NIKON D850"),
        ("Canon EOS R6", "Canon Canon EOS R6"),
        ("Leica V-Lux (Typ 114)", "Leica V-Lux"),
        ("Phase One P 25+", "Phase One A/S P 25+"),
    ],
)
def test_a_camera_by_any_of_its_names(names):
    found = {load_profile(n).name for n in names}
    assert len(found) == 1, found


def test_an_unknown_name_lists_the_closest_cameras():
    with pytest.raises(ProfileError, match="unknown sensor profile 'sony a7 xx'") as err:
        load_profile("sony a7 xx")
    assert "Sony ILCE-7" in str(err.value) and "profiles list --search" in str(err.value)
    r = run("profiles", "show", "canon eos r55")
    assert r.exit_code == 2 and "Canon EOS R5" in r.output


def test_show_and_list_mark_each_assumed_value():
    """profiles show puts "(assumed)" on the line of each assumed value and on no other;
    profiles list names them in its "assumed" column."""
    cam = next(
        c
        for c in cameras.cameras()
        if not c.bundled
        and c.data["source"]["black_level"].startswith("assumed")
        and not c.data["source"]["white_level"].startswith("assumed")
        and c.data["source"]["iso_range"].startswith("assumed")
    )
    lines = run("profiles", "show", cam.label).output.splitlines()
    levels = next(line for line in lines if line.startswith("  CFA "))
    black, white = levels.split(", black ")[1].split(", white ")
    assert black.endswith("DN (assumed)") and "assumed" not in white, levels
    assert next(line for line in lines if line.startswith("  ISO ")).endswith("(assumed)")
    assert not next(line for line in lines if "XYZ→camera" in line).endswith("(assumed)")
    sourced = next(
        c for c in cameras.cameras() if not c.bundled and not load_profile(c.label).assumed
    )
    shown = run("profiles", "show", sourced.label).output
    assert "(assumed)" not in shown and "source[iso_range]" in shown
    rows = run("profiles", "list", "--search", cam.data["model"]).output.splitlines()
    row = next(r for r in rows if r.startswith(cam.name + " ")).split()
    column = row[-2].split(",")  # assumed (then curves)
    assert {"black", "iso"} <= set(column) and "white" not in column, column


def test_search_and_show_say_measured_or_estimated():
    r = run("profiles", "list", "--search", "a7 iii")
    assert r.exit_code == 0 and "sony_ilce_7m3" in r.output and "estimated" in r.output
    assert "sony_ilce_7m4" not in r.output
    r = run("profiles", "list", "--search", "D850")
    assert "nikon_d850" in r.output and "measured" in r.output
    assert "canon_eos_700d" in run("profiles", "list", "--search", "rebel t5i").output
    rows = json.loads(run("profiles", "list", "--json", "--search", "a7 iii").output)
    assert {r["name"]: r["aliases"] for r in rows} == {"sony_ilce_7m3": ["A7 III"]}
    r = run("profiles", "show", "sony a7 iii")
    assert "noise: estimated (sensor physics)" in r.output and "source[noise.gain]" in r.output
    assert "noise: measured" in run("profiles", "show", "nikon_d850").output
    r = run("profiles", "list", "--search", "no such camera")
    assert r.exit_code == 0 and "no camera matches" in r.output


def test_the_estimate_predicts_each_eld_camera_from_the_others_within_35_percent():
    """Leave one out: fitted on four of ELD's cameras, K of the fifth over ISO 400–6400."""
    iso = (400, 800, 1600, 3200, 6400)
    cams = [estimate.calibrated_camera(load_profile(n), iso) for n in ELD]
    for i, cam in enumerate(cams):
        eta = estimate.fit(cams[:i] + cams[i + 1 :])["eta"]
        for iso, k, _ in cam["points"]:
            assert estimate.gain(iso, cam["span"], cam["area"], eta) / k == pytest.approx(
                1, abs=0.35
            ), (cam["name"], iso)
    # The shipped constants are the fit on all five (the database is not stale).
    shipped = cameras.about()["estimate"]["constants"]
    assert estimate.fit(cams)["eta"] == pytest.approx(shipped["eta"], rel=1e-4)


def test_an_estimated_profile_follows_the_model():
    p = load_profile("Sony ILCE-7M3")
    c = cameras.about()["estimate"]["constants"]
    area = cameras.find("Sony ILCE-7M3").data["pixel_area_um2"]
    span = p.white_level - p.black_level
    for iso in (100, 1600, 12800):
        k = p.noise.gain(iso)
        assert k == pytest.approx(estimate.gain(iso, span, area, c["eta"]), rel=1e-4)
        sigma = estimate.read_sigma(k, span, c["read_e"], c["floor_dn14"])
        assert p.noise.read_sigma(iso, k) == pytest.approx(sigma, rel=1e-4)


def _one_camera_per_maker():
    by_maker = defaultdict(list)
    for cam in cameras.cameras():
        if not cam.bundled:
            by_maker[cam.data["make"]].append(cam)
    # The maker's first camera with a tabulated (not assumed) layout, if any.
    return [
        next(
            (c for c in cams if not c.data["source"]["cfa_pattern"].startswith("assumed")), cams[0]
        )
        for cams in by_maker.values()
    ]


@pytest.mark.slow
def test_each_maker_unprocesses_to_dngs_libraw_renders_as_that_camera(tmp_path):
    """One generated profile per maker: the DNG opens in LibRaw with the camera's make and
    model, in its CFA, and renders (X-Trans photos are tiled past LibRaw's 512-row limit)."""
    import OpenImageIO as oiio

    small = tmp_path / "small"
    big = tmp_path / "big"
    small.mkdir()
    big.mkdir()
    photo = Path(__file__).parent / "data" / "srgb" / "coffee.png"
    pixels = oiio.ImageBuf(str(photo)).get_pixels(oiio.UINT8)[:96, :128, :3]
    oiio.ImageBuf(np.ascontiguousarray(pixels)).write(str(small / "p.png"))
    oiio.ImageBuf(np.ascontiguousarray(np.tile(pixels, (6, 5, 1)))).write(str(big / "p.png"))
    makers = _one_camera_per_maker()
    assert len(makers) >= 20
    makers.append(cameras.find("Fujifilm X-T4"))  # and an X-Trans one
    for cam in makers:
        profile = load_profile(cam.label)
        xtrans = profile.cfa.period == (6, 6)
        out = tmp_path / cam.name
        r = run(
            "unprocess", big if xtrans else small, "-o", out, "-p", cam.label, "--iso", 800, "-q"
        )
        assert r.exit_code == 0, (cam.label, r.output)
        with rawpy.imread(str(out / "p.dng")) as raw:
            assert raw.raw_image_visible.shape[0] in (96, 576), cam.label
            rgb = raw.postprocess(user_flip=0)
            assert rgb.mean() > 5, cam.label
        meta = json.loads((out / "p.json").read_text())
        assert meta["profile"]["noise_kind"] == "estimated"
        assert (meta["profile"]["make"], meta["profile"]["model"]) == (
            cam.data["make"],
            cam.data["model"],
        )
        tags = _dng_make_model(out / "p.dng")
        assert tags == (cam.data["make"], cam.data["model"]), (cam.label, tags)


def _dng_make_model(path):
    import tifffile

    with tifffile.TiffFile(path) as tif:
        tags = tif.pages[0].tags
        return tags["Make"].value, tags["Model"].value


def test_a_camera_whose_daylight_gain_is_below_1_renders_at_the_photo_brightness(tmp_path):
    """The Pentax K100D's blue daylight gain is 0.86: LibRaw and process divide the gains
    by it, so unprocess darkens the raw by as much; the render keeps the photo's level."""
    import OpenImageIO as oiio

    assert min(load_profile("Pentax K100D").white_balance) < 0.9
    photo = Path(__file__).parent / "data" / "srgb" / "chelsea.png"
    flags = ["--iso", 200, "--noise", "none", "--wb-inverse", "exact", "-q"]
    r = run("unprocess", photo, "-o", tmp_path / "raw", "-p", "Pentax K100D", *flags)
    assert r.exit_code == 0, r.output
    r = run("process", tmp_path / "raw" / "chelsea.dng", "-o", tmp_path / "out", "-q")
    assert r.exit_code == 0, r.output
    out = oiio.ImageBuf(str(tmp_path / "out" / "chelsea.png")).get_pixels(oiio.FLOAT)[..., :3]
    src = oiio.ImageBuf(str(photo)).get_pixels(oiio.FLOAT)[: out.shape[0], : out.shape[1], :3]
    assert out.mean() == pytest.approx(src.mean(), rel=0.02)
    with rawpy.imread(str(tmp_path / "raw" / "chelsea.dng")) as raw:
        srgb = {"gamma": (2.4, 12.92), "no_auto_bright": True, "output_bps": 8}
        libraw = raw.postprocess(user_flip=0, **srgb) / 255
    assert libraw.mean() == pytest.approx(src.mean(), rel=0.06)


def test_info_names_the_profile_unprocess_takes_for_a_raws_camera():
    raws = Path(__file__).parent / "data"
    facts = json.loads(run("info", raws / "raw" / "canon_eos60d_mlv.dng", "--json").output)
    assert facts["unprocess_profile"] == {
        "name": "canon_eos_60d",
        "camera": "Canon EOS 60D",
        "noise": "estimated",
    }
    chart = json.loads(run("info", raws / "chart" / "canon_550d_colorchecker.dng", "--json").output)
    assert chart["model"] == "Canon EOS Kiss X4" and chart["unprocess_profile"]["name"] == (
        "canon_eos_550d"
    )  # an alias of the EOS 550D
    unknown = json.loads(run("info", raws / "raw" / "apple_quicktake150.qtk", "--json").output)
    assert unknown["unprocess_profile"] is None
