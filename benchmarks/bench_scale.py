"""Files per second on a Ray cluster, beside local worker processes, in one run.

    python benchmarks/bench_scale.py [--files 96]

Makes ``--files`` JPEGs of 1 MP (1152×864, from the test photos) and unprocesses
them with ``rawsim unprocess … -p sony_a7s2 --iso 1600`` (issue 16):

  1. ``--executor ray --address …`` on a running local Ray cluster (``ray start
     --head --num-cpus W``) for W = 1, 2, 4 workers (one CPU thread each); the
     cluster is up before the command starts, as on a real cluster;
  2. the peer: the same command with local processes, ``--jobs W`` (each with
     cores / W threads, at least 1);
  3. Ray's own cost per task on the same cluster (empty tasks), which bounds how
     small a bundle can usefully be.

Each command is timed whole (start-up, connecting, listing, all files) on N and
2N files: the difference gives the rate in files/s, the rest the fixed cost per
command. On Ray the fixed cost includes starting the workers: Ray ends a driver's
workers when it disconnects, so every command starts its own. The peak-memory
figures of issue 16 are printed by ``benchmarks/bench_memory.py``.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import OpenImageIO as oiio

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "srgb"
CLI = [sys.executable, "-c", "from rawsim_cli.main import main; main()"]
RAY = str(Path(sys.executable).with_name("ray"))
ARGS = ["-p", "sony_a7s2", "--iso", "1600", "--seed", "1", "-q"]


def make_jpegs(folder: Path, count: int) -> None:
    sources = sorted(DATA.glob("*"))
    for i in range(count):
        buf = oiio.ImageBuf(str(sources[i % len(sources)]))
        buf = oiio.ImageBufAlgo.resize(buf, roi=oiio.ROI(0, 1152, 0, 864))
        buf.specmod().attribute("Compression", "jpeg:90")
        assert buf.write(str(folder / f"{i:04d}.jpg")), oiio.geterror()


def timed(args: list[str], env: dict) -> float:
    start = time.perf_counter()
    done = subprocess.run([*CLI, *args], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode:
        raise SystemExit(f"failed: {args}\n{done.stderr}")
    return seconds


def start_cluster(cpus: int, env: dict) -> str:
    said = subprocess.run(
        [RAY, "start", "--head", "--port=0", f"--num-cpus={cpus}", "--include-dashboard=false"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return re.search(r"ray start --address='([^']+)'", said.stdout + said.stderr)[1]


def task_overhead(address: str, env: dict) -> float:
    """Seconds of Ray scheduling per empty task, 2000 tasks on the cluster."""
    code = (
        f"import ray, time; ray.init(address={address!r}, logging_level='ERROR');"
        "f = ray.remote(num_cpus=1)(lambda: None); ray.get([f.remote() for _ in range(50)]);"
        "t = time.perf_counter(); ray.get([f.remote() for _ in range(2000)]);"
        "print((time.perf_counter() - t) / 2000)"
    )
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    return float(done.stdout.split()[-1])


def fixed_and_rate(root: Path, out: str, where: list[str], files: int, env: dict):
    """(fixed seconds, files/s) of ``rawsim unprocess … WHERE`` from runs over
    ``files`` and 2 × ``files`` inputs: t(n) = fixed + n / rate."""
    small, large = (
        timed(["unprocess", str(root / n), "-o", str(root / f"{out}-{n}"), *ARGS, *where], env)
        for n in ("half", "all")
    )
    return 2 * small - large, files / (large - small)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--files", type=int, default=96)
    files = parser.parse_args().files
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_USAGE_STATS_ENABLED": "0"}
    print(
        f"1 MP JPEGs, {os.cpu_count()} cores; each command timed on {files} and {2 * files} files"
    )
    print("fixed: seconds a command pays whatever its size (start-up, connecting, Ray's")
    print("workers starting and importing rawsim); rate: files/s beyond that")
    print(
        f"{'workers':>8} {'ray fixed':>10} {'ray rate':>9} {'local fixed':>12} {'local rate':>11}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for name, count in (("half", files), ("all", 2 * files)):
            (root / name).mkdir()
            make_jpegs(root / name, count)
        timed(["unprocess", str(root / "half"), "-o", str(root / "warm"), *ARGS], env)  # caches
        for workers in (1, 2, 4):
            address = start_cluster(workers, env)
            try:
                where = ["--executor", "ray", "--address", address]
                ray_fixed, ray_rate = fixed_and_rate(root, f"ray{workers}", where, files, env)
                overhead = task_overhead(address, env)
            finally:
                subprocess.run([RAY, "stop", "--force"], env=env, capture_output=True)
            where = ["--jobs", str(workers)]
            local_fixed, local_rate = fixed_and_rate(root, f"local{workers}", where, files, env)
            print(
                f"{workers:>8} {ray_fixed:>9.1f}s {ray_rate:>9.1f} {local_fixed:>11.1f}s "
                f"{local_rate:>11.1f}   (Ray: {overhead * 1e3:.2f} ms per empty task)"
            )


if __name__ == "__main__":
    main()
