"""Peak memory (RSS) of whole commands, each in a fresh process, beside a peer.

    python benchmarks/bench_memory.py

Measures, on this machine (issue 16 targets in brackets):
  1. ``rawsim unprocess`` of a 100 MP JPEG (12240×8160) [< 2 GB];
  2. ``rawsim process`` of the resulting 100 MP DNG, to a 16-bit TIFF and to the
     default PNG [< 2 GB], beside rawpy (LibRaw AHD) postprocessing the same DNG
     and writing a TIFF in a fresh Python;
  3. ``rawsim calibrate --method patches`` of 4, 16 and 32 frames of 4 MP [flat
     in the number of frames: only per-block statistics are kept, about 1/10 of a
     frame].
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import OpenImageIO as oiio

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "srgb"
CLI = "from rawsim_cli.main import main; main()"


def peak(code: str, *args: str) -> tuple[float, float]:
    """(peak RSS in GB, seconds) of ``python -c code args`` run in its own process."""
    probe = (
        "import resource, subprocess, sys, time; t = time.perf_counter(); "
        "r = subprocess.run(sys.argv[1:]); "
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, "
        "time.perf_counter() - t, r.returncode)"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe, sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
    )
    kb, seconds, rc = done.stdout.split()[-3:]
    if rc != "0":
        raise SystemExit(f"failed: {args}\n{done.stderr}")
    return int(kb) / 1024**2, float(seconds)


def resized(src: Path, dst: Path, width: int, height: int, kind: str) -> Path:
    buf = oiio.ImageBufAlgo.resize(oiio.ImageBuf(str(src)), roi=oiio.ROI(0, width, 0, height))
    if kind == "jpg":
        buf.specmod().attribute("Compression", "jpeg:90")
    else:
        buf = oiio.ImageBufAlgo.copy(buf, "uint16")
    assert buf.write(str(dst)), oiio.geterror()
    return dst


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        big = resized(DATA / "astronaut.png", root / "big.jpg", 12240, 8160, "jpg")
        u = root / "u"
        gb, s = peak(
            CLI, "unprocess", str(big), "-o", str(u), "-p", "sony_a7s2", "--iso", "800", "-q"
        )
        print(f"unprocess 100 MP JPEG → DNG: peak {gb:.2f} GB ({s:.1f} s)   [target < 2 GB]")
        dng = u / "big.dng"
        for label, extra in (("16-bit TIFF", ["--format", "tiff", "--bits", "16"]), ("PNG", [])):
            out = root / f"p{len(extra)}"
            gb, s = peak(CLI, "process", str(dng), "-o", str(out), "-q", *extra)
            print(f"process 100 MP DNG → {label}: peak {gb:.2f} GB ({s:.1f} s)   [target < 2 GB]")
        libraw = (
            "import rawpy, tifffile, sys; r = rawpy.imread(sys.argv[1]); "
            "tifffile.imwrite(sys.argv[2], r.postprocess(output_bps=16))"
        )
        gb, s = peak(libraw, str(dng), str(root / "libraw.tif"))
        print(f"peer, rawpy AHD → 16-bit TIFF: peak {gb:.2f} GB ({s:.1f} s)")
        photos = root / "photos"
        photos.mkdir()
        for src in sorted(DATA.iterdir()):
            resized(src, photos / f"{src.stem}.png", 2048, 2048, "png")
        frames = root / "frames"
        peak(
            CLI,
            "unprocess",
            str(photos),
            "-o",
            str(frames),
            "-p",
            "sony_a7s2",
            "--iso",
            "800",
            "-q",
        )
        for count in (4, 16, 32):
            folder = root / f"cal{count}"
            folder.mkdir()
            for k in range(count):
                source = sorted(frames.glob("*.dng"))[k % 4]
                (folder / f"{source.stem}_{k}.dng").symlink_to(source)
            args = ["calibrate", str(folder), "--method", "patches", "-o", str(root / "c.json")]
            gb, s = peak(CLI, *args, "--overwrite")
            print(f"calibrate, {count:2d} frames of 4 MP: peak {gb:.2f} GB ({s:.1f} s)")


if __name__ == "__main__":
    main()
