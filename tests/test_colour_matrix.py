"""A profile's colour matrix where it comes from a file, and the warning where it has none.

``rawsim calibrate`` takes the matrix ``process`` renders the files with: the chart DNG
(a Kiss X4, a name LibRaw's table lacks) carries ColorMatrix1, read here independently
with tifffile. A profile without a colour matrix (calibrate on a DNG with none) is
warned about in one line wherever it is used: by calibrate, by ``profiles show``, and
by ``unprocess`` once per run, each sidecar recording it.
"""

import json
from types import SimpleNamespace

import numpy as np
import tifffile
from click.testing import CliRunner

from rawsim.cameras.profiles import NO_MATRIX, load_profile, profile_from_dict
from rawsim.io.dng_colour import read_dng_colour
from rawsim_cli.main import cli
from tests.conftest import DATA
from tests.test_profiles_from_raw import UNLISTED, edited_dng

CHART = DATA / "chart" / "canon_550d_colorchecker.dng"
PHOTOS = [DATA / "srgb" / "chelsea.png", DATA / "srgb" / "coffee.png"]


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def colour_matrix_1(path) -> np.ndarray:
    """ColorMatrix1 (tag 50721, SRATIONAL numerator/denominator pairs) as tifffile reads it."""
    with tifffile.TiffFile(path) as tif:
        pairs = np.array(tif.pages.first.tags[50721].value, dtype=np.float64)
    return (pairs[0::2] / pairs[1::2]).reshape(3, 3)


def test_calibrate_takes_the_dngs_own_colour_matrix(tmp_path):
    out = tmp_path / "x4.json"
    r = run("calibrate", CHART, "--method", "patches", "--iso", 100, "-o", out)
    assert r.exit_code == 0, r.output
    assert "no colour matrix" not in r.output
    p = load_profile(out)
    np.testing.assert_allclose(p.xyz_to_camera, colour_matrix_1(CHART), rtol=0, atol=1e-12)
    assert "the file's ColorMatrix1 (unknown illuminant)" in p.source["xyz_to_camera"]
    assert p.colour_warning is None


def test_a_profile_without_a_colour_matrix_is_warned_about_where_it_is_used(tmp_path):
    drop = ("-ColorMatrix1=", "-ColorMatrix2=", "-ForwardMatrix1=", "-ForwardMatrix2=")
    dng = edited_dng(tmp_path, *UNLISTED, *drop)
    profile = tmp_path / "bare.json"
    r = run("calibrate", dng, "--method", "patches", "-o", profile)
    assert r.exit_code == 0, r.output
    assert r.stderr.count("warning: profile 'bare' has no colour matrix") == 1, r.stderr
    data = json.loads(profile.read_text())
    assert data["xyz_to_camera"] == np.eye(3).tolist()
    assert data["source"]["xyz_to_camera"].startswith(NO_MATRIX)

    r = run("profiles", "show", profile)
    assert r.exit_code == 0 and "warning: profile 'bare' has no colour matrix" in r.output

    r = run("unprocess", *PHOTOS, "-o", tmp_path / "raw", "-p", profile, "--iso", 100)
    assert r.exit_code == 0, r.output
    said = [line for line in r.stderr.splitlines() if "no colour matrix" in line]
    assert len(said) == 1 and said[0].startswith("warning: profile 'bare'"), r.stderr
    for photo in PHOTOS:
        sidecar = json.loads((tmp_path / "raw" / f"{photo.stem}.json").read_text())
        assert load_profile(profile).colour_warning in sidecar["warnings"]

    r = run("unprocess", PHOTOS[0], "-o", tmp_path / "ok", "-p", "canon_eos_70d", "--iso", 100)
    assert r.exit_code == 0 and "no colour matrix" not in r.output


def test_a_profile_that_takes_camera_rgb_as_srgb_has_no_colour_matrix():
    """The bundled OPPO phone (no matrix published: camera RGB taken as sRGB) and a seed
    config without color_matrix_d50 are warned about; a camera's own matrix is not."""
    assert "camera RGB as linear sRGB" in load_profile("oppo_reno10x").colour_warning
    seed = profile_from_dict({"bit": 12}, "seed.json")
    assert "camera RGB as linear sRGB" in seed.colour_warning
    ccm = [[1.6, -0.4, -0.2], [-0.2, 1.5, -0.3], [0.0, -0.5, 1.5]]
    assert profile_from_dict({"bit": 12, "color_matrix_d50": ccm}).colour_warning is None
    assert all(load_profile(n).colour_warning is None for n in ("sony_a7s2", "Canon EOS R6"))


def _tags(**values):
    """IFD0 tags as tifffile gives them (``.value``), rationals as (num, den) pairs."""
    codes = {"cm1": 50721, "cm2": 50722, "ill1": 50778, "ill2": 50779, "cc2": 50724}
    codes["ab"] = 50727
    out = {}
    for name, value in values.items():
        flat = np.ravel(value)
        pairs = value if name.startswith("ill") else [v for x in flat for v in (x * 10000, 10000)]
        out[codes[name]] = SimpleNamespace(value=tuple(int(round(v)) for v in np.ravel(pairs)))
    return out


