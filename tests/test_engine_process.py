"""The compiled process engine against the torch reference: every demosaic, every CFA
pattern, every stage option, tile sizes, thread counts, orientations; and real raws.

16-bit outputs must agree within 1 code value, float outputs within 1e-5, with
highlights clipped (:func:`base_config`): the default, ``reconstruct``, agrees as
closely except at the sites it rebuilds, which the engine rounds to whole DN
(tests/test_highlights_reconstruct.py bounds those); ``unclip``, which the engine also
runs on the mosaic before the kernels, within the rounding of the sites it raises
(:data:`ROUNDED`).
"""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from rawsim.cfa import BAYER_PATTERNS, CFA
from rawsim.io.images import to_samples
from rawsim.io.raw import RawImage, read_raw
from rawsim.isp.config import DEMOSAIC_METHODS, default_config, override
from rawsim.pipelines.process import ProcessOptions, engine_plan, engine_render, render
from tests.conftest import DATA, installed_command_imports, numba_threads, thread_counts

XYZ_TO_CAMERA = np.array(
    [[0.5271, -0.0712, -0.0347], [-0.6153, 1.4814, 0.1324], [-0.0881, 0.2174, 0.8169]]
)


def synthetic_raw(pattern="RGGB", h=78, w=142, orientation=1, seed=0) -> RawImage:
    """A 14-bit mosaic with edges, texture, noise and clipped highlights; per-site black
    (per colour for patterns other than Bayer, as LibRaw gives them)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    scene = 0.35 + 0.25 * np.sin(x / 5.0) * np.cos(y / 7.0) + 0.3 * ((x + 2 * y) % 37 < 9)
    scene += 0.5 * ((x - w / 2) ** 2 + (y - h / 2) ** 2 < (h / 5) ** 2)  # a clipped disc
    cfa = CFA(pattern)
    if cfa.is_bayer:
        black = np.array([[512.0, 514.0], [510.0, 516.0]])
    else:
        black = np.array([512.0, 514.0, 510.0])[np.array(cfa.colors)].reshape(cfa.period)
    dn = 512 + scene * 15000 + rng.normal(0, 30, (h, w))
    return RawImage(
        data=np.clip(np.round(dn), 0, 16383).astype(np.uint16),
        cfa=cfa,
        black_level=black,
        white_level=16383.0,
        as_shot_wb=(2.1, 1.0, 1.6),
        daylight_wb=(2.0, 1.0, 1.5),
        xyz_to_camera=XYZ_TO_CAMERA,
        camera_to_srgb=None,
        orientation=orientation,
        iso=100.0,
        make="test",
        model="synthetic",
        path="<synthetic>",
    )


def base_config() -> list[dict]:
    """The default config with highlights clipped, as the matrix holds it."""
    return override(default_config(), highlights="clip")


def _both(raw, config, fmt="tiff", bits=16, tile=None):
    config = ProcessOptions(config, fmt, bits).effective_config()
    plan = engine_plan(raw, config, fmt)
    assert plan is not None, "the engine should cover this config"
    ours = engine_render(raw, plan, fmt, bits, tile)
    ref, info = render(raw, config)
    assert plan.info == info
    return ours, to_samples(ref[0], fmt, bits)


#: Tolerances (16-bit codes, floats) where the engine's highlight pre-pass rounds the
#: values it raises to whole DN (``unclip``): half a DN × the largest gain (2.1 / 15 867
#: of white here, 6.6e-5), carried through the demosaic, the colour matrix and the
#: output curve's slope (up to 3 codes where a half-size pixel is one block's sites);
#: the usual one code and 1e-5 elsewhere.
ROUNDED = (4, 2.5e-4)


def _assert_close(ours, ref, tolerance=(1, 1e-5)):
    """``ours`` and ``ref`` alike, within ``tolerance`` (16-bit codes, floats)."""
    codes, floats = tolerance
    assert ours.shape == ref.shape and ours.dtype == ref.dtype
    if ours.dtype.kind == "f":
        diff = np.abs(ours.astype(np.float64) - ref)
        assert diff.max() <= floats, float(diff.max())
    else:
        diff = np.abs(ours.astype(np.int64) - ref)
        assert diff.max() <= codes, (int(diff.max()), np.argwhere(diff > codes)[:5].tolist())
        assert (diff > 1).mean() < 1e-3, float((diff > 1).mean())


@pytest.mark.parametrize("pattern", BAYER_PATTERNS)
@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
def test_every_demosaic_and_pattern(method, pattern):
    raw = synthetic_raw(pattern)
    config = override(base_config(), demosaic=method)
    _assert_close(*_both(raw, config))  # display-referred 16-bit codes
    _assert_close(*_both(raw, config, "exr", 32))  # scene-linear floats


#: Patterns other than Bayer: X-Trans, and a 3×3 layout (every periodic R/G/B CFA).
PERIODIC = ("XTRANS", "GRG/BGB/GRG")


@pytest.mark.parametrize("pattern", PERIODIC)
@pytest.mark.parametrize("method", ["bilinear", "wcd"])  # wcd is icd on these patterns
def test_periodic_patterns(method, pattern):
    raw = synthetic_raw(pattern, h=83, w=151)  # not whole periods: ragged tiles, edges
    for changes in (
        {},
        dict(highlights="blend", wb="auto"),
        dict(highlights="unclip"),
        dict(tone="aces", exposure=1.5),
    ):
        config = override(base_config(), demosaic=method, **changes)
        tolerance = ROUNDED if changes.get("highlights") == "unclip" else (1, 1e-5)
        _assert_close(*_both(raw, config), tolerance)
        _assert_close(*_both(raw, config, "exr", 32), tolerance)


@pytest.mark.parametrize("orientation", [1, 6, 3])
def test_xtrans_orientation_shading_and_tiles(orientation):
    """X-Trans with lens shading on the mosaic (site by site, no table), every tile
    size and thread count: the reference's values and the same bits."""
    raw = synthetic_raw("XTRANS", h=90, w=130, orientation=orientation)
    config = override(base_config(), demosaic="wcd")
    shading = next(s for s in config if s["name"] == "lens_shading")
    shading["enabled"] = True
    config.insert(1, config.pop(config.index(shading)))  # before the demosaic
    base, ref = _both(raw, config)
    _assert_close(base, ref)
    plan = engine_plan(raw, config, "tiff")
    for tile in ((6, 6), (12, 30), (96, 504)):
        for n in thread_counts():
            with numba_threads(n):
                assert np.array_equal(engine_render(raw, plan, "tiff", 16, tile), base)


