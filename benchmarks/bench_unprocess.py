"""Unprocessing speed, printed beside OpenImageIO's own decode time for the same files.

    python benchmarks/bench_unprocess.py [--quick]

Measures, on this machine:
  1. core unprocessing of one 24 MP 8-bit photo (decode and encode excluded);
  2. whole-file throughput of ``rawsim unprocess`` on a folder of 1 MP JPEGs
     (process start-up included), with --jobs 1 and --jobs 2;
  3. ``rawsim --help`` latency.
Inputs are made by resizing the real photos in ../shared/data/srgb.
Targets (issue 2, 2-core machine): (1) ≤ 0.5 s, (2) ≥ 15 images/s, (3) ≤ 0.3 s.
"""

from __future__ import annotations

import argparse
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import torch

from rawsim.pipelines.unprocess import unprocess_tensor
from rawsim.sensors import RGBSensor

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "srgb"


def resized(src: Path, dst: Path, width: int, height: int) -> Path:
    buf = oiio.ImageBufAlgo.resize(oiio.ImageBuf(str(src)), roi=oiio.ROI(0, width, 0, height))
    buf.specmod().attribute("Compression", "jpeg:90")
    assert buf.write(str(dst)), oiio.geterror()
    return dst


def oiio_decode(path: Path) -> np.ndarray:
    inp = oiio.ImageInput.open(str(path))
    pixels = inp.read_image(0, 0, 0, 3, oiio.UINT8)
    inp.close()
    return pixels


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def core_24mp(tmp: Path, repeat: int) -> None:
    photo = resized(DATA / "astronaut.png", tmp / "photo24.png", 6000, 4000)
    decode_s = best(lambda: oiio_decode(photo), repeat)
    pixels = torch.from_numpy(oiio_decode(photo)).permute(2, 0, 1).unsqueeze(0)
    sensor = RGBSensor.from_profile("sony_a7s2")
    params = sensor.default_params(1600)
    threads = torch.get_num_threads()
    print(f"1. core unprocess, one 24 MP 8-bit photo (6000×4000), {threads} threads")
    print(f"   {'OpenImageIO decode (reference)':<44} {decode_s:7.3f} s")
    for noise in ("none", "gaussian", "poisson-gaussian"):
        for clean in (False, True):
            gen = torch.Generator().manual_seed(0)
            t = best(
                partial(
                    unprocess_tensor,
                    sensor,
                    pixels,
                    params,
                    noise=noise,
                    generator=gen,
                    clean=clean,
                ),
                repeat,
            )
            label = f"rawsim noise={noise}" + (" + clean" if clean else "")
            print(f"   {label:<44} {t:7.3f} s   (target ≤ 0.5 s)")


def throughput(tmp: Path, count: int) -> None:
    folder = tmp / "jpegs"
    folder.mkdir()
    sources = sorted(DATA.glob("*"))
    for i in range(count):
        resized(sources[i % len(sources)], folder / f"img{i:03d}.jpg", 1224, 816)
    decode_s = best(lambda: [oiio_decode(p) for p in sorted(folder.glob("*.jpg"))], 3)
    print(f"2. whole files: {count} JPEGs of 1 MP (1224×816), ISO 1600, DNG + JSON out")
    print(f"   {'OpenImageIO decode only (reference)':<44} {count / decode_s:7.1f} images/s")
    for jobs in (1, 2):
        out = tmp / f"out{jobs}"
        cmd = [
            "rawsim",
            "-q",
            "unprocess",
            str(folder),
            "-o",
            str(out),
            "-p",
            "sony_a7s2",
            "--iso",
            "1600",
            "--jobs",
            str(jobs),
        ]
        start = time.perf_counter()
        done = subprocess.run(cmd, check=True, capture_output=True, text=True)
        elapsed = time.perf_counter() - start
        batch_s = float(re.search(r"in ([0-9.]+) s", done.stderr).group(1))
        shutil.rmtree(out)
        print(
            f"   {f'rawsim unprocess --jobs {jobs}, batch (summary time)':<44} "
            f"{count / batch_s:7.1f} images/s   (target ≥ 15)"
        )
        print(
            f"   {f'rawsim unprocess --jobs {jobs}, incl. start-up':<44} "
            f"{count / elapsed:7.1f} images/s   (start-up {elapsed - batch_s:.1f} s)"
        )


def help_latency() -> None:
    times = []
    for _ in range(5):
        start = time.perf_counter()
        subprocess.run(["rawsim", "--help"], check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    print(
        f"3. rawsim --help: median {statistics.median(times):.3f} s, best {min(times):.3f} s "
        "(target ≤ 0.3 s)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats and files")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        core_24mp(tmp, 1 if args.quick else 3)
        throughput(tmp, 20 if args.quick else 200)
        help_latency()
    sys.stdout.flush()


if __name__ == "__main__":
    main()
