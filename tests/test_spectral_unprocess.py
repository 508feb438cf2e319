"""Spectral scenes through ``rawsim unprocess``: the raw is the exact integral of the
camera's curves, the light and the scene; the DNG's colour tags, the sidecar, the
refusals, LibRaw's and ``rawsim process``'s reading of the files."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
import rawpy
from click.testing import CliRunner

from rawsim.cameras import spectra
from rawsim.cameras.profiles import load_profile
from rawsim.cfa import CFA
from rawsim.io.spectral import read_spectral, wavelength_of
from rawsim.spectral import fit, tables
from rawsim_cli.main import cli
from tests.conftest import DATA, require_tool

CHART = DATA / "spectral" / "chart.npz"
PROFILE = "nikon_d850"


def unprocess(*args, ok=True):
    done = CliRunner().invoke(cli, ["unprocess", *map(str, args)])
    if ok:
        assert done.exit_code == 0, done.output
    return done


def clean_raw(tmp_path, source, *options, name="out"):
    """The clean mosaic (H, W) DN and the sidecar of ``source``, noise-free."""
    out = tmp_path / name
    unprocess(
        source, "-o", out, "-p", PROFILE, "--iso", 100, "--noise", "none", "--clean", *options
    )
    with rawpy.imread(str(out / f"{source.stem}.clean.dng")) as raw:
        mosaic = raw.raw_image.copy()
    return mosaic, json.loads((out / f"{source.stem}.json").read_text())


def expected_raw(spectra_hw, nm, light, kind="reflectance"):
    """The clean mosaic computed here from the tables: each pixel's spectrum put on the
    5 nm grid (np.interp, ends held), Σ curve · light · reflectance (or · radiance),
    over Σ curve_G · light; then levels, rounding and the white level."""
    prof = load_profile(PROFILE)
    curves = spectra.of_camera("Nikon D850").rgb
    h, w, n = spectra_hw.shape
    flat = spectra_hw.reshape(-1, n).astype(np.float64)
    grid = np.stack([np.interp(tables.WAVELENGTHS, nm, s) for s in flat])  # (HW, 81)
    seen = grid * light if kind == "reflectance" else grid
    rgb = (seen @ curves / (curves[:, 1] @ light)).reshape(h, w, 3)
    colors = np.array(CFA(prof.cfa.pattern).colors).reshape(2, 2)
    site = np.tile(colors, (h // 2, w // 2))
    v = np.take_along_axis(rgb, site[:, :, None], axis=2)[:, :, 0]
    dn = prof.black_level + v * (prof.white_level - prof.black_level)
    return np.minimum(np.rint(dn), prof.white_level)


def test_clean_raw_is_the_exact_integral(tmp_path):
    mosaic, meta = clean_raw(tmp_path, CHART)
    with np.load(CHART) as npz:
        expected = expected_raw(npz["spectra"], npz["wavelengths"], tables.illuminant("D65"))
    assert meta["params"]["wb_gains"][1] == 1 and min(meta["params"]["wb_gains"]) >= 1
    assert np.abs(mosaic - expected).max() <= 1
    assert (mosaic == expected).mean() > 0.99
    # the white reflector's green is the white level; the 18 % grey's green 18 % up
    assert mosaic[0, 1] == 16383
    assert mosaic[0, 9] == pytest.approx(400 + 0.18 * (16383 - 400), abs=1)


def test_reflectance_and_radiance_give_the_same_raw(tmp_path):
    refl = tables.training_reflectances()[:, :12].T.reshape(3, 4, 81).repeat(8, 0).repeat(8, 1)
    light = tables.illuminant("F11") * 3.5  # a radiance's units are the scene's own
    np.savez(tmp_path / "r.npz", spectra=refl, wavelengths=tables.WAVELENGTHS, illuminant="F11")
    np.savez(
        tmp_path / "e.npz",
        spectra=refl * light,
        wavelengths=tables.WAVELENGTHS,
        kind="radiance",
        illuminant=light,
    )
    a, meta_a = clean_raw(tmp_path, tmp_path / "r.npz", name="r")
    b, meta_b = clean_raw(tmp_path, tmp_path / "e.npz", name="e")
    assert np.abs(a.astype(int) - b).max() <= 1
    assert np.allclose(meta_a["spectral"]["neutral"], meta_b["spectral"]["neutral"])
    assert meta_b["spectral"]["kind"] == "radiance"
    assert meta_b["spectral"]["illuminant"]["name"] == "the scene's spectrum"
    assert np.array_equal(a, expected_raw(refl, tables.WAVELENGTHS, tables.illuminant("F11")))


def test_illuminant_from_a_file_equals_its_name(tmp_path):
    csv = tmp_path / "a.csv"
    csv.write_text(
        "nm,power\n"
        + "".join(
            f"{n:g},{p:.17g}\n"
            for n, p in zip(tables.WAVELENGTHS, tables.illuminant("A"), strict=True)
        )
    )
    named, meta_named = clean_raw(tmp_path, CHART, "--illuminant", "a", name="named")
    read, meta_read = clean_raw(tmp_path, CHART, "--illuminant", csv, name="file")
    assert np.array_equal(named, read)
    assert meta_named["spectral"]["illuminant"] == {
        "name": "A",
        "file": False,
        "origin": "--illuminant",
    }
    assert meta_read["spectral"]["illuminant"] == {
        "name": str(csv),
        "file": True,
        "origin": "--illuminant",
    }
    assert (
        "the scene carries its illuminant (D65); --illuminant A is used" in meta_named["warnings"]
    )
    with np.load(CHART) as npz:
        expected = expected_raw(npz["spectra"], npz["wavelengths"], tables.illuminant("A"))
    assert np.abs(named - expected).max() <= 1


def test_the_exr_scene_gives_the_npz_scenes_raw(tmp_path):
    exr = DATA / "spectral" / "chart.exr"
    a, _ = clean_raw(tmp_path, CHART, name="npz")
    b, meta = clean_raw(tmp_path, exr, name="exr")
    assert np.array_equal(a, b)
    assert meta["input_format"] == "OpenEXR (spectral)"
    assert meta["spectral"]["illuminant"]["origin"] == "scene"


def test_a_fichet_radiance_exr_gives_the_reflectances_raw(tmp_path):
    import OpenImageIO as oiio

    refl = tables.training_reflectances()[:, 20:32].T.reshape(3, 4, 81).repeat(8, 0).repeat(8, 1)
    light = tables.illuminant("D50")
    np.savez(tmp_path / "r.npz", spectra=refl, wavelengths=tables.WAVELENGTHS)
    exr = tmp_path / "e.exr"
    spec = oiio.ImageSpec(refl.shape[1], refl.shape[0], 81, oiio.FLOAT)
    spec.channelnames = tuple(f"S0.{nm:g},000000nm" for nm in tables.WAVELENGTHS[::-1])
    spec.attribute("illuminant", "d50")
    out = oiio.ImageOutput.create(str(exr))
    assert out.open(str(exr), spec)
    out.write_image(np.ascontiguousarray((refl * light)[:, :, ::-1], np.float32))
    out.close()
    a, _ = clean_raw(tmp_path, tmp_path / "r.npz", "--illuminant", "D50", name="r")
    b, meta = clean_raw(tmp_path, exr, name="e")
    assert np.abs(a.astype(int) - b).max() <= 1
    assert meta["spectral"]["kind"] == "radiance"
    assert meta["spectral"]["illuminant"] == {"name": "D50", "file": False, "origin": "scene"}


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("400nm", (400.0, None)),
        ("w455", (455.0, None)),
        ("550", (550.0, None)),
        ("S0.550,000000nm", (550.0, "S0")),
        ("T.412.5nm", (412.5, "T")),
        ("R", None),
        ("Y", None),
    ],
)
def test_exr_channel_spellings(name, expected):
    assert wavelength_of(name) == expected


def test_sidecar_records_the_curves_light_kind_and_wavelengths(tmp_path):
    _, meta = clean_raw(tmp_path, CHART, "--format", "both")
    with np.load(tmp_path / "out" / "chart.npz") as npz:
        assert json.loads(str(npz["metadata"])) == meta
    seen = meta["spectral"]
    assert meta["input_kind"] == "spectral" and meta["input_format"] == "NumPy npz (spectral)"
    assert seen["kind"] == "reflectance"
    assert seen["wavelengths"] == list(range(400, 701, 10))
    assert seen["curves"] == {
        "camera": "Nikon D850",
        "kind": "measured",
        "source": spectra.of_camera("Nikon D850").source,
    }
    assert seen["illuminant"] == {"name": "D65", "file": False, "origin": "scene"}
    curves = spectra.of_camera("Nikon D850").rgb
    light = tables.illuminant("D65")
    white = curves.T @ light
    assert np.allclose(seen["neutral"], white / white[1])
    assert np.allclose(meta["as_shot_neutral"], seen["neutral"])


def test_dng_colour_tags(tmp_path):
    exiftool = require_tool("exiftool")
    clean_raw(tmp_path, CHART, "--illuminant", "A")
    dng = tmp_path / "out" / "chart.clean.dng"
    tags = json.loads(
        subprocess.run(
            [
                exiftool,
                "-j",
                "-n",
                "-ColorMatrix1",
                "-ColorMatrix2",
                "-CalibrationIlluminant1",
                "-CalibrationIlluminant2",
                "-AsShotNeutral",
                str(dng),
            ],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    )[0]
    curves = spectra.of_camera("Nikon D850").rgb
    matrix = lambda text: np.array(text.split(), float).reshape(3, 3)  # noqa: E731
    assert tags["CalibrationIlluminant1"] == 17 and tags["CalibrationIlluminant2"] == 21
    a = fit.color_matrix(curves, tables.illuminant("A")).xyz_to_camera
    d65 = fit.color_matrix(curves, tables.illuminant("D65")).xyz_to_camera
    assert np.allclose(matrix(tags["ColorMatrix1"]), a, atol=1e-4)
    assert np.allclose(matrix(tags["ColorMatrix2"]), d65, atol=1e-4)
    white = curves.T @ tables.illuminant("A")
    assert np.allclose(np.array(tags["AsShotNeutral"].split(), float), white / white[1], atol=1e-4)


def test_libraw_and_rawsim_process_render_grey_neutral(tmp_path):
    clean_raw(tmp_path, CHART, "--illuminant", "F11")
    dng = tmp_path / "out" / "chart.clean.dng"
    with rawpy.imread(str(dng)) as raw:
        assert raw.raw_pattern.tolist() == [[0, 1], [3, 2]]
        rgb = raw.postprocess(use_camera_wb=True, no_auto_bright=True, gamma=(1, 1), output_bps=16)
    grey = rgb[2:6, 10:14].reshape(-1, 3).mean(axis=0)  # the 18 % patch, away from its edges
    assert np.ptp(grey) / grey.mean() < 0.01
    done = CliRunner().invoke(
        cli, ["process", str(dng), "-o", str(tmp_path / "p"), "--format", "tiff"]
    )
    assert done.exit_code == 0, done.output
    import OpenImageIO as oiio

    rendered = oiio.ImageBuf(str(tmp_path / "p" / "chart.clean.tif")).get_pixels(oiio.FLOAT)
    grey = rendered[2:6, 10:14].reshape(-1, 3).mean(axis=0)
    assert np.ptp(grey) < 0.01


def test_same_seed_same_bytes(tmp_path):
    for name in ("a", "b"):
        unprocess(CHART, "-o", tmp_path / name, "-p", PROFILE, "--iso", 3200, "--seed", 7)
    first = (tmp_path / "a" / "chart.dng").read_bytes()
    assert first == (tmp_path / "b" / "chart.dng").read_bytes()
    unprocess(CHART, "-o", tmp_path / "c", "-p", PROFILE, "--iso", 3200, "--seed", 8)
    assert first != (tmp_path / "c" / "chart.dng").read_bytes()


def _scene(tmp_path, name, **arrays):
    path = tmp_path / f"{name}.npz"
    np.savez(path, **arrays)
    return path


def test_bad_scenes_are_refused_and_the_batch_goes_on(tmp_path):
    good = np.full((4, 4, 31), 0.5, np.float32)
    nm = np.arange(400, 701, 10.0)
    nan = good.copy()
    nan[1, 2, 3] = np.nan
    bad = {
        "narrow": dict(spectra=good[:, :, :21], wavelengths=nm[5:26]),
        "nan": dict(spectra=nan, wavelengths=nm),
        "negative": dict(spectra=-good, wavelengths=nm),
        "radiance": dict(spectra=good, wavelengths=nm, kind="radiance"),
        "nospectra": dict(mosaic=good),
        "mismatch": dict(spectra=good, wavelengths=nm[:-1]),
    }
    paths = [_scene(tmp_path, k, **v) for k, v in bad.items()]
    paths.append(tmp_path / "text.npz")
    paths[-1].write_text("no zip")
    ok = _scene(tmp_path, "ok", spectra=good, wavelengths=nm)
    done = unprocess(*paths, ok, "-o", tmp_path / "out", "-p", PROFILE, "--iso", 100, ok=False)
    assert done.exit_code == 1, done.output
    assert (tmp_path / "out" / "ok.dng").is_file()
    said = {line.split(".npz:")[0].rsplit("/", 1)[-1]: line for line in done.output.splitlines()}
    assert "(450–650 nm) do not cover 400–700 nm" in said["narrow"]
    assert "1 pixel(s) hold NaN or infinite values" in said["nan"]
    assert "negative values" in said["negative"]
    assert "a radiance scene needs its illuminant" in said["radiance"]
    assert "holds no 'spectra' or 'wavelengths'" in said["nospectra"]
    assert "do not match" in said["mismatch"]
    assert "not an npz (no zip archive)" in said["text"]
    assert "1 done, 0 skipped, 7 failed" in done.output


def test_a_camera_without_curves_is_refused(tmp_path):
    """A phone outside the database has neither measured nor estimated curves."""
    done = unprocess(CHART, "-o", tmp_path, "-p", "oppo_reno10x", "--iso", 100, ok=False)
    assert done.exit_code == 1
    line = next(x for x in done.output.splitlines() if "spectral sensitivities" in x)
    assert "oppo_reno10x" in line and "Canon EOS 100D" in line and "more" in line
    assert not list(tmp_path.glob("*.dng"))


def test_randomize_and_mono_are_refused(tmp_path):
    for flag in (["--randomize"], ["--sensor", "mono"]):
        done = unprocess(CHART, "-o", tmp_path, "-p", PROFILE, "--iso", 100, *flag, ok=False)
        assert done.exit_code == 1 and f"{flag[0]}" in done.output


def test_a_bad_illuminant_is_a_usage_error(tmp_path):
    done = unprocess(
        CHART, "-o", tmp_path, "-p", PROFILE, "--iso", 100, "--illuminant", "D93", ok=False
    )
    assert done.exit_code == 2 and "'--illuminant'" in done.output


def test_an_illuminant_for_an_rgb_image_says_it_is_not_used(tmp_path):
    photo = DATA / "srgb" / "chelsea.png"
    done = unprocess(photo, "-o", tmp_path, "-p", PROFILE, "--iso", 100, "--illuminant", "A")
    assert "--illuminant A lights spectral scenes only" in done.output
    side = json.loads((tmp_path / "chelsea.json").read_text())
    assert any("--illuminant A" in w for w in side["warnings"])


def test_read_spectral_crops_to_even(tmp_path):
    path = _scene(tmp_path, "odd", spectra=np.ones((5, 7, 3)), wavelengths=[380.0, 550, 780])
    scene = read_spectral(path)
    assert scene.spectra.shape == (4, 6, 3) and scene.source_size == (7, 5)
    assert scene.kind == "reflectance" and scene.illuminant is None


def test_a_seed_configs_spectral_responses_are_used(tmp_path):
    nm = np.arange(400, 701, 10.0)
    bell = lambda c, w: np.exp(-0.5 * ((nm - c) / w) ** 2).tolist()  # noqa: E731
    seed = tmp_path / "seed.json"
    seed.write_text(
        json.dumps(
            {
                "bit": 12,
                "black_level": 256,
                "bayer_pattern": "rggb",
                "wavelengths": nm.tolist(),
                "red_spectral_response": bell(600, 30),
                "green_spectral_response": bell(530, 35),
                "blue_spectral_response": bell(460, 25),
            }
        )
    )
    unprocess(CHART, "-o", tmp_path, "-p", seed, "--iso", 100, "--noise", "none")
    meta = json.loads((tmp_path / "chart.json").read_text())
    assert "red/green/blue_spectral_response" in meta["spectral"]["curves"]["source"]
    assert not any("no colour matrix" in w for w in meta["warnings"])  # the curves give it
    curves = tables.resample(nm, np.column_stack([bell(600, 30), bell(530, 35), bell(460, 25)]), "")
    white = curves.T @ tables.illuminant("D65")
    assert np.allclose(meta["spectral"]["neutral"], white / white[1])


def test_the_torch_reference_sees_what_the_engine_sees():
    """The whole spectral path twice: the compiled integral then the engine, and the
    torch reference's integral (a float64 einsum) then the torch reference."""
    from rawsim.pipelines.unprocess import UnprocessOptions, simulate
    from rawsim.spectral import render

    scene = read_spectral(CHART)
    curves = spectra.of_camera("Nikon D850")
    light = tables.illuminant("A")
    camera = (render.dng_matrices(curves)[1], 1 / render.neutral(curves.rgb, light))
    options = UnprocessOptions(load_profile(PROFILE), iso=800, clean=True, exposure_ev=-0.5)
    sims = []
    for engine in (True, False):
        rgb = render.camera_rgb(
            scene.spectra, scene.wavelengths, curves.rgb, light, "reflectance", engine=engine
        )
        sims.append(
            simulate(None, rgb, options, 3, display_referred=False, engine=engine, camera=camera)
        )
    clean = [s.codes(s.clean).astype(int) for s in sims]
    assert np.abs(clean[0] - clean[1]).max() <= 1
    noisy = [s.codes(s.noisy).astype(int) for s in sims]  # the same draws, bit for bit
    assert np.abs(noisy[0] - noisy[1]).max() <= 1
    assert sims[0].params.wb_gains == pytest.approx(tuple(camera[1]))