def test_xtrans_black_that_differs_within_a_colour_falls_back():
    raw = synthetic_raw("XTRANS")
    black = raw.black_level.copy()
    black[0, 0] += 1  # one green site of the period
    assert engine_plan(replace(raw, black_level=black), base_config(), "tiff") is None
    assert engine_plan(replace(raw, data=raw.data[:17]), base_config(), "tiff") is None


OPTIONS = [
    dict(tone="reinhard"),
    dict(tone="aces", exposure=1.5),
    dict(tone="hable", transfer="gamma:2.2"),
    dict(tone="hable", tone_exposure=1.0, tone_white=4.0),
    dict(tone="reinhard", tone_exposure=4.0, tone_white=12.0),
    dict(tone="aces", tone_white=0.25, transfer="gamma:2.2", tone_exposure=2.0),
    dict(transfer="gamma:1.8"),
    dict(highlights="blend", demosaic="menon"),
    dict(highlights="unclip", demosaic="wcd"),
    dict(wb="daylight", output_space="xyz"),
    dict(wb="1.5,1,2.5", output_space="camera", exposure=-1),
    dict(wb="auto"),
    # output spaces, each with its own transfer (table: sRGB, BT.2020, ROMM curves;
    # kernel power law: Adobe RGB's 563/256), and transfers other than the space's own
    dict(output_space="display-p3"),
    dict(output_space="adobe-rgb"),
    dict(output_space="rec2020", tone="aces"),
    dict(output_space="prophoto", highlights="blend"),
    dict(output_space="prophoto", transfer="bt2020"),
    dict(output_space="xyz", transfer="romm"),
    dict(output_space="adobe-rgb", transfer="linear", tone="hable"),
    dict(output_space="rec2020", transfer="gamma:563/256"),
    dict(transfer="bt2020", exposure=1.0),
]


@pytest.mark.parametrize(
    "changes", OPTIONS, ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items())
)
def test_every_stage_option(changes):
    raw = synthetic_raw("GBRG")
    config = override(base_config(), **changes)
    tolerance = ROUNDED if changes.get("highlights") == "unclip" else (1, 1e-5)
    _assert_close(*_both(raw, config), tolerance)
    _assert_close(*_both(raw, config, "png", 8), tolerance)


