"""Event sensor and event streams: hand-computed counts and times, noise rates,
seeding, formats and the CLI."""

import json
import math

import numpy as np
import OpenImageIO as oiio
import pytest
import torch
from click.testing import CliRunner

from rawsim.errors import ParameterError
from rawsim.events.sensor import (
    EventSensor,
    events_to_timestamp_image,
    events_to_voxel_grid,
)
from rawsim.events.stream import EventParams, EventStream, voxel_grid
from rawsim_cli.main import cli
from tests.conftest import numba_threads, thread_counts


def _pair(changes, base=0.1):
    """A (1, 1, 1, N) frame pair whose log intensity changes by ``changes``."""
    prev = torch.full((1, 1, 1, len(changes)), base, dtype=torch.float64)
    cur = prev * torch.exp(torch.tensor(changes, dtype=torch.float64)).view(1, 1, 1, -1)
    return cur, prev


def test_hand_computed_counts():
    sensor = EventSensor(threshold_pos=0.2, threshold_neg=0.3, sigma_threshold=0, eps=1e-12)
    cur, prev = _pair([0.45, 0.19, -0.65, -0.29, 0.0, 1.05])
    ev = sensor(cur, prev, dt=0.01)
    # brightening 0.45/0.2 → 2; below threshold → 0; darkening 0.65/0.3 → 2; 0.29/0.3 → 0
    assert ev[0, 0, 0].tolist() == [2, 0, 0, 0, 0, 5]
    assert ev[0, 1, 0].tolist() == [0, 0, 2, 0, 0, 0]


def test_high_pass_attenuates_by_one_minus_alpha():
    dt, fc = 0.01, 5.0
    tau = 1 / (2 * math.pi * fc)
    gain = 1 - tau / (tau + dt)  # ≈ 0.239
    cur, prev = _pair([1.05, 0.55])
    off = EventSensor(threshold_pos=0.1, sigma_threshold=0, eps=1e-12)(cur, prev, dt)
    on = EventSensor(threshold_pos=0.1, sigma_threshold=0, cutoff_hz=fc, eps=1e-12)(cur, prev, dt)
    assert off[0, 0, 0].tolist() == [10, 5]
    assert on[0, 0, 0].tolist() == [math.floor(1.05 * gain / 0.1), math.floor(0.55 * gain / 0.1)]


def test_rgb_frames_use_luminance_and_threshold_noise_only_raises_thresholds():
    prev = torch.full((1, 3, 64, 64), 0.2)
    cur = prev * math.exp(0.5)
    exact = EventSensor(sigma_threshold=0)(cur, prev, 0.01)
    assert torch.all(exact[:, 0] == 2) and torch.all(exact[:, 1] == 0)
    noisy = EventSensor(sigma_threshold=0.05)(cur, prev, 0.01, torch.Generator().manual_seed(0))
    assert torch.all(noisy[:, 0] <= 2) and (noisy[:, 0] < 2).any()
    with pytest.raises(ParameterError, match="Generator"):
        EventSensor()(cur, prev, 0.01)


@pytest.mark.parametrize("kind", ["leak", "shot"])
def test_noise_event_rates(kind):
    rate, dt = 40.0, 0.005  # rate·dt = 0.2
    kw = {"leak_rate_hz": rate} if kind == "leak" else {"shot_noise_rate_hz": rate}
    sensor = EventSensor(sigma_threshold=0, **kw)
    still = torch.full((1, 1, 400, 500), 0.3)
    ev = sensor(still, still, dt, torch.Generator().manual_seed(1))
    n = still.numel()
    if kind == "leak":
        assert float(ev[:, 0].sum()) / n == pytest.approx(rate * dt, rel=0.05)
        assert float(ev[:, 1].sum()) == 0
    else:
        for c in (0, 1):
            assert float(ev[:, c].sum()) / n == pytest.approx(rate * dt / 2, rel=0.05)