def _within_an_ulp(a: np.ndarray, b: np.ndarray) -> bool:
    return bool((np.abs(a - b) <= np.spacing(np.maximum(np.abs(a), np.abs(b)))).all())


@pytest.mark.parametrize(
    "shape, crop",
    [((6, 200, 31), None), ((7, 131, 5), (slice(0, 6), slice(1, 130))), ((4, 64, 81), None)],
    ids=["31 bands", "5 bands, a cropped view", "81 bands, one block"],
)
def test_the_integral_kernel_equals_the_torch_reference(shape, crop):
    """:func:`rawsim.engine.spectral.integral_kernel` against
    :func:`rawsim.spectral.render.integrate` and numpy's float64 matmul: the same float64
    sums to rounding, so within one float32 ulp (almost always the same bits); any
    strides, a width that is no whole number of blocks; the same bits on any threads."""
    from rawsim.engine.spectral import camera_rgb
    from rawsim.spectral.render import integrate
    from tests.conftest import numba_threads, thread_counts

    rng = np.random.default_rng(4)
    scene = rng.random(shape, dtype=np.float32)
    if crop is not None:
        scene = scene[crop]
        assert not scene.flags.c_contiguous
    weights = rng.normal(size=(shape[2], 3))
    ours = camera_rgb(scene, weights)
    assert ours.shape == (*scene.shape[:2], 3) and ours.dtype == np.float32
    reference = integrate(scene, weights).numpy()
    n = scene.shape[2]
    by_hand = (scene.reshape(-1, n).astype(np.float64) @ weights).astype(np.float32)
    assert _within_an_ulp(ours, reference)
    assert _within_an_ulp(ours, by_hand.reshape(ours.shape))
    assert np.mean(ours != reference) < 0.01
    for threads in thread_counts():
        with numba_threads(threads):
            assert np.array_equal(camera_rgb(scene, weights), ours)