@pytest.mark.parametrize("mode", ["clip", "unclip", "blend"])
def test_a_colour_that_saturates_below_white(mode):
    """Green saturates at 96 % of the white level (its sites pile up there): both
    backends clip, unclip and blend at the levels the data give, alike; ``clip`` and
    ``unclip`` leave what clipped in every colour neutral."""
    raw = synthetic_raw("GRBG")
    green = np.asarray(raw.cfa.color_map(*raw.data.shape)).reshape(raw.data.shape) == 1
    data = np.where(green, np.minimum(raw.data, 15750), raw.data).astype(np.uint16)
    raw = replace(raw, data=data)
    config = override(base_config(), highlights=mode)
    tolerance = ROUNDED if mode == "unclip" else (1, 1e-5)
    ours, ref = _both(raw, config, "exr", 32)
    _assert_close(ours, ref, tolerance)
    _assert_close(*_both(raw, config), tolerance)
    if mode == "clip":
        disc = ours[43:46, 66:72].reshape(-1, 3)  # every site around clipped
        assert np.abs(disc - disc[:, 1:2]).max() < 0.01, "the blown disc has a cast"
    if mode == "unclip":
        # unclip acts on the mosaic: each 2 × 2 block of the band across the disc that
        # clipped in every colour is neutral, as a half-size render (a pixel per block)
        # shows (the full-size demosaic reaches past this narrow band into the orange
        # beside it)
        half = override(config, demosaic="half")
        ours, ref = _both(raw, half, "exr", 32)
        _assert_close(ours, ref, tolerance)
        band = ours[21:23, 32:37].reshape(-1, 3)  # sites [42:46, 64:74]
        assert np.abs(band - band[:, 1:2]).max() < 1e-3, "the blown band has a cast"


def test_float_outputs_half_and_exr_config():
    raw = synthetic_raw("BGGR")
    _assert_close(*_both(raw, override(base_config(), exposure=2), "exr", 32))
    ours, ref = _both(raw, base_config(), "exr", 16)
    assert ours.dtype == np.float16
    assert np.abs(ours.astype(np.float64) - ref).max() <= 1e-3  # one half-float step near 1


def test_stage_order_and_optional_stages():
    """Lens shading and white balance on either side of the demosaic, in a custom order."""
    config = base_config()
    names = [s["name"] for s in config]
    shading = config.pop(names.index("lens_shading"))
    shading["enabled"] = True
    wb = next(s for s in config if s["name"] == "white_balance")
    config.remove(wb)
    at = next(i for i, s in enumerate(config) if s["name"] == "demosaic") + 1
    config[at:at] = [wb, shading]
    raw = synthetic_raw("GRBG")
    _assert_close(*_both(raw, config))
    shading["strength"] = 0.5
    config.insert(1, config.pop(config.index(shading)))  # before the demosaic
    _assert_close(*_both(raw, config))


@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientations(orientation):
    raw = synthetic_raw("RGGB", orientation=orientation)
    _assert_close(*_both(raw, override(base_config(), demosaic="bilinear")))


@pytest.mark.parametrize("tile", [(2, 2), (6, 18), (16, 64), (64, 512)])
def test_tile_sizes_and_threads_give_identical_bits(tile):
    """Every tile size and thread count gives the same bits (learned, wcd and menon,
    ragged edges)."""
    raw = synthetic_raw("GBRG", h=70, w=94)
    for method in ("learned", "wcd", "menon"):
        config = override(base_config(), demosaic=method)
        plan = engine_plan(raw, config, "tiff")
        base = engine_render(raw, plan, "tiff", 16)
        for n in thread_counts():
            with numba_threads(n):
                assert np.array_equal(engine_render(raw, plan, "tiff", 16, tile), base)


def test_reference_only_configs_fall_back():
    raw = synthetic_raw()
    config = base_config()
    for stage in config:
        if stage["name"] == "denoise":
            stage["enabled"] = True
    assert engine_plan(raw, config, "tiff") is None
    assert engine_plan(replace(raw, data=raw.data[:8, :8]), base_config(), "tiff") is None


