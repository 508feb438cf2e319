"""Dark shading and black-level error (issue 30): the profile's maps, their draws in
``unprocess --noise physics``, and their calibration from dark frames."""

import json
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from rawsim.cameras.dark_calibration import accumulate, frames_needed
from rawsim.cameras.profiles import load_profile
from rawsim.errors import ParameterError, ProfileError
from rawsim.io.raw import read_raw
from rawsim.io.task import Task
from rawsim.noise.dark_shading import write_maps
from rawsim.noise.models import dark_draw
from rawsim.pipelines.unprocess import UnprocessOptions, noise_key, unprocess_file
from rawsim.sensors import RGBSensor
from rawsim_cli.main import cli
from tests.test_calibrate import _write

BASE = "canon_eos_70d"
#: Two gain ranges, as a dual conversion gain sensor has (the switch at ISO 800).
RANGES = [(100.0, 799.0), (800.0, 12800.0)]
#: σ of the test maps' k (DN/ISO) and b (DN) per gain range.
K_SIGMA, B_SIGMA = (0.045, 0.02), (10.0, 25.0)
#: σ (DN) of the black-level error at ISO 100 and 12800.
BLE = (1.0, 8.0)


def make_maps(h: int, w: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(k, b), each (2, h, w): per-pixel noise plus column and row structure, as real
    dark shading has (PMN's maps show both)."""
    rng = np.random.default_rng(seed)
    maps = []
    for sigmas in (K_SIGMA, B_SIGMA):
        m = rng.normal(size=(2, h, w)) + rng.normal(size=(2, 1, w)) + rng.normal(size=(2, h, 1))
        maps.append(m / math.sqrt(3) * np.array(sigmas)[:, None, None])
    return maps[0], maps[1]


def dark_profile(folder: Path, h: int, w: int, base: str = BASE) -> Path:
    """A copy of ``base`` whose physics model carries test maps (h × w, two gain ranges)
    and a black-level error, written to ``folder``."""
    data = json.loads(Path(load_profile(base).path).read_text())
    k, b = make_maps(h, w)
    write_maps(folder / "test.dark.npz", RANGES, k, b, data["cfa_pattern"])
    data["noise"]["dark_shading"] = {
        "file": "test.dark.npz",
        "iso_ranges": [list(r) for r in RANGES],
        "size": [h, w],
    }
    data["noise"]["black_level_error"] = {"iso": [100, 12800], "sigma": list(BLE)}
    data["source"]["noise.dark_shading"] = "test maps (tests/test_dark_shading.py)"
    data["source"]["noise.black_level_error"] = "test figures (tests/test_dark_shading.py)"
    path = folder / "dark.json"
    path.write_text(json.dumps(data))
    return path


def test_profile_maps_load_lazily_and_validate(tmp_path):
    path = dark_profile(tmp_path, 40, 60)
    profile = load_profile(path)
    shading = profile.noise.dark_shading
    assert shading.size == (40, 60) and shading.iso_ranges == tuple(RANGES)
    assert [shading.range_index(i) for i in (50, 100, 799, 800, 900, 99999)] == [0, 0, 0, 1, 1, 1]
    k, b = shading.maps(1600)
    truth = make_maps(40, 60)
    step = [(m[1].max() - m[1].min()) / 65535 for m in truth]  # uint16 codes
    assert np.abs(k - truth[0][1]).max() <= step[0] * 0.51 + 1e-7
    assert np.abs(b - truth[1][1]).max() <= step[1] * 0.51 + 1e-5
    assert shading.maps(1600)[0] is k  # cached
    assert profile.noise.black_level_error(100) == BLE[0]
    assert profile.to_dict()["noise"]["dark_shading"]["file"] == "test.dark.npz"
    # Levels of other models carry none of it; the physics model's do.
    assert not profile.noise.levels("poisson-gaussian", 1600).has_dark
    levels = profile.noise.levels("physics", 6450)
    assert levels.has_dark and levels.black_level_sigma == pytest.approx(4.5)
    # A map file that is missing, a profile that lacks a source: errors name file and key.
    (tmp_path / "test.dark.npz").rename(tmp_path / "moved.npz")
    with pytest.raises(ProfileError, match="map file not found"):
        load_profile(path).noise.dark_shading.maps(100)
    data = json.loads(path.read_text())
    del data["source"]["noise.black_level_error"]
    path.write_text(json.dumps(data))
    with pytest.raises(ProfileError, match="noise.black_level_error"):
        load_profile(path)


def test_crop_is_seeded_cfa_aligned_and_a_larger_image_is_refused(tmp_path):
    profile = load_profile(dark_profile(tmp_path, 80, 122))
    levels = profile.noise.levels("physics", 1600)
    draws = [dark_draw(levels, s, 64, 96, profile.cfa) for s in range(1000)]
    tops, lefts = {d.top for d in draws}, {d.left for d in draws}
    assert tops == set(range(0, 17, 2)) and lefts == set(range(0, 27, 2))
    assert dark_draw(levels, 7, 64, 96, profile.cfa) == draws[7]  # a function of the key
    # 1000 draws: the sample's sigma is within 10 % (4.5 standard errors)
    offsets = np.array([d.offset for d in draws])
    assert offsets.std() == pytest.approx(levels.black_level_sigma, rel=0.1)
    assert abs(offsets.mean()) < 4 * levels.black_level_sigma / math.sqrt(1000)
    with pytest.raises(ParameterError, match="larger than the profile's dark-shading map 80×122"):
        dark_draw(levels, 1, 82, 96, profile.cfa)


def _black_png(path: Path, h: int, w: int) -> Path:
    from rawsim.io.png import write_png

    write_png(path, np.zeros((h, w, 3), np.uint8))
    return path


@pytest.mark.parametrize("engine", [True, False], ids=["engine", "reference"])
def test_unprocessed_black_frames_reproduce_the_map(tmp_path, engine, monkeypatch):
    """16 black frames: their per-pixel mean, placed at each file's recorded crop,
    reproduces the map; each file's black offset is the recorded one."""
    import rawsim.pipelines.unprocess as pipeline

    monkeypatch.setattr(pipeline, "use_engine", lambda image: engine)
    h, w, iso = 64, 96, 1600
    profile = load_profile(dark_profile(tmp_path, 80, 120))
    source = _black_png(tmp_path / "black.png", h, w)
    options = UnprocessOptions(profile=profile, iso=iso, noise="physics", formats=("npz",))
    total, count = np.zeros((80, 120)), np.zeros((80, 120))
    frame_means, recorded = [], []
    levels = profile.noise.levels("physics", iso)
    k, b = profile.noise.dark_shading.maps(iso)
    shade = k.astype(np.float64) * iso + b
    bias = np.tile(np.array(levels.channel_bias)[[0, 1, 2, 3]].reshape(2, 2), (40, 60))
    for i in range(16):
        outs = {"json": tmp_path / f"{i}.json", "npz": tmp_path / f"{i}.npz"}
        meta = unprocess_file(Task(source, f"{i}.png", outs, 1000 + i), options)
        draw = meta["noise"]["dark_draw"]
        assert draw == dark_draw(levels, noise_key(1000 + i), h, w, profile.cfa).to_dict()
        with np.load(outs["npz"]) as z:
            mosaic = profile.cfa.unpack(torch.from_numpy(z["mosaic"].astype(np.float64))[None])
        frame = mosaic[0, 0].numpy() - profile.black_level - draw["black_level_offset_dn"]
        rows = slice(draw["map_top"], draw["map_top"] + h)
        cols = slice(draw["map_left"], draw["map_left"] + w)
        total[rows, cols] += frame - bias[rows, cols]
        count[rows, cols] += 1
        frame_means.append(frame.mean() + draw["black_level_offset_dn"] - shade[rows, cols].mean())
        recorded.append(draw["black_level_offset_dn"])
    seen = count >= 8
    assert seen.sum() > 0.5 * h * w
    mean = total[seen] / count[seen]
    assert np.corrcoef(mean, shade[seen])[0, 1] >= 0.95
    # Each file's black level is offset by its recorded draw: a frame mean is off it by
    # row and read noise only (σ_row/√h plus a little).
    frame_noise = math.sqrt(levels.row_sigma**2 / h + levels.read_variance / (h * w))
    err = np.array(frame_means) - np.array(recorded) - np.mean(bias)
    assert np.abs(err).max() < 4.5 * frame_noise
    assert np.std(recorded) > 2 * frame_noise  # the offsets are seen, not lost in the noise


def test_a_profile_without_a_map_adds_nothing(tmp_path):
    """The dark terms are the physics model's only, and absent without the keys."""
    profile = load_profile(BASE)
    assert not profile.noise.levels("physics", 1600).has_dark
    assert "dark_shading" not in profile.noise.levels("physics", 1600).to_dict()
    with_map = load_profile(dark_profile(tmp_path, 64, 64))
    sensor, plain = RGBSensor(with_map), RGBSensor(profile)
    dn = torch.full((1, 1, 64, 64), float(profile.black_level) + 100)
    for model in ("poisson-gaussian", "gaussian"):
        a = sensor.simu_noise(dn, 1600, model, 5)
        assert torch.equal(a, plain.simu_noise(dn, 1600, model, 5))
    physics = sensor.simu_noise(dn, 1600, "physics", 5)
    assert not torch.equal(physics, plain.simu_noise(dn, 1600, "physics", 5))


# ---------------------------------------------------------------- calibration


def test_frames_needed_follows_the_correlation_of_a_mean():
    rng = np.random.default_rng(0)
    pattern = rng.normal(size=200_000)
    v, p = 4.0, 1.0
    n = math.ceil(frames_needed(v, p))
    assert n == 38  # 9.26 · 4
    mean = pattern + rng.normal(size=pattern.size) * math.sqrt(v / n)
    assert np.corrcoef(mean, pattern)[0, 1] == pytest.approx(0.95, abs=0.003)
    assert frames_needed(v, 0.0) == math.inf


#: The calibration's ISOs: two per gain range of the test maps.
CAL_ISOS = (100, 400, 800, 3200)
CAL_DARKS = 12
#: The calibration frames' size (rows, columns).
CAL_SIZE = (384, 512)


def _frame(sensor, iso: float, level: float, seed: int, h: int = CAL_SIZE[0], w: int = CAL_SIZE[1]):
    """A frame of ``sensor`` (physics model): a flat field with a gradient whose
    brightest part is ``level`` of the range, or a dark frame (``level`` 0)."""
    p = sensor.profile
    x = torch.linspace(0.05, 1.0, w)[None, :] * torch.linspace(0.7, 1.0, h)[:, None]
    dn = (p.black_level + level * (p.white_level - p.black_level) * x)[None, None]
    return sensor.simu_noise(dn, iso, "physics", seed)[0, 0].numpy().astype(np.uint16)


@pytest.fixture(scope="module")
def dark_frames(tmp_path_factory):
    """Flats and dark frames of a 70D whose profile carries the test maps (``CAL_SIZE``)."""
    root = tmp_path_factory.mktemp("dark_cal")
    sensor = RGBSensor(load_profile(dark_profile(root, *CAL_SIZE)))
    for sub in ("flats", "darks"):
        (root / sub).mkdir()
    seed = 0
    for iso in CAL_ISOS:
        for level in (0.3, 0.85):
            seed += 1
            _write(root / "flats" / f"f{iso}_{level}.dng", _frame(sensor, iso, level, seed), iso)
        for i in range(CAL_DARKS):
            seed += 1
            _write(root / "darks" / f"d{iso}_{i:02d}.dng", _frame(sensor, iso, 0.0, seed), iso)
    return root, sensor


@pytest.mark.slow
def test_calibration_recovers_dark_shading(dark_frames, tmp_path):
    root, sensor = dark_frames
    out = tmp_path / "cam.json"
    args = ["calibrate", str(root / "flats"), "--dark", str(root / "darks"), "-o", str(out)]
    r = CliRunner().invoke(cli, [*args, "--dark-shading", "--gain-switch", "800", "--json"])
    assert r.exit_code == 0, r.output
    fits = {f["iso"]: f for f in json.loads(r.stdout)}
    for iso, fit in fits.items():  # today's tolerances (tests/test_calibrate.py)
        levels = sensor.noise_levels(iso, "physics")
        assert fit["K"] == pytest.approx(levels.gain, rel=0.03)
        assert fit["read_sigma"] == pytest.approx(
            math.sqrt(levels.read_variance - levels.row_sigma**2), rel=0.05
        )
        assert fit["row_sigma"] == pytest.approx(levels.row_sigma, rel=0.10)
    profile = load_profile(out)
    shading = profile.noise.dark_shading
    assert shading.iso_ranges == ((100.0, 400.0), (800.0, 3200.0))
    assert (out.parent / "cam.dark.npz").is_file() and shading.size == CAL_SIZE
    true_k, true_b = make_maps(*CAL_SIZE)
    for i, iso in enumerate((400, 3200)):
        k, b = shading.maps(iso)
        assert np.corrcoef(k.ravel(), true_k[i].ravel())[0, 1] >= 0.95
        assert np.corrcoef(b.ravel(), true_b[i].ravel())[0, 1] >= 0.95
    truth = sensor.profile.noise.black_level_error
    ratios = [profile.noise.black_level_error(i) / truth(i) for i in CAL_ISOS]
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.3)  # 12 frames: ±21 % each
    # Without the map taken out, the pattern would pass for read noise.
    plain = tmp_path / "plain.json"
    r = CliRunner().invoke(cli, [*args[:-1], str(plain), "--json"])
    read = {f["iso"]: f["read_sigma"] for f in json.loads(r.stdout)}
    assert all(read[i] > 1.2 * fits[i]["read_sigma"] for i in (800, 3200))


@pytest.mark.slow
def test_too_few_dark_frames_or_isos_are_refused(dark_frames, tmp_path):
    root, _ = dark_frames
    out = tmp_path / "cam.json"
    few = [str(p) for p in sorted((root / "darks").glob("d*_0[0-3].dng"))]
    args = ["calibrate", str(root / "flats"), "-o", str(out), "--dark-shading"]
    r = CliRunner().invoke(cli, [*args, "--gain-switch", "800", *_darks(few)])
    assert r.exit_code == 1 and "4 dark frame(s)" in r.output and "needs at least" in r.output
    assert not out.exists() and not (tmp_path / "cam.dark.npz").exists()
    r = CliRunner().invoke(cli, [*args, "--gain-switch", "400", "--dark", str(root / "darks")])
    assert r.exit_code == 1 and "at least two ISOs per gain range" in r.output, r.output
    # refused before the flats are read: a broken one is never opened
    broken = tmp_path / "flats"
    broken.mkdir()
    (broken / "f.dng").write_bytes(b"not a raw")
    one_iso = [*args[:1], str(broken), *args[2:], "--gain-switch", "400"]
    r = CliRunner().invoke(cli, [*one_iso, "--dark", str(root / "darks")])
    assert r.exit_code == 1 and "at least two ISOs per gain range" in r.output, r.output
    r = CliRunner().invoke(cli, [*args])
    assert r.exit_code != 0 and "needs dark frames" in r.output


def _darks(paths):
    return [a for p in paths for a in ("--dark", p)]


def test_dark_frames_are_streamed(tmp_path):
    """The accumulator's memory does not grow with the number of frames (four dark
    frames of 256 × 384 read in turn: keeping each would add 5 MB by the 32nd)."""
    sensor = RGBSensor(load_profile(dark_profile(tmp_path, 256, 384)))
    files = [tmp_path / f"d400_{i}.dng" for i in range(4)]
    for i, file in enumerate(files):
        _write(file, _frame(sensor, 400, 0.0, i + 1, 256, 384), 400)

    def peak(n: int) -> int:
        tracemalloc.start()
        acc = accumulate((read_raw(files[i % len(files)]), 400.0) for i in range(n))
        size = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert acc.n[400.0] == n
        return size

    small, large = peak(4), peak(32)
    assert large < 1.1 * small, (small, large)