def _mapping(array: np.ndarray) -> np.memmap | None:
    """The memory map ``array`` is a view of, or None."""
    while array is not None and not isinstance(array, np.memmap):
        array = array.base if isinstance(array.base, np.ndarray) else None
    return array


def test_an_uncompressed_npz_is_mapped_and_read_as_np_load_reads_it(tmp_path):
    """``np.savez``'s scene is mapped from the file (read-only, no copy; cropped to even
    in place), any order; a compressed one, a float64 one and a Fortran-ordered one
    read the same values."""
    rng = np.random.default_rng(1)
    data = rng.random((9, 13, 31), dtype=np.float32)
    nm = np.arange(400, 701, 10.0)
    stored = _scene(tmp_path, "stored", spectra=data, wavelengths=nm, kind="reflectance")
    scene = read_spectral(stored)
    assert _mapping(scene.spectra) is not None and not scene.spectra.flags.writeable
    assert scene.spectra.dtype == np.float32 and scene.spectra.shape == (8, 12, 31)
    assert np.array_equal(scene.spectra, data[:8, :12])
    assert scene.source_size == (13, 9) and scene.kind == "reflectance"
    compressed = tmp_path / "compressed.npz"
    np.savez_compressed(compressed, spectra=data, wavelengths=nm)
    fortran = _scene(tmp_path, "fortran", spectra=np.asfortranarray(data), wavelengths=nm)
    wide = _scene(tmp_path, "float64", spectra=data.astype(np.float64), wavelengths=nm)
    for path in (compressed, fortran, wide):
        other = read_spectral(path)
        assert other.spectra.dtype == np.float32 and not other.spectra.flags.writeable
        assert np.array_equal(other.spectra, scene.spectra), path.name
    assert _mapping(read_spectral(fortran).spectra) is not None


