"""Processing speed and memory: rawsim's ISP beside LibRaw (rawpy) and dcraw in the same run.

    python benchmarks/bench_process.py [--quick] [--io] [--half]

Makes a 24 MP, 14-bit DNG with ``rawsim unprocess`` (a test photo resized to
6000×4000, Sony A7S II profile, ISO 800), then times, each in a fresh process so
that peak memory (max RSS) is its own:
  * LibRaw AHD through ``rawpy.postprocess`` (camera WB, sRGB, 16-bit), alone and
    with a 16-bit TIFF write (tifffile) in a fresh interpreter;
  * ``dcraw -T -6 -w`` (AHD, 16-bit TIFF) where installed;
  * ``rawsim process`` with each demosaic method (default: wcd), per image in a
    batch of copies of the file (median of each file's time, start-up and the
    first file, which loads the engine, excluded), 16-bit TIFF out, on the
    compiled engine and, for wcd, on the torch reference (RAWSIM_ENGINE=0);
  * the default output (8-bit PNG) per image, and the write alone;
  * ``rawsim process --half-size`` (16-bit TIFF) beside the full render (the defaults,
    16-bit TIFF), per file in a batch, in alternating rounds (:func:`half_vs_full`;
    ``--half`` runs this alone, on this DNG and on ``--io``'s, whose highlight
    pre-pass has three times the clipped sites to rebuild), and the embedded preview;
  * single cold invocations of ``rawsim process x.dng --format tiff --bits 16``:
    the first after clearing numba's cache (compiling) and later ones;
  * forward and backward of ``rawsim.process`` with gradients on 1 MP;
  * X-Trans: a 24 MP X-Trans DNG of the test photos at their own resolution
    (mirrored tiles; a real camera matrix and white balance), rendered to 16-bit
    sRGB TIFF by ``rawsim process`` (per image in a batch) and by LibRaw's 3-pass
    Markesteijn (postprocess + TIFF write, fresh interpreter): seconds, and CPSNR
    of each render against the photo.
  * (``--io`` runs this alone, on the photo ``IO_EXPOSURE`` stops brighter, 1–2 % of
    its sites clipped) the I/O floor and batches (issues 28, 61), in
    interleaved rounds, medians: marginal seconds per file over 3 copies of the
    file (a batch of 4 less a batch of 1, fresh processes) of ``rawsim process``
    (the defaults → 16-bit TIFF; also with ``--highlights clip``, against the default's
    reconstruction of the photo's clipped sites) and of the floor, rawpy reading the raw plus
    OpenImageIO writing a 16-bit TIFF of the render's size; and 8 copies with
    ``--jobs 2`` beside ``dcraw_emu -T -6`` (LibRaw's AHD, 16-bit TIFF) run two at
    a time on the same files; each run after ``sync``, so that none pays for the
    writeback of the one before. Then 144 MB written in one ``write()`` beside
    1 MiB pieces (:mod:`rawsim.io.pieces`), files kept as a batch keeps them.
Targets (issues 13, 15, 26, 28): steady-state wcd ≤ 0.5× LibRaw AHD with peak ≤ 1.0 GB; the
default output ≤ 0.75× LibRaw AHD + TIFF write; cold ≤ 1.0× rawpy AHD + TIFF write;
backward ≤ 3× forward; X-Trans ≤ 0.5× LibRaw 3-pass (+ TIFF write); process ≤ 2.0×
the I/O floor; 8 files with --jobs 2 ≤ 0.5× dcraw_emu two at a time.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from machine import describe

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "srgb"

LIBRAW = """
import os, sys, time, rawpy, tifffile
t = time.perf_counter()
algorithm = rawpy.DemosaicAlgorithm(int(os.environ.get("LIBRAW_QUALITY", 3)))  # 3: AHD
with rawpy.imread(sys.argv[1]) as raw:
    rgb = raw.postprocess(demosaic_algorithm=algorithm, use_camera_wb=True,
                          output_color=rawpy.ColorSpace.sRGB, output_bps=16, no_auto_bright=True,
                          gamma=(2.4, 12.92) if os.environ.get("LIBRAW_SRGB") else (2.222, 4.5),
                  half_size=bool(os.environ.get("LIBRAW_HALF")))
t1 = time.perf_counter()
if len(sys.argv) > 2:
    tifffile.imwrite(sys.argv[2], rgb, photometric="rgb")
