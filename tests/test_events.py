"""Event sensor: hand-computed counts, noise-event rates, shapes and the CLI."""

import json
import math

import numpy as np
import OpenImageIO as oiio
import pytest
import torch
from click.testing import CliRunner

from rawsim.errors import ParameterError
from rawsim.events import (
    EventSensor,
    events_to_timestamp_image,
    events_to_voxel_grid,
)
from rawsim_cli.main import cli


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
    assert one.exit_code == 2 and "at least 2 frames" in one.output