def test_a_truncated_npz_member_is_refused(tmp_path):
    """A stored member whose bytes end before its header says: one line, no crash."""
    import io
    import zipfile

    def npy(array: np.ndarray) -> bytes:
        buffer = io.BytesIO()
        np.lib.format.write_array(buffer, array)
        return buffer.getvalue()

    short = tmp_path / "bad.npz"
    with zipfile.ZipFile(short, "w") as archive:  # stored, as np.savez writes
        archive.writestr("spectra.npy", npy(np.full((4, 4, 31), 0.5, np.float32))[:-100])
        archive.writestr("wavelengths.npy", npy(np.arange(400, 701, 10.0)))
    done = unprocess(short, "-o", tmp_path / "out", "-p", PROFILE, "--iso", 100, ok=False)
    assert done.exit_code != 0
    assert "bad.npz" in done.output and "truncated" in done.output


def test_a_truncated_exr_is_refused(tmp_path):
    """An EXR cut short (its strips read one after another): one line, no crash."""
    from rawsim.errors import UnsupportedInputError

    data = CHART.with_suffix(".exr").read_bytes()
    short = tmp_path / "short.exr"
    short.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(UnsupportedInputError, match="short.exr: cannot decode pixels"):
        read_spectral(short)


def test_one_spectral_file_imports_no_torch(tmp_path):
    """The installed command sees a spectral scene on the engine (the integral's kernel,
    then the unprocess kernel) without importing torch."""
    from tests.conftest import installed_command_imports

    args = ("-q", "unprocess", CHART, "-o", tmp_path / "out", "-p", PROFILE, "--iso", "400")
    imported = installed_command_imports(*args)
    assert "rawsim.engine.spectral" in imported and "rawsim.engine.unprocess" in imported
    assert "torch" not in imported
    assert (tmp_path / "out" / "chart.dng").is_file()