print(t1 - t)
"""

WRITE = """
import sys, time, numpy as np, OpenImageIO as oiio
from rawsim.io.images import write_image
rgb = oiio.ImageBuf(sys.argv[1]).get_pixels(oiio.UINT16)
rgb = (rgb >> 8).astype(np.uint8) if sys.argv[3] == "8" else rgb
t = time.perf_counter()
write_image(sys.argv[2], rgb, sys.argv[2].rsplit(".", 1)[1].replace("tif", "tiff"))
print(time.perf_counter() - t)
"""


FLOOR = """
import sys, numpy as np, rawpy, OpenImageIO as oiio
pixels = None
for i, path in enumerate(sys.argv[2:]):
    with rawpy.imread(path) as raw:
        mosaic = raw.raw_image_visible.copy()
    if pixels is None:  # a render's size and type (its contents cost nothing to write)
        pixels = np.zeros((*mosaic.shape, 3), np.uint16)
    name = f"{sys.argv[1]}/{i}.tif"
    out = oiio.ImageOutput.create(name)
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, oiio.UINT16)
    spec.attribute("compression", "none")  # as rawsim and dcraw write TIFFs
    out.open(name, spec)
    assert out.write_image(pixels), out.geterror()
    out.close()
"""

PIECES = """
import os, statistics, sys, time, numpy as np
from rawsim.io.pieces import PIECE_BYTES, write_pieces
pixels = np.zeros((4000, 6000, 3), np.uint16)  # a 24 MP 16-bit render: 144 MB
times = {"one write()": [], f"{PIECE_BYTES >> 20} MiB writes": []}
os.sync()
for i in range(6):  # files kept until the end, as a batch's are: dirty pages pile up
    for k, name in enumerate(times):
        t = time.perf_counter()
        with open(f"{sys.argv[1]}/pieces{i}{k}.bin", "wb") as f:
            f.write(pixels) if k == 0 else write_pieces(f, pixels)
        times[name].append(time.perf_counter() - t)
print("  write 144 MB, 6 interleaved rounds:", ", ".join(
    f"{name} median {statistics.median(t):.3f} s" for name, t in times.items()))
for i in range(6):
    for k in range(2):
        os.remove(f"{sys.argv[1]}/pieces{i}{k}.bin")
"""


def timed(cmd: list[str], env=None) -> tuple[float, float]:
    """Wall seconds and peak RSS (GB) of one fresh process."""
    wall, peak, _ = timed_cpu(cmd, env)
    return wall, peak


def timed_cpu(cmd: list[str], env=None) -> tuple[float, float, float]:
    """Wall seconds, peak RSS (GB) and CPU seconds (user + system, every thread) of one
    fresh process."""
    t = time.perf_counter()
    _, _, usage = run_child(cmd, env)
    cpu = usage.ru_utime + usage.ru_stime
    return time.perf_counter() - t, usage.ru_maxrss / 1024**2, cpu


def child(cmd: list[str], env=None) -> tuple[str, str, float]:
    """Run ``cmd``; return stdout, stderr and its own peak RSS in GB (from ``wait4``)."""
    stdout, stderr, usage = run_child(cmd, env)
    return stdout, stderr, usage.ru_maxrss / 1024**2


def run_child(cmd: list[str], env=None) -> tuple[str, str, os.struct_rusage]:
    """Run ``cmd``; return stdout, stderr and its own resource usage (from ``wait4``)."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0), err.seek(0)
        stdout, stderr = out.read(), err.read()
    if proc.returncode:
        raise subprocess.CalledProcessError(proc.returncode, cmd, stdout, stderr)
    return stdout, stderr, usage


#: ``--io``'s DNG: the photo this many stops brighter, so that 1–2 % of its sites clip
#: (1.5 %) and the default's highlight reconstruction has work to do.
IO_EXPOSURE = 0.4


def make_dng(tmp: Path, exposure: float = 0.0) -> Path:
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
            "--exposure",
            str(exposure),
        ],
        check=True,
    )
    return tmp / "dng" / "photo24.dng"


def clipped_share(dng: Path) -> float:
    """The share of the mosaic's sites at or above 99 % of the white level."""
    from rawsim.io.raw import read_raw

    raw = read_raw(dng)
    black = float(np.max(raw.black_level))
    return float((raw.data >= black + 0.99 * (raw.white_level - black)).mean())