def test_the_dng_matrix_libraw_would_take():
    """Of two matrices, the D65 one, else a daylight-like one (D50 here), else the second
    tag; one matrix whatever its illuminant; AB · CC · CM, as the DNG specification
    composes them. (Checked against LibRaw's own choice on real DNGs in
    tests/test_profiles_from_raw.py.)"""
    a = np.array([[0.7, -0.1, -0.1], [-0.4, 1.2, 0.2], [-0.1, 0.2, 0.6]])
    b = a + 0.05
    for ill, want, name in (
        ((17, 21), b, "ColorMatrix2 (D65)"),
        ((21, 17), a, "ColorMatrix1 (D65)"),
        ((17, 23), b, "ColorMatrix2 (D50)"),
        ((17, 17), b, "ColorMatrix2 (standard light A)"),
    ):
        colour = read_dng_colour(_tags(cm1=a, cm2=b, ill1=[ill[0]], ill2=[ill[1]]))
        matrix, what = colour.chosen()
        np.testing.assert_allclose(matrix, want, atol=1e-12)
        assert what == name
    colour = read_dng_colour(
        _tags(cm1=a, cm2=b, ill1=[17], ill2=[21], cc2=np.diag([1.1, 1, 0.9]), ab=[0.5, 1, 2])
    )
    matrix, what = colour.chosen()
    np.testing.assert_allclose(
        matrix, np.diag([0.5, 1, 2]) @ np.diag([1.1, 1, 0.9]) @ b, atol=1e-12
    )
    assert what == "AnalogBalance · CameraCalibration2 · ColorMatrix2 (D65)"
    assert read_dng_colour(_tags(ill1=[21])) is None  # no matrix


def _two_matrices(path=DATA / "raw" / "canon_eos60d_mlv.dng"):
    with tifffile.TiffFile(path) as tif:
        return read_dng_colour(tif.pages.first.tags)


def _neutral_gains(matrix, xyz_white):
    """The gains that make ``xyz_white`` neutral for XYZ → camera ``matrix`` (G = 1)."""
    camera = np.asarray(matrix) @ np.asarray(xyz_white)
    return camera[1] / camera


def test_two_dng_matrices_are_interpolated_by_the_white_balance():
    """The 60D's DNG (ColorMatrix1 for A, 2 for D65), as the DNG specification's
    chapter 6 with the DNG SDK's temperatures (A 2850 K, D65 6500 K): a shot balanced
    for A's white (2856 K) takes ColorMatrix1 all but alone, for D65's ColorMatrix2
    alone (6504 K: above 6500, clamped), and for a white between, each in proportion
    to inverse temperature, the white found with the matrix it gives."""
    colour = _two_matrices()
    cm1, cm2 = colour.composed(1), colour.composed(2)
    a_white = np.array([1.09850, 1.0, 0.35585])  # CIE A, XYZ (Y = 1)
    d65_white = np.array([0.95047, 1.0, 1.08883])

    def weight(cct):
        return (1 / cct - 1 / 6500) / (1 / 2850 - 1 / 6500)

    m, how = colour.interpolated(_neutral_gains(cm1, a_white))
    assert abs(how["cct"] - 2856) <= 2
    assert abs(how["weights"]["ColorMatrix1"] - weight(2856)) < 1e-3 and np.allclose(
        m, cm1, atol=0.01
    )
    m, how = colour.interpolated(_neutral_gains(cm2, d65_white))
    assert how["weights"] == {"ColorMatrix1": 0.0, "ColorMatrix2": 1.0} and np.allclose(m, cm2)
    # D50's white is found with the matrix it gives: a fixed point at 5003 K
    d50_white = np.array([0.96422, 1.0, 0.82521])
    w1 = weight(5003)
    mixed = w1 * cm1 + (1 - w1) * cm2
    m, how = colour.interpolated(_neutral_gains(mixed, d50_white))
    assert abs(how["cct"] - 5003) <= 2
    assert abs(how["weights"]["ColorMatrix1"] - w1) < 1e-3 and np.allclose(m, mixed, atol=1e-3)


def test_process_interpolates_a_dngs_two_matrices_unless_told_to_take_libraws(tmp_path):
    """By default the sidecar records the interpolation and the render's matrix is the
    interpolated one's; --dng-matrices libraw renders with LibRaw's single matrix."""
    from rawsim.color import srgb_from_camera
    from rawsim.io.raw import read_raw

    raw = DATA / "raw" / "canon_eos60d_mlv.dng"
    sides = {}
    for mode in ("interpolate", "libraw"):
        out = tmp_path / mode
        r = CliRunner().invoke(cli, ["process", str(raw), "-o", str(out), "--dng-matrices", mode])
        assert r.exit_code == 0, r.output
        sides[mode] = json.loads((out / "canon_eos60d_mlv.process.json").read_text())
    how = sides["interpolate"]["dng_matrices"]
    assert 4000 < how["cct"] < 6500 and sum(how["weights"].values()) == 1
    w1 = how["weights"]["ColorMatrix1"]
    colour = _two_matrices(raw)
    want = srgb_from_camera(w1 * colour.composed(1) + (1 - w1) * colour.composed(2))
    assert np.allclose(sides["interpolate"]["color_matrix"], want, atol=1e-5)
    assert "dng_matrices" not in sides["libraw"]
    libraw = srgb_from_camera(read_raw(raw).xyz_to_camera)
    assert np.allclose(sides["libraw"]["color_matrix"], libraw, atol=1e-5)
    assert np.abs(np.subtract(sides["interpolate"]["color_matrix"], libraw)).max() > 0.01


def test_info_says_how_a_dngs_two_matrices_are_weighted():
    r = CliRunner().invoke(cli, ["info", str(DATA / "raw" / "canon_eos60d_mlv.dng"), "--json"])
    assert r.exit_code == 0, r.output
    (record,) = (
        json.loads(r.output) if r.output.lstrip().startswith("[") else [json.loads(r.output)]
    )
    assert record["dng_matrices"]["cct"] == 6016
    assert set(record["dng_matrices"]["weights"]) == {"ColorMatrix1", "ColorMatrix2"}