def test_video_voxel_grid_and_timestamp_shapes():
    g = torch.Generator().manual_seed(2)
    frames = torch.rand(2, 5, 3, 16, 24, generator=g) + 0.05
    sensor = EventSensor(sigma_threshold=0)
    video = sensor.forward_video(frames, 1 / 30)
    assert video.shape == (2, 4, 2, 16, 24)
    assert torch.equal(video[:, 2], sensor(frames[:, 3], frames[:, 2], 1 / 30))
    grid = events_to_voxel_grid(video, 3)
    assert grid.shape == (2, 3, 16, 24)
    net = (video[:, :, 0] - video[:, :, 1]).sum(1)
    assert torch.allclose(grid.sum(1), net, atol=1e-5)  # every event lands in the grid once
    stamps = events_to_timestamp_image(video)
    assert stamps.shape == (2, 2, 16, 24) and float(stamps.max()) == 1.0
    assert float(stamps.min()) >= 0


def test_timestamp_image_marks_the_latest_event():
    ev = torch.zeros(1, 4, 2, 1, 3)
    ev[0, 0, 0, 0, 0] = 1  # step 1
    ev[0, 3, 0, 0, 1] = 2  # step 4
    ev[0, 1, 1, 0, 2] = 1  # negative, step 2
    stamps = events_to_timestamp_image(ev)
    assert stamps[0, 0, 0].tolist() == [0.25, 1.0, 0.0]
    assert stamps[0, 1, 0].tolist() == [0.0, 0.0, 1.0]


def test_events_cli_on_a_short_sequence(tmp_path):
    frames = tmp_path / "clip"
    frames.mkdir()
    for t in range(4):
        img = np.full((24, 32, 3), 40 + 50 * t, np.uint8)
        img[:, :16] = 120  # left half still
        oiio.ImageBuf(img).write(str(frames / f"frame_{t:03d}.png"))
    out = tmp_path / "events"
    args = ["events", frames, "-o", out, "--fps", 120, "--sigma-threshold", 0, "--preview"]
    r = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    z = np.load(out / "events.npz")
    events = z["events"]
    assert events.shape == (3, 2, 24, 32) and events.dtype == np.int32
    assert events[:, :, :, :16].sum() == 0 and events[:, 1].sum() == 0
    assert (events[:, 0, :, 16:] > 0).all()
    params = json.loads(str(z["params"]))
    assert params["fps"] == 120 and params["sigma_threshold"] == 0
    assert sorted(p.name for p in (out / "preview").iterdir()) == [
        "step_0001.png",
        "step_0002.png",
        "step_0003.png",
    ]
    again = CliRunner().invoke(cli, [str(a) for a in args])
    assert again.exit_code == 0 and "skip: " in again.output and "exists" in again.output
    one = CliRunner().invoke(
        cli, ["events", str(frames / "frame_000.png"), "-o", str(tmp_path / "x"), "--fps", "1"]
    )
    assert one.exit_code == 2 and "events need at least 2" in one.output


# ---- event streams --------------------------------------------------------------------


def _stream(values, dt=0.01, **kw):
    """One pixel row: log intensity 0, then ``values`` (one list per step)."""
    exact = dict(sigma_threshold=0, eps=1e-12)
    refractory = kw.pop("refractory_s", 0.0)
    params = EventParams(**{**exact, **kw})
    steps = [np.asarray(v, dtype=np.float64)[None] for v in values]
    stream = EventStream(params, steps[0].shape, refractory_s=refractory)
    stream.start(np.zeros_like(steps[0]), 0.0)
    return [stream.step(s, (k + 1) * dt) for k, s in enumerate(steps)]


def test_stream_first_step_is_the_count_model_with_exact_times():
    vals = [0.45, 0.19, -0.65, -0.29, 0.0, 1.05]
    (batch,) = _stream([vals], threshold_pos=0.2, threshold_neg=0.3)
    cur, prev = _pair(vals)
    counts = EventSensor(threshold_pos=0.2, threshold_neg=0.3, sigma_threshold=0, eps=1e-12)(
        cur, prev, 0.01
    )
    assert np.array_equal(batch.counts, counts[0, :, 0:1].numpy().astype(np.int32))
    # Pixel 0 crosses 0.2 and 0.4 of its 0.45 change: at 4/9 and 8/9 of the step.
    first = batch.t[batch.x == 0]
    assert np.allclose(first, [0.01 * 0.2 / 0.45, 0.01 * 0.4 / 0.45], rtol=0, atol=1e-15)
    assert np.all(np.diff(batch.t) >= 0) and set(batch.p.tolist()) == {0, 1}
    assert np.all(batch.p[batch.x == 2] == 0)


