"""Event-simulation speed: frame pairs per second at 640×480, beside its peers.

    python benchmarks/bench_events.py [--frames N]

Makes N + 1 frames (8-bit PNG, 640×480) panning 2 pixels per frame across a
real photo (tests/data/srgb/astronaut.png, upsampled), then times, in one run:
  1. ``rawsim events`` end to end (decode, simulate, write) for each stream
     format: npz, h5 (v2e's layout), txt (ESIM's);
  2. the floor: OpenImageIO's decode of the same frames;
  3. the per-step torch model (EventSensor, counts only, no stream) on the
     decoded frames: rawsim's previous event simulator.
Target (issue 15, 2 cores): ≥ 100 frame pairs/s.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import torch

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "srgb"
CLI = [sys.executable, "-c", "from rawsim_cli.main import main; main()"]


def make_frames(folder: Path, count: int, scene: str) -> list[Path]:
    """``pan``: the camera pans 2 px per frame across the photo (every textured pixel
    changes: a busy scene). ``object``: a still camera; a dark disc of radius 60 px
    crosses the photo at 2 px per frame (events at its edges only)."""
    width = 640 + 2 * count if scene == "pan" else 640
    src = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(str(DATA / "astronaut.png")), roi=oiio.ROI(0, width, 0, 640)
    )
    pixels = src.get_pixels(oiio.UINT8)
    yy, xx = np.mgrid[0:480, 0:640]
    paths = []
    for k in range(count):
        if scene == "pan":
            frame = np.ascontiguousarray(pixels[80:560, 2 * k : 2 * k + 640, :3])
        else:
            frame = pixels[80:560, :640, :3].copy()
            disc = (xx - 60 - 2 * k % 520) ** 2 + (yy - 240) ** 2 < 60**2
            frame[disc] = frame[disc] // 4
        path = folder / f"frame_{k:05d}.png"
        out = oiio.ImageOutput.create(str(path))
        out.open(str(path), oiio.ImageSpec(640, 480, 3, "uint8"))
        out.write_image(frame)
        out.close()
        paths.append(path)
    return paths


def timed(command: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(done.stderr)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=400)
    args = parser.parse_args()
    for scene in ("object", "pan"):
        run_scene(scene, args.frames)


def run_scene(scene: str, pairs: int) -> None:
    print(f"scene {scene}:")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        clip = root / "clip"
        clip.mkdir()
        paths = make_frames(clip, pairs + 1, scene)
        warm = ["events", str(clip / "frame_00000.png"), str(clip / "frame_00001.png")]
        timed([*CLI, *warm, "-o", str(root / "warm"), "--fps", "240"])  # compile, if needed
        short = root / "short"
        short.mkdir()
        for p in paths[:2]:
            (short / p.name).symlink_to(p)
        start_up = timed([*CLI, "events", str(short), "-o", str(root / "s"), "--fps", "240"])
        print(f"  frames 640×480, {pairs} pairs; command start-up + 1 pair: {start_up:.2f} s")
        for fmt in ("npz", "h5", "txt"):
            wall = timed(
                [*CLI, "events", str(clip), "-o", str(root / fmt), "--fps", "240", "--format", fmt]
            )
            rate = pairs / max(wall - start_up, 1e-9)
            size = (root / fmt / f"events.{fmt}").stat().st_size / 1e6
            events = events_in(root / fmt / f"events.{fmt}", fmt)
            print(
                f"  rawsim events --format {fmt}: {wall:.2f} s, {pairs / wall:.0f} pairs/s "
                f"({rate:.0f} pairs/s without start-up; {events / pairs / 1e3:.0f} k events "
                f"per pair, {events / max(wall - start_up, 1e-9) / 1e6:.1f} M events/s), "
                f"file {size:.0f} MB"
            )
        start = time.perf_counter()
        frames = [oiio.ImageBuf(str(p)).get_pixels(oiio.UINT8) for p in paths]
        decode = time.perf_counter() - start
        print(f"  floor, OpenImageIO decode: {len(paths) / decode:.0f} frames/s")
        from rawsim.events.sensor import EventSensor
        from rawsim.sensors import display_to_linear

        sensor = EventSensor(sigma_threshold=0)
        start = time.perf_counter()
        prev = None
        for f in frames:
            x = display_to_linear(torch.from_numpy(f).permute(2, 0, 1)[None].float() / 255)
            if prev is not None:
                sensor(x, prev, 1 / 240)
            prev = x
        torch_time = time.perf_counter() - start
        print(
            "  peer, rawsim's previous per-step torch model (counts only): "
            f"{pairs / (torch_time + decode):.0f} pairs/s"
        )


def events_in(path: Path, fmt: str) -> int:
    if fmt == "npz":
        return int(np.load(path)["t"].size)
    if fmt == "h5":
        import h5py

        with h5py.File(path) as f:
            return int(f["events"].shape[0])
    with open(path, "rb") as f:
        return sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 20), b""))


if __name__ == "__main__":
    main()