@pytest.mark.slow
def test_rawsim_compile_builds_what_a_spectral_scene_needs(tmp_path, monkeypatch):
    """After ``rawsim compile``'s tasks for spectral scenes (and the linear EXR's, which
    they wait for) in an empty cache, unprocessing an npz, a compressed npz, an EXR and
    a scene of odd size (read with strides) compiles no kernel."""
    from rawsim_cli import compile as rc

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    folders = {"in": tmp_path / "in", "out": tmp_path / "out"}
    rc._inputs(folders["in"])
    tasks = {name: args for name, _, args in rc.TASKS}
    assert rc.LINEAR in dict((n, needs) for n, needs, _ in rc.TASKS)["unprocess: spectral scenes"]
    rc._run(tasks[rc.LINEAR], folders)
    _, kernels = rc._run(tasks["unprocess: spectral scenes"], folders)
    assert "engine.spectral.integral_kernel" in kernels
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    with np.load(CHART) as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez_compressed(scenes / "compressed.npz", **arrays)
    arrays["spectra"] = arrays["spectra"][:47, :63]
    np.savez(scenes / "odd.npz", **arrays)
    for source in (CHART, CHART.with_suffix(".exr"), scenes):
        run = subprocess.run(
            ["rawsim", "unprocess", source, "-o", tmp_path / "seen", "-p", PROFILE, "--iso", "400"]
            + ["--overwrite"],
            capture_output=True,
            text=True,
        )
        assert run.returncode == 0, run.stderr
        assert "compiling" not in run.stderr, run.stderr