def test_stream_remembers_what_the_count_model_drops():
    """+0.1 per step, θ 0.15: the count model never fires; a real pixel fires in step 2."""
    batches = _stream([[0.1], [0.2], [0.3]], threshold_pos=0.15)
    assert [int(b.counts[0].sum()) for b in batches] == [0, 1, 1]
    assert batches[1].t[0] == pytest.approx(0.015)  # 0.15 reached halfway through step 2
    assert batches[2].t[0] == pytest.approx(0.03)  # and 0.30 at its end


def test_refractory_period_absorbs_crossings():
    """A change of 1.0 crosses θ 0.2 at 2, 4, 6, 8, 10 ms; a 3 ms refractory period keeps
    2, 6 and 10 ms, and the reference still follows all five (no events afterwards)."""
    batches = _stream([[1.0], [1.0]], threshold_pos=0.2, refractory_s=0.003)
    assert np.allclose(batches[0].t, [0.002, 0.006, 0.010])
    assert batches[1].t.size == 0


def test_leak_fires_on_events_at_its_rate_in_a_still_scene():
    still = [[0.0] * 50] * 11  # 1.1 s at dt 0.1
    batches = _stream(still, dt=0.1, leak_rate_hz=2.0, threshold_pos=0.2)
    on = sum(int(b.counts[0].sum()) for b in batches)
    assert on == 2 * 50 and sum(int(b.counts[1].sum()) for b in batches) == 0


def test_shot_noise_rate_and_threshold_mismatch_are_seeded():
    params = EventParams(sigma_threshold=0.03, shot_noise_rate_hz=20.0)
    shape = (200, 300)
    runs = []
    for seed in (1, 1, 2):
        stream = EventStream(params, shape, seed=seed)
        stream.start(np.zeros(shape), 0.0)
        runs.append((stream.on.copy(), stream.step(np.zeros(shape), 0.01)))
    (on_a, a), (on_b, b), (on_c, c) = runs
    assert np.array_equal(on_a, on_b) and not np.array_equal(on_a, on_c)
    assert on_a.mean() == pytest.approx(0.2, abs=0.001) and on_a.std() == pytest.approx(
        0.03, rel=0.02
    )
    assert np.array_equal(a.t, b.t) and np.array_equal(a.x, b.x) and not np.array_equal(a.t, c.t)
    n = shape[0] * shape[1]
    for polarity in (0, 1):  # rate·dt/2 each
        assert (a.p == polarity).sum() / n == pytest.approx(0.1, rel=0.05)


def test_stream_is_the_same_for_any_thread_count():
    g = np.random.default_rng(3)
    frames = [np.log(g.random((64, 96)) + 0.05) for _ in range(4)]
    params = EventParams(sigma_threshold=0.03, leak_rate_hz=1.0, shot_noise_rate_hz=5.0)
    results = []
    for threads in thread_counts():
        with numba_threads(threads):
            stream = EventStream(params, frames[0].shape, seed=4, refractory_s=1e-3)
            stream.start(frames[0], 0.0)
            results.append([stream.step(f, (k + 1) / 100) for k, f in enumerate(frames[1:])])
    for a, b in zip(*results, strict=True):
        for name in ("t", "x", "y", "p", "counts"):
            assert np.array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.parametrize(
    "params, refractory",
    [
        (EventParams(sigma_threshold=0.03, leak_rate_hz=1.0, shot_noise_rate_hz=5.0), 1e-3),
        (EventParams(sigma_threshold=0.0), 0.0),
        (EventParams(cutoff_hz=30.0, sigma_threshold=0.05, threshold_neg=0.3), 0.0),
    ],
    ids=["noisy", "exact", "cutoff"],
)
def test_torch_reference_gives_the_engines_events_bit_for_bit(params, refractory):
    """The torch stream step (what --device cuda runs) against the compiled kernels, on
    the CPU: every event, time, polarity and count identical."""
    g = np.random.default_rng(3)
    frames = [np.log(g.random((48, 80)) + 0.05) for _ in range(5)]
    runs = []
    for device in (None, "cpu"):
        stream = EventStream(
            params, frames[0].shape, seed=4, refractory_s=refractory, device=device
        )
        stream.start(frames[0], 0.0)
        runs.append([stream.step(f, (k + 1) / 100) for k, f in enumerate(frames[1:])])
    assert sum(b.t.size for b in runs[0]) > 10_000
    for a, b in zip(*runs, strict=True):
        for name in ("t", "x", "y", "p", "counts"):
            got, want = getattr(b, name), getattr(a, name)
            assert got.dtype == want.dtype and np.array_equal(got, want), name