def rawsim_batch(batch: Path, out_dir: Path, args: list[str], env=None) -> tuple[float, float]:
    """Steady-state seconds per image and peak RSS (GB) of one batch run.

    Per image: the median of each file's own time (``-v`` reports it: render,
    write, and what of its read was not done ahead while the file before
    rendered), the first file excluded (it also loads the compiled engine).
    :func:`io_floor` times whole batches instead.
    """
    _, err, peak = child(["rawsim", "-v", "process", str(batch), "-o", str(out_dir), *args], env)
    shutil.rmtree(out_dir)
    seconds = [float(s) for s in re.findall(r"^done: .* \(([0-9.]+) s\)$", err, re.M)]
    return statistics.median(seconds[1:]), peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one copy, fewer methods")
    ap.add_argument("--io", action="store_true", help="only the I/O floor and batches")
    ap.add_argument("--half", action="store_true", help="only half size against the full render")
    args = ap.parse_args()
    print("\n".join(describe()), flush=True)
    if args.half:
        for exposure in (0.0, IO_EXPOSURE):
            with tempfile.TemporaryDirectory() as d:
                dng = make_dng(Path(d), exposure)
                share = 100 * clipped_share(dng)
                print(f"the DNG: +{exposure} EV, {share:.2f} % of its sites clipped")
                half, full = half_vs_full(Path(d), dng, 5)
                print(
                    f"  rawsim process --half-size (TIFF 16) {half:.3f} s per file, the full "
                    f"render (TIFF 16) {full:.3f} s: {half / full:.2f}× (target ≤ 0.4×)"
                )
        return
    if args.io:
        with tempfile.TemporaryDirectory() as d:
            dng = make_dng(Path(d), IO_EXPOSURE)
            share = 100 * clipped_share(dng)
            print(f"the DNG: +{IO_EXPOSURE} EV, {share:.2f} % of its sites clipped")
            io_floor(Path(d), dng, 5)
        return
    copies = 1 if args.quick else 3
    methods = ["wcd", "bilinear"] if args.quick else ["wcd", "menon", "malvar", "bilinear"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        dng = make_dng(tmp)
        print(f"24 MP 14-bit DNG ({dng.stat().st_size / 1e6:.0f} MB), {os.cpu_count()} cores")
        libraw, libraw_tiff, peak_libraw = [], [], 0.0
        for _ in range(copies):
            out, _, peak = child([sys.executable, "-c", LIBRAW, str(dng)])
            libraw.append(float(out))
            peak_libraw = max(peak_libraw, peak)
            libraw_tiff.append(
                timed([sys.executable, "-c", LIBRAW, str(dng), str(tmp / "libraw.tif")])[0]
            )
        libraw, libraw_tiff = min(libraw), min(libraw_tiff)
        row = "  {:<44} {:6.2f} s  peak {:4.2f} GB  {}"
        print(row.format("LibRaw AHD (rawpy.postprocess), compute", libraw, peak_libraw, ""))
        print(
            row.format("rawpy AHD + TIFF write, fresh interpreter", libraw_tiff, 0, "").replace(
                "peak 0.00 GB", "            "
            )
        )
        if shutil.which("dcraw"):
            seconds = min(
                timed(["dcraw", "-T", "-6", "-w", "-q", "3", str(dng)])[0] for _ in range(copies)
            )
            print(
                row.format("dcraw -T -6 -w -q 3 (AHD)", seconds, 0, "").replace(
                    "peak 0.00 GB", "            "
                )
            )
        batch = tmp / "batch"
        batch.mkdir()
        for i in range(copies + 1):  # the first file loads the engine: not counted
            shutil.copy(dng, batch / f"copy{i}.dng")
        tiff16 = ["--format", "tiff", "--bits", "16"]
        full = {}
        for method in methods:
            seconds, peak = rawsim_batch(batch, tmp / "o", ["--demosaic", method, *tiff16])
            full[method] = seconds
            print(
                row.format(
                    f"rawsim process --demosaic {method} (TIFF 16)",
                    seconds,
                    peak,
                    f"rawsim/LibRaw = {seconds / libraw:4.2f}×",
                )
            )
        reference = dict(os.environ, RAWSIM_ENGINE="0")
        seconds, peak = rawsim_batch(batch, tmp / "o", tiff16, reference)
        print(
            row.format(
                "  torch reference, wcd (RAWSIM_ENGINE=0)",
                seconds,
                peak,
                f"rawsim/LibRaw = {seconds / libraw:4.2f}×",
            )
        )
        seconds, peak = rawsim_batch(batch, tmp / "o", [])
        print(
            row.format(
                "rawsim process, default output (PNG 8)",
                seconds,
                peak,
                f"vs LibRaw + TIFF write = {seconds / libraw_tiff:4.2f}×",
            )
        )
        previews(tmp, batch, copies, full["wcd"])
        render = tmp / "render.tif"
        subprocess.run(["rawsim", "-q", "process", str(dng), "-o", str(tmp), *tiff16], check=True)
        (tmp / "photo24.tif").rename(render)
        for name, bits in (("w.png", "8"), ("w.png", "16"), ("w.tif", "16")):
            out, _, _ = child([sys.executable, "-c", WRITE, str(render), str(tmp / name), bits])
            print(f"    write only: {name[2:].upper()} {bits}-bit {float(out):6.2f} s")
        cache = Path(rawsim_engine_dir()) / "__pycache__"
        shutil.rmtree(cache, ignore_errors=True)
        cold = []
        for _ in range(1 + copies):
            shutil.rmtree(tmp / "cold", ignore_errors=True)
            cold.append(
                timed(["rawsim", "-q", "process", str(dng), "-o", str(tmp / "cold"), *tiff16])
            )
        print(row.format("cold rawsim process x.dng, first run (compiles)", *cold[0], ""))
        seconds, peak = min(cold[1:])
        print(
            row.format(
                "cold rawsim process x.dng, later runs",
                seconds,
                peak,
                f"vs rawpy AHD + TIFF = {seconds / libraw_tiff:4.2f}×",
            )
        )
        print(
            "  targets: wcd ≤ 0.5× LibRaw with peak ≤ 1.0 GB; PNG default ≤ 0.75× LibRaw + TIFF;"
            " cold ≤ 1.0× rawpy + TIFF"
        )
    gradients_1mp()
    with tempfile.TemporaryDirectory() as d:
        xtrans(Path(d), copies)


def xtrans_photo() -> np.ndarray:
    """(4000, 6000, 3) linear sRGB: the test photos at their own size, mirrored to fill."""
    tiles = []
    for path in sorted(DATA.glob("*")):
        x = oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)[:, :, :3]
        tiles.append(np.concatenate([x, x[:, ::-1]], 1))
    rows, width = [], 6000
    while sum(r.shape[0] for r in rows) < 4000:
        tile = tiles[len(rows) % len(tiles)]
        reps = -(-width // tile.shape[1])
        rows.append(np.concatenate([tile, tile[:, ::-1]] * reps, 1)[:, :width])
    return np.concatenate(rows)[:4000] ** 2.2


THUMB = """
import sys, time, rawpy
t = time.perf_counter()
with rawpy.imread(sys.argv[1]) as raw:
    thumb = raw.extract_thumb()
with open(sys.argv[2], "wb") as f:
    f.write(thumb.data)
print(time.perf_counter() - t)
"""


def previews(tmp: Path, batch: Path, copies: int, full: float) -> None:
    """Half-size and embedded-preview renders per image in a batch, beside the full
    render (the half size against one timed in the same rounds, :func:`half_vs_full`;
    the preview against wcd → 16-bit TIFF, ``full`` seconds) and LibRaw's half_size
    and extract_thumb."""
    import exiv2

    env = dict(os.environ, LIBRAW_HALF="1")
    dng = next(batch.iterdir())
    seconds, alike = half_vs_full(tmp, dng, 5)
    libraw = min(
        timed([sys.executable, "-c", LIBRAW, str(dng), str(tmp / "half.tif")], env)[0]
        for _ in range(copies)
    )
    print(
        f"  rawsim process --half-size (TIFF 16)         {seconds:6.3f} s  "
        f"= {seconds / alike:4.2f}× the full render ({alike:.3f} s, the same rounds); LibRaw "
        f"half_size + TIFF write (fresh interpreter) {libraw:.2f} s"
    )
    # A camera-sized embedded preview (1620 × 1080 JPEG), as most raws carry
    preview = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(str(DATA / "astronaut.png")), roi=oiio.ROI(0, 1620, 0, 1080)
    )
    preview.write(str(tmp / "preview.jpg"))
    for path in batch.iterdir():
        image = exiv2.ImageFactory.open(str(path))
        image.readMetadata()
        exiv2.ExifThumb(image.exifData()).setJpegThumbnail((tmp / "preview.jpg").read_bytes())
        image.writeMetadata()
    seconds, _ = rawsim_batch(batch, tmp / "o", ["--thumbnail"])
    libraw = min(
        timed([sys.executable, "-c", THUMB, str(dng), str(tmp / "thumb.jpg")])[0]
        for _ in range(copies)
    )
    print(
        f"  rawsim process --thumbnail (its JPEG)       {seconds:6.2f} s  "
        f"= {seconds / full:4.2f}× the full render; LibRaw extract_thumb (fresh "
        f"interpreter) {libraw:.2f} s"
    )
    print("  target: half size ≤ 0.4× the full render")


