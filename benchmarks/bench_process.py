"""Processing speed and memory: rawsim's ISP beside LibRaw (rawpy) in the same run.

    python benchmarks/bench_process.py [--quick]

Makes a 24 MP, 14-bit DNG with ``rawsim unprocess`` (a test photo resized to
6000×4000, Sony A7S II profile, ISO 800), then times, each in a fresh process so
that peak memory (max RSS) is its own:
  * LibRaw AHD through ``rawpy.postprocess`` (camera WB, sRGB, 16-bit);
  * ``rawsim process`` with each demosaic method (default: wcd), per image in a
    batch of copies of the file (start-up excluded), uncompressed 16-bit TIFF out
    (LibRaw's figure excludes writing; a 24 MP 16-bit PNG alone takes ~11 s to deflate).
Goal (issue 3): rawsim ≥ 1.5× faster than LibRaw AHD, peak memory ≤ 1.5 GB.
"""

from __future__ import annotations

import argparse
import re
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import OpenImageIO as oiio

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "srgb"

LIBRAW = """
import sys, time, rawpy
t = time.perf_counter()
with rawpy.imread(sys.argv[1]) as raw:
    raw.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD, use_camera_wb=True,
                    output_color=rawpy.ColorSpace.sRGB, output_bps=16, no_auto_bright=True)
print(time.perf_counter() - t)
"""


def child(cmd: list[str]) -> tuple[str, str, float]:
    """Run ``cmd``; return stdout, stderr and its peak RSS in GB."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return done.stdout, done.stderr, max(peak, before) / 1024**2


def make_dng(tmp: Path) -> Path:
    photo = tmp / "photo24.png"
    buf = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(str(DATA / "astronaut.png")), roi=oiio.ROI(0, 6000, 0, 4000)
    )
    assert buf.write(str(photo)), oiio.geterror()
    subprocess.run(
        [
            "rawsim",
            "-q",
            "unprocess",
            str(photo),
            "-o",
            str(tmp / "dng"),
            "-p",
            "sony_a7s2",
            "--iso",
            "800",
        ],
        check=True,
    )
    return tmp / "dng" / "photo24.dng"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one copy, fewer methods")
    args = ap.parse_args()
    copies = 1 if args.quick else 3
    methods = ["wcd", "bilinear"] if args.quick else ["wcd", "menon", "malvar", "bilinear"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        dng = make_dng(tmp)
        print(f"24 MP 14-bit DNG ({dng.stat().st_size / 1e6:.0f} MB), 2-core machine")
        times = []
        peak_libraw = 0.0
        for _ in range(copies):
            out, _, peak = child([sys.executable, "-c", LIBRAW, str(dng)])
            times.append(float(out))
            peak_libraw = max(peak_libraw, peak)
        libraw = min(times)
        print(
            f"  {'LibRaw AHD (rawpy.postprocess)':<36} {libraw:6.2f} s/image  "
            f"peak {peak_libraw:4.2f} GB"
        )
        batch = tmp / "batch"
        batch.mkdir()
        for i in range(copies):
            shutil.copy(dng, batch / f"copy{i}.dng")
        for method in methods:
            out_dir = tmp / f"out_{method}"
            _, err, peak = child(
                [
                    "rawsim",
                    "-q",
                    "process",
                    str(batch),
                    "-o",
                    str(out_dir),
                    "--demosaic",
                    method,
                    "--format",
                    "tiff",
                    "--bits",
                    "16",
                ]
            )
            seconds = float(re.search(r"in ([0-9.]+) s", err).group(1)) / copies
            print(
                f"  {f'rawsim process --demosaic {method}':<36} {seconds:6.2f} s/image  "
                f"peak {peak:4.2f} GB   LibRaw/rawsim = {libraw / seconds:4.2f}×"
            )
            shutil.rmtree(out_dir)
        print("  goal: LibRaw/rawsim ≥ 1.5× with peak ≤ 1.5 GB")


if __name__ == "__main__":
    main()