def test_time_order_is_a_stable_sort_for_any_thread_count():
    """The parallel counting sort equals numpy's stable argsort (ties in input order),
    with many ties and clustered times, on 1 thread and on all."""
    from rawsim.events.kernels import time_order

    g = np.random.default_rng(8)
    n = 50_000
    t = np.round(0.5 + 0.01 * g.beta(0.3, 3.0, n), 6)  # clustered, many equal values
    x, y = g.integers(0, 640, n).astype(np.uint16), g.integers(0, 480, n).astype(np.uint16)
    p = g.integers(0, 2, n).astype(np.int8)
    order = np.argsort(t, kind="stable")
    for threads in thread_counts():
        with numba_threads(threads):
            for buckets in (1, 7, 256, n // 2):
                out = [np.empty_like(a) for a in (t, x, y, p)]
                time_order(t, x, y, p, 0.5, 0.01, buckets, threads, *out)
                for got, a in zip(out, (t, x, y, p), strict=True):
                    assert np.array_equal(got, a[order])


def test_voxel_grid_keeps_every_event_once():
    g = np.random.default_rng(0)
    (batch,) = _stream([g.normal(0, 0.5, 40)], threshold_pos=0.1, threshold_neg=0.1)
    grid = voxel_grid(batch, 0.0, 0.01, 5)
    net = batch.counts[0] - batch.counts[1]
    assert grid.shape == (5, 1, 40) and np.allclose(grid.sum(0), net, atol=1e-5)


def test_events_cli_stream_formats_agree(tmp_path):
    """npz, v2e's HDF5 and ESIM's text hold the same events; --jobs does not change them;
    --json reports the run."""
    import h5py

    frames = tmp_path / "clip"
    frames.mkdir()
    g = np.random.default_rng(1)
    base = g.integers(20, 230, (48, 64, 3)).astype(np.uint8)
    for t in range(5):
        oiio.ImageBuf(np.roll(base, 2 * t, axis=1)).write(str(frames / f"f{t}.png"))
    common = [str(frames), "--fps", "1000", "--seed", "3", "--refractory-s", "1e-4"]
    out = {}
    for fmt, jobs in (("npz", "1"), ("h5", "2"), ("txt", "2"), ("npz", "2")):
        folder = tmp_path / f"{fmt}{jobs}"
        args = ["events", *common, "-o", str(folder), "--format", fmt, "--jobs", jobs, "--json"]
        r = CliRunner().invoke(cli, args + (["--voxel-bins", "3"] if fmt == "npz" else []))
        assert r.exit_code == 0, r.output
        record = json.loads(r.stdout)
        assert record["frames"] == 5 and record["outputs"][0].endswith(f"events.{fmt}")
        out[fmt + jobs] = folder / f"events.{fmt}"
    z = np.load(out["npz1"])
    assert (tmp_path / "npz1" / "events.npz").read_bytes() == (
        tmp_path / "npz2" / "events.npz"
    ).read_bytes()
    assert z["t"].size == record["events"]["on"] + record["events"]["off"] > 100
    assert np.all(np.diff(z["t"]) >= 0) and z["events"].shape == (4, 2, 48, 64)
    with h5py.File(out["h52"]) as f:
        rows = f["events"][:]
        assert rows.dtype == np.uint32 and rows.shape == (z["t"].size, 4)
        assert np.array_equal(rows[:, 0], np.round(z["t"] * 1e6).astype(np.uint32))
        assert np.array_equal(rows[:, 1:], np.stack([z["x"], z["y"], z["p"]], 1))
        assert f["frame_ts"][:].tolist() == [0, 1000, 2000, 3000, 4000]
        assert f["frame_idx"][-1] == rows.shape[0]
    text = np.loadtxt(out["txt2"])
    assert np.allclose(text[:, 0], z["t"], rtol=0, atol=1e-9)
    assert np.array_equal(text[:, 1:].astype(int), np.stack([z["x"], z["y"], z["p"]], 1))
    voxels = np.load(tmp_path / "npz1" / "voxels.npy")
    assert voxels.shape == (4, 3, 48, 64)
    assert np.allclose(voxels.sum(1), z["events"][:, 0] - z["events"][:, 1], atol=1e-4)


def test_events_cli_device(tmp_path):
    """--device auto on a machine without a GPU is the engine's file; --device cuda there
    says there is none."""
    import torch

    frames = tmp_path / "clip"
    frames.mkdir()
    base = np.random.default_rng(2).integers(20, 230, (32, 48, 3)).astype(np.uint8)
    for t in range(3):
        oiio.ImageBuf(np.roll(base, 3 * t, axis=0)).write(str(frames / f"f{t}.png"))
    common = ["events", str(frames), "--fps", "500", "--seed", "1", "--shot-noise-rate-hz", "9"]
    for device in ("cpu", "auto"):
        r = CliRunner().invoke(cli, [*common, "-o", str(tmp_path / device), "--device", device])
        assert r.exit_code == 0, r.output
    if not torch.cuda.is_available():
        a, b = (np.load(tmp_path / d / "events.npz") for d in ("cpu", "auto"))
        assert all(np.array_equal(a[k], b[k]) for k in a.files)
        r = CliRunner().invoke(cli, [*common, "-o", str(tmp_path / "gpu"), "--device", "cuda"])
        assert r.exit_code == 2 and "no CUDA device is available" in r.output


def test_stream_writers_over_many_blocks():
    """The parallel writers' bytes, over several blocks of events, are the formats'
    definitions: ESIM's text lines (9 decimals of the rounded nanoseconds) and v2e's
    uint32 rows (rounded microseconds), in order."""
    from rawsim.events import kernels as ee

    g = np.random.default_rng(5)
    n = 150_001
    t = np.sort(g.uniform(0, 20, n))
    t[:4] = [0.0, 1e-9, 2.5e-7, 12.5]
    x, y = (g.integers(0, 65536, n).astype(np.uint16) for _ in range(2))
    p = g.integers(0, 2, n).astype(np.int8)
    out = np.empty(n * ee.LINE_BYTES, np.uint8)
    text = bytes(out[: ee.text_lines(t, x, y, p, out)]).decode()
    ns = np.round(t * 1e9).astype(np.int64)
    want = [
        f"{a // 10**9}.{a % 10**9:09d} {b} {c} {d}\n"
        for a, b, c, d in zip(ns, x, y, p, strict=True)
    ]
    assert text == "".join(want)
    rows = np.empty((n, 4), np.uint32)
    ee.v2e_rows(t, x, y, p, rows)
    assert np.array_equal(rows[:, 0], np.round(t * 1e6).astype(np.uint32))
    assert np.array_equal(rows[:, 1:], np.stack([x, y, p], 1))


def test_npz_writer_is_numpys_savez_byte_for_byte(tmp_path):
    """events.npz joins each step's arrays as it writes them (no concatenated copy): the
    bytes np.savez writes for the joined arrays, whatever the parts (empty ones,
    strided ones, dtypes that numpy would join by promoting)."""
    import io

    from rawsim.events.files import _Joined, _savez

    g = np.random.default_rng(3)
    small = {"frame_ts": np.array([0.0, 0.5]), "frames": np.array(["a.png", "b/ü.png"])}
    cases = []
    for n in (1, 2, 5):
        t = [g.random(int(g.integers(0, 2000))) for _ in range(n)] + [np.empty(0)]
        counts = [g.integers(0, 9, (2, 3, 5)).astype(np.int32) for _ in range(n + 1)]
        cases.append((t, counts))
    cases.append(([np.arange(10.0)[::2], np.arange(3, dtype=np.int64)], [np.zeros((2, 1, 1))]))
    for t, counts in cases:
        ours, numpys = io.BytesIO(), io.BytesIO()
        x = [a.astype(np.uint16) for a in t]
        _savez(ours, t=_Joined(t), x=_Joined(x), events=_Joined(counts, stacked=True), **small)
        joined = {"t": np.concatenate(t), "x": np.concatenate(x), "events": np.stack(counts)}
        np.savez(numpys, **joined, **small)
        assert ours.getvalue() == numpys.getvalue()