def test_smoothstep_clips_outside_its_domain_in_both():
    """Smoothstep is defined on [0, 1]: both forms clip there (ordinary photos reach
    beyond white) and agree."""
    raw = synthetic_raw()
    config = override(base_config(), tone="smoothstep", exposure=2.0)
    ours, ref = _both(raw, config)
    assert (ours == 65535).any()  # values beyond white reached the curve
    _assert_close(ours, ref)


@pytest.mark.parametrize("name", ["canon_eos60d_mlv.dng", "synthetic_colorchecker_bggr.dng"])
def test_real_raws(name):
    raw = read_raw(DATA / "raw" / name)
    for method in DEMOSAIC_METHODS:
        _assert_close(*_both(raw, override(base_config(), demosaic=method)))


def test_installed_command_starts_lean(tmp_path):
    """A one-file `rawsim process` through the installed console script starts without
    torch and without numba's BLAS probe (``scipy.linalg``): the script enters through
    ``main``, which sets that up, not through the bare click group."""
    dng = DATA / "raw" / "canon_eos60d_mlv.dng"
    imported = installed_command_imports("-q", "process", dng, "-o", tmp_path, "--format", "tiff")
    assert "rawsim.engine" in imported
    assert "torch" not in imported and "scipy.linalg" not in imported
    assert (tmp_path / "canon_eos60d_mlv.tif").is_file()


def test_cold_command_reads_while_the_engine_loads_and_skips_the_blas_probe(tmp_path):
    """The command's own start: the raw is read in a thread while numba loads (the same
    raw as a plain read), numba is imported without ``scipy.linalg``, which still
    imports normally afterwards, and the output is what an in-process render gives."""
    dng = DATA / "raw" / "canon_eos60d_mlv.dng"
    code = (
        "import sys\n"
        "import numpy as np\n"
        "import rawsim.engine\n"
        "from rawsim.io.raw import read_raw\n"
        "from rawsim.pipelines.process import _read_while_loading_engine\n"
        "rawsim.engine.lean_start = True\n"
        f"raw = _read_while_loading_engine({str(dng)!r}, 'cpu')\n"
        "assert 'rawsim.engine.process' in sys.modules and 'numba' in sys.modules\n"
        "assert 'scipy.linalg' not in sys.modules\n"
        f"plain = read_raw({str(dng)!r})\n"
        "assert np.array_equal(raw.data, plain.data) and raw.iso == plain.iso\n"
        "import scipy.linalg\n"
        "assert scipy.linalg.cython_blas is not None\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    done = subprocess.run(
        [
            "rawsim",
            "-q",
            "process",
            str(dng),
            "-o",
            str(tmp_path),
            "--format",
            "tiff",
            "--bits",
            "16",
        ],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    assert "1 done" in done.stderr  # the summary reaches the pipe before the fast exit
    raw = read_raw(dng)
    config = ProcessOptions(base_config(), "tiff", 16).effective_config()
    ours = engine_render(raw, engine_plan(raw, config, "tiff"), "tiff", 16)
    import tifffile

    assert np.array_equal(tifffile.imread(tmp_path / "canon_eos60d_mlv.tif"), ours)


@pytest.mark.parametrize("fmt,bits", [("tiff", 16), ("png", 8), ("exr", 32)])
def test_a_batch_renders_into_the_last_files_output_as_into_a_new_one(fmt, bits):
    """engine_render(reuse=True) writes every sample of the array release() gave back:
    a render over another image's output equals a render into a new array."""
    from rawsim.pipelines.process import _spare, release

    config = ProcessOptions(base_config(), fmt, bits).effective_config()
    raws = [synthetic_raw(seed=1), synthetic_raw("GBRG", seed=2), synthetic_raw(orientation=6)]
    raws.append(raws[0])  # after a rotated one: the spare does not fit it
    plans = [engine_plan(raw, config, fmt) for raw in raws]
    fresh = [engine_render(raw, plan, fmt, bits) for raw, plan in zip(raws, plans, strict=True)]
    _spare.clear()
    for raw, plan, expected in zip(raws, plans, fresh, strict=True):
        samples = engine_render(raw, plan, fmt, bits, reuse=True)
        assert np.array_equal(samples, expected)
        release(samples)
    assert len(_spare) == 1
    again = engine_render(raws[0], plans[0], fmt, bits, reuse=True)
    assert (again is samples) == (bits != 8)  # 8-bit samples are a copy of the kernel's codes
    _spare.clear()