def batches(tmp: Path, dng: Path, name: str, sizes: tuple[int, ...]) -> dict[int, Path]:
    """Folders ``tmp/<name><n>`` of ``n`` copies of ``dng`` each, for each n of ``sizes``."""
    folders = {}
    for n in sizes:
        folders[n] = tmp / f"{name}{n}"
        folders[n].mkdir()
        for i in range(n):
            shutil.copy(dng, folders[n] / f"copy{i}.dng")
    return folders


def half_vs_full(tmp: Path, dng: Path, rounds: int) -> tuple[float, float]:
    """Seconds per file in a batch of ``rawsim process --half-size`` and of the full render
    (the defaults; both 16-bit TIFF), measured alike and alternately: ``rounds`` rounds of
    whole batches of 4 copies of ``dng`` and of 1, fresh processes, each after ``sync``;
    the marginal seconds per file over the 3 more, medians. (Each file's own time from
    ``-v`` is printed to 0.01 s, an eighth of a half-size render.)"""
    folders = batches(tmp, dng, "half_vs_full", (1, 4))
    out = tmp / "half_vs_full_out"
    tiff16 = ["--format", "tiff", "--bits", "16"]
    modes = {"half": ["--half-size", *tiff16], "full": tiff16}
    times: dict[tuple[str, int], list[float]] = {(m, n): [] for m in modes for n in folders}
    for _ in range(rounds):
        for mode, args in modes.items():
            for n, folder in folders.items():
                shutil.rmtree(out, ignore_errors=True)
                os.sync()
                command = ["rawsim", "-q", "process", str(folder), "-o", str(out), *args]
                times[mode, n].append(timed(command)[0])
    shutil.rmtree(out, ignore_errors=True)
    for folder in folders.values():
        shutil.rmtree(folder)
    med = {key: statistics.median(t) for key, t in times.items()}
    half, full = ((med[m, 4] - med[m, 1]) / 3 for m in modes)
    return half, full


