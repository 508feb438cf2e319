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

from rawsim.io.dng_colour import read_dng_colour
from rawsim.profiles import NO_MATRIX, load_profile, profile_from_dict
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