def test_the_python_api_gives_the_cli_capture(tmp_path):
    """rawsim.unprocess_spectral: the same noisy and clean mosaics as the command on
    the same scene and seed, bit for bit, and the sidecar's spectral record."""
    import rawsim

    with np.load(CHART) as npz:
        spectra, nm = npz["spectra"], npz["wavelengths"]
    sensor = rawsim.RGBSensor(rawsim.load_profile(PROFILE))
    seed = rawsim.file_seed(5, "chart.npz")
    noisy, clean, meta = rawsim.unprocess_spectral(
        spectra, nm, sensor, seed, iso=800, illuminant="D65"
    )
    unprocess(CHART, "-o", tmp_path, "-p", PROFILE, "--iso", 800, "--seed", 5, "--clean")
    for name, ours in (("chart.dng", noisy), ("chart.clean.dng", clean)):
        with rawpy.imread(str(tmp_path / name)) as raw:
            assert np.array_equal(ours[0, 0].numpy(), raw.raw_image_visible), name
    side = json.loads((tmp_path / "chart.json").read_text())["spectral"]
    assert meta["spectral"]["curves"] == side["curves"]
    assert meta["spectral"]["color_matrix_2"] == side["color_matrix_2"]
    with pytest.raises(rawsim.ParameterError, match="one wavelength per band"):
        rawsim.unprocess_spectral(spectra, nm[:-1], sensor, seed)
    for value, why in ((np.nan, "NaN or infinite"), (-0.5, "negative values")):
        bad = spectra.copy()
        bad[3, 4, 10] = value
        with pytest.raises(rawsim.RawsimError, match=f"spectra: 1 pixel\\(s\\) hold {why}"):
            rawsim.unprocess_spectral(bad, nm, sensor, seed, iso=800)