def make_xtrans_dng(path: Path) -> None:
    """Write the X-Trans DNG of :func:`xtrans_photo` (the A7S II's matrix, an as-shot
    white balance, 90 % of full scale) and beside it ``truth.npy``, the photo as 8-bit
    sRGB levels. Run in a child process: a process forked later inherits its
    parent's peak memory in its own figure."""
    from rawsim.cameras.profiles import load_profile
    from rawsim.cfa import CFA
    from rawsim.color import camera_from_srgb
    from rawsim.io.dng import DngInfo, write_dng

    xt = CFA("XTRANS")
    xyz = np.asarray(load_profile("sony_a7s2").xyz_to_camera)
    neutral = (0.5, 1.0, 0.7)
    linear = 0.9 * xtrans_photo()
    cam = (linear @ camera_from_srgb(xyz).T * neutral).clip(0, 1)
    cmap = np.tile(np.array(xt.colors).reshape(6, 6), (4000 // 6 + 1, 1000))[:4000, :6000]
    mosaic = np.take_along_axis(cam, cmap[..., None], 2)[..., 0]
    info = DngInfo(xt, 1024, 16383, tuple(map(tuple, xyz)), neutral, "Fujifilm", "X", "X", 400)
    write_dng(path, np.round(1024 + mosaic * 15359).astype(np.uint16), info)
    np.save(path.parent / "truth.npy", srgb_8bit(linear).astype(np.uint8))


def xtrans(tmp: Path, copies: int) -> None:
    """X-Trans: rawsim process (default demosaic) beside LibRaw 3-pass Markesteijn."""
    batch = tmp / "xt"
    batch.mkdir()
    dng = str(batch / "copy0.dng")
    code = f"import bench_process as b; b.make_xtrans_dng(b.Path({dng!r}))"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).parent)
    truth = np.load(batch / "truth.npy")
    (batch / "truth.npy").unlink()
    for i in range(1, copies + 1):
        shutil.copy(batch / "copy0.dng", batch / f"copy{i}.dng")
    env = dict(os.environ, LIBRAW_QUALITY="3", LIBRAW_SRGB="1")
    libraw = []
    for _ in range(copies):
        start = time.perf_counter()
        child([sys.executable, "-c", LIBRAW, str(batch / "copy0.dng"), str(tmp / "l.tif")], env)
        libraw.append(time.perf_counter() - start)
    seconds, peak = rawsim_batch(batch, tmp / "o", ["--format", "tiff", "--bits", "16"])
    subprocess.run(
        [
            "rawsim",
            "-q",
            "process",
            str(batch / "copy0.dng"),
            "-o",
            str(tmp / "r"),
            "--format",
            "tiff",
            "--bits",
            "16",
            "--baseline-exposure",
            "ignore",
        ],
        check=True,
    )
    ours = cpsnr(tmp / "r" / "copy0.tif", truth)
    theirs = cpsnr(tmp / "l.tif", truth)
    print(f"X-Trans, 24 MP 14-bit DNG of the test photos, {os.cpu_count()} cores:")
    print(
        f"  LibRaw 3-pass Markesteijn + TIFF write   {min(libraw):6.2f} s   CPSNR {theirs:.2f} dB"
    )
    print(
        f"  rawsim process (icd, TIFF 16)            {seconds:6.2f} s   CPSNR {ours:.2f} dB"
        f"   peak {peak:4.2f} GB   rawsim/LibRaw = {seconds / min(libraw):4.2f}×"
    )
    print("  target: ≤ 0.5× LibRaw 3-pass")


def io_floor(tmp: Path, dng: Path, rounds: int) -> None:
    """``rawsim process`` per file in a batch against the I/O floor, and 8 files with
    ``--jobs 2`` against ``dcraw_emu -T -6`` two at a time: ``rounds`` interleaved
    rounds of fresh processes, medians."""
    folders = batches(tmp, dng, "batch", (1, 4, 8))
    out = tmp / "out"
    tiff16 = ["--format", "tiff", "--bits", "16"]

    def floor(n: int) -> list[str]:
        out.mkdir()
        return [sys.executable, "-c", FLOOR, str(out), *map(str, sorted(folders[n].iterdir()))]

    def rawsim(n: int, *more: str) -> list[str]:
        return ["rawsim", "-q", "process", str(folders[n]), "-o", str(out), *tiff16, *more]

    dcraw = tmp / "dcraw"  # its own copies: dcraw_emu writes <input>.tiff beside each
    shutil.copytree(folders[8], dcraw)

    def dcraw_pairs() -> list[str]:
        files = sorted(str(p) for p in dcraw.glob("*.dng"))
        script = 'printf "%s\\n" "$@" | xargs -P 2 -n 1 dcraw_emu -T -6'
        return ["sh", "-c", script, "sh", *files]

    runs = {
        "floor 1": lambda: floor(1),
        "floor 4": lambda: floor(4),
        "rawsim 1": lambda: rawsim(1),
        "rawsim 4": lambda: rawsim(4),
        "rawsim 1 --highlights clip": lambda: rawsim(1, "--highlights", "clip"),
        "rawsim 4 --highlights clip": lambda: rawsim(4, "--highlights", "clip"),
        "rawsim 8 --jobs 2": lambda: rawsim(8, "--jobs", "2"),
        "dcraw_emu 8, two at a time": dcraw_pairs,
    }
    times: dict[str, list[float]] = {name: [] for name in runs}
    cpus: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(rounds):
        for name, cmd in runs.items():
            shutil.rmtree(out, ignore_errors=True)
            for tiff in dcraw.glob("*.tiff"):
                tiff.unlink()
            os.sync()  # no run pays for the writeback of the one before
            if not name.startswith("floor"):
                out.mkdir()
            command = cmd()
            wall, _, cpu = timed_cpu(command)
            times[name].append(wall)
            cpus[name].append(cpu)
    shutil.rmtree(out, ignore_errors=True)
    med = {name: statistics.median(t) for name, t in times.items()}
    cpu = {name: statistics.median(t) for name, t in cpus.items()}
    ours, theirs = (med["rawsim 4"] - med["rawsim 1"]) / 3, (med["floor 4"] - med["floor 1"]) / 3
    print(f"I/O floor and batches, 24 MP 14-bit DNG, {os.cpu_count()} cores, {rounds} rounds:")
    clip = (med["rawsim 4 --highlights clip"] - med["rawsim 1 --highlights clip"]) / 3
    for name, t in times.items():
        print(f"  {name:<28} median {med[name]:6.2f} s  ({min(t):.2f}–{max(t):.2f})")
    print(
        f"  per file in a batch (marginal over 3 copies): rawsim (defaults) → TIFF 16 "
        f"{ours:.3f} s, "
        f"floor (rawpy read + OIIO TIFF 16 write) {theirs:.3f} s = {ours / theirs:.2f}× "
        f"(target ≤ 2.0×); with --highlights clip {clip:.3f} s = {clip / theirs:.2f}× (what the "
        f"default's reconstruction of the sites that clip costs: {ours - clip:+.3f} s)"
    )
    print(
        f"  the default / --demosaic wcd --highlights clip (the default demosaic): "
        f"{ours / clip:.2f}× (target ≤ 1.3×)"
    )
    # CPU seconds swing less than wall seconds where other machines share the cores
    margin = {name: (cpu[f"{name} 4"] - cpu[f"{name} 1"]) / 3 for name in ("floor", "rawsim")}
    margin["clip"] = (cpu["rawsim 4 --highlights clip"] - cpu["rawsim 1 --highlights clip"]) / 3
    print(
        f"  CPU seconds per file (user + system, every thread; marginal as above): rawsim "
        f"(defaults) {margin['rawsim']:.3f}, with --highlights clip {margin['clip']:.3f} "
        f"({margin['rawsim'] / margin['clip']:.2f}×), floor {margin['floor']:.3f} "
        f"({margin['rawsim'] / margin['floor']:.2f}×)"
    )
    print(
        f"  one file, fresh process: rawsim {med['rawsim 1']:.3f} s = steady per file + "
        f"{med['rawsim 1'] - ours:.3f} s (target ≤ 0.3 s); floor {med['floor 1']:.3f} s = "
        f"steady + {med['floor 1'] - theirs:.3f} s"
    )
    ratio = med["rawsim 8 --jobs 2"] / med["dcraw_emu 8, two at a time"]
    print(f"  8 files, --jobs 2 / dcraw_emu two at a time = {ratio:.2f}× (target ≤ 0.5×)")
    print(child([sys.executable, "-c", PIECES, str(tmp)])[0], end="")


def srgb_8bit(linear: np.ndarray) -> np.ndarray:
    """Linear values → sRGB-coded 8-bit levels (float), clipped to [0, 1] first."""
    from rawsim.colorspaces import SRGB_CURVE

    return np.round(SRGB_CURVE.encode(np.clip(linear, 0, 1)) * 255)


def cpsnr(path: Path, truth: np.ndarray, border: int = 12) -> float:
    """CPSNR (8-bit scale) of a 16-bit TIFF against ``truth`` (8-bit levels), border cut."""
    y = np.round(oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)[:, :, :3] * 255)
    d = (y - truth.astype(np.float64))[border:-border, border:-border]
    return float(10 * np.log10(255**2 / np.mean(d**2)))


def gradients_1mp() -> None:
    """Forward and backward of ``rawsim.process`` (torch reference, default ISP) on 1 MP."""
    import torch

    import rawsim

    sensor = rawsim.RGBSensor.from_profile("nikon_d850")
    image = torch.rand(1, 3, 1024, 1024)
    noisy, _, meta = rawsim.unprocess(image, sensor, seeds=[1], iso=800)
    forward, backward = [], []
    for _ in range(3):
        mosaic = noisy.clone().requires_grad_()
        start = time.perf_counter()
        rgb = rawsim.process(mosaic, sensor, meta)
        forward.append(time.perf_counter() - start)
        start = time.perf_counter()
        rgb.mean().backward()
        backward.append(time.perf_counter() - start)
    fwd, bwd = min(forward), min(backward)
    print(
        f"rawsim.process with gradients, 1 MP (torch reference): forward {fwd:.2f} s, "
        f"backward {bwd:.2f} s = {bwd / fwd:.1f}× forward (target ≤ 3×)"
    )


def rawsim_engine_dir() -> str:
    import rawsim.engine

    return os.path.dirname(rawsim.engine.__file__)


if __name__ == "__main__":
    main()
