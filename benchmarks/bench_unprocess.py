"""Unprocessing speed, each figure printed beside its peer measured in the same run.

    python benchmarks/bench_unprocess.py [--quick]

Measures, on this machine:
  1. one 24 MP JPEG, whole file (decode, unprocess, DNG + JSON written), steady
     state, against the I/O floor: OpenImageIO's decode of the same JPEG plus
     writing the same number of 16-bit samples (tifffile, uncompressed); the
     decode both by OpenImageIO's ``read_image`` (the issue's floor) and by
     strips, as rawsim reads (``read_image`` copies its whole buffer: slower);
     then per file in a batch (``rawsim unprocess`` on folders of 1 and 4 copies,
     fresh processes: the next image is decoded while one is unprocessed) beside
     the same floor run as a batch, and the steady state of a batch of 8: the
     time between one file's end and the next's;
  2. the compute alone (unprocess + mosaic + noise, 24 MP): the compiled engine
     against the eager torch reference, per noise model; and the physics model
     with a 24 MP dark-shading map and black-level error beside without;
  3. whole-file throughput of ``rawsim unprocess`` on folders of 1 MP JPEGs,
     with --jobs 1 and --jobs 2, beside OpenImageIO's decode rate: the whole
     command, the batch, and the steady state (the extra time N more files take);
  4. ``rawsim --help`` latency;
  5. the Python API, ``rawsim.unprocess`` on a (1, 3, 4000, 6000) uint8 tensor
     (channels-first, as a training loader hands it), into new tensors and into
     the same ``out=`` tensors each call, beside the kernel alone
     (``engine_unprocess`` on contiguous (H, W, 3) pixels into preallocated
     outputs) and DeepLens's ``RGBSensor`` (unprocess + mosaic + noise, torch) on
     the same tensor, interleaved; DeepLens from a checkout of singer-yang/DeepLens
     given by ``--deeplens PATH`` (its ``deeplens/sensor`` package is all it loads),
     skipped without one;
  6. spectral scenes (``--spectral`` runs only this): ``rawsim unprocess`` of a 4 MP
     (2448×1632), 31-band (400–700 nm, 10 nm) reflectance scene, as an uncompressed
     npz, a compressed npz and a ZIP EXR, beside the same image as RGB (its sRGB
     rendering as a 16-bit PNG and as a JPEG), whole command, fresh processes,
     interleaved rounds, the same options (-p nikon_d850 --iso 800 --jobs 1), each
     command's peak resident memory (its own, and the pages of files it maps);
     then the spectral path's stages in one process.
Inputs are made by resizing the real photos in tests/data/srgb.
Targets (issue 13, 2-core machine): (1) ≤ 2.0× the I/O floor, (2) engine ≥ 6×
the torch reference and physics ≤ 1.5× gaussian, (3) ≥ 50 images/s with --jobs 2.
Issue 28: (1) ≤ 1.3× the I/O floor; (5) the API ≤ 1.2× the kernel alone and ≥ 10×
DeepLens. Issue 30: (2) dark shading ≤ 1.2× the physics model without. Issue 63:
(6) the 31-band scene (uncompressed npz) ≤ 2× the same image as RGB (16-bit PNG).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import types
from functools import partial
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import tifffile
import torch
from machine import describe

import rawsim
from rawsim.cameras.profiles import load_profile
from rawsim.io.images import read_pixels
from rawsim.io.task import Task
from rawsim.noise.dark_shading import write_maps
from rawsim.noise.seeds import derive_seed
from rawsim.pipelines.unprocess import UnprocessOptions, engine_unprocess, simulate, unprocess_file

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "srgb"


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


def oiio_decode_strips(path: Path) -> np.ndarray:
    """OpenImageIO's decode by strips into one array, as rawsim reads."""
    inp = oiio.ImageInput.open(str(path))
    pixels = read_pixels(inp, inp.spec(), oiio.UINT8)
    inp.close()
    return pixels


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def interleaved(runs: dict, repeat: int, before=None) -> dict[str, list[float]]:
    """Seconds of each of ``runs`` (name → callable) over ``repeat`` interleaved
    rounds: the machine's slow spells hit all of them alike. ``before()``, if
    given, runs untimed before each."""
    times: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(repeat):
        for name, fn in runs.items():
            if before is not None:
                before()
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return times


def file_24mp(tmp: Path, repeat: int) -> None:
    photo = tmp / "photo24.jpg"

    def floor(decode) -> None:
        pixels = decode(photo)
        tifffile.imwrite(tmp / "floor.tif", np.zeros(pixels.shape[:2], np.uint16))

    options = UnprocessOptions(profile=load_profile("sony_a7s2"), iso=1600)
    task = Task(photo, "photo24.jpg", {"dng": tmp / "o.dng", "json": tmp / "o.json"}, 7)
    unprocess_file(task, options)  # warm: compiled code loaded from the cache
    runs = {
        "read_image": partial(floor, oiio_decode),
        "strip reads": partial(floor, oiio_decode_strips),
        "rawsim": lambda: unprocess_file(task, options),
    }
    outputs = [tmp / "floor.tif", *task.outputs.values()]

    def new_files() -> None:
        """Each run writes new files, as a batch does: on ext4, a file written over
        (truncated, or renamed over) is flushed at once, which no batch pays."""
        for path in outputs:
            path.unlink(missing_ok=True)

    times = interleaved(runs, repeat, new_files)
    labels = {
        "read_image": "I/O floor: OIIO read_image + 16-bit write",
        "strip reads": "I/O floor: OIIO strip reads + 16-bit write",
        "rawsim": "rawsim unprocess (DNG + JSON)",
    }
    print(f"1. one 24 MP JPEG (6000×4000), whole file, steady state ({repeat} rounds)")
    for name, t in times.items():
        print(f"   {labels[name]:<44} best {min(t):6.3f} s   median {statistics.median(t):6.3f} s")
    ours = times["rawsim"]
    for name in ("read_image", "strip reads"):
        best_ratio = min(ours) / min(times[name])
        median_ratio = statistics.median(ours) / statistics.median(times[name])
        print(
            f"   rawsim / the {name} floor: best {best_ratio:.2f}×, "
            f"median {median_ratio:.2f}× (target ≤ 2.0×; issue 28: ≤ 1.3×)"
        )


BATCH_FLOOR = """
import sys, numpy as np, OpenImageIO as oiio
from rawsim.io.images import read_pixels
from rawsim.io.pieces import write_pieces
for i, path in enumerate(sys.argv[2:]):
    inp = oiio.ImageInput.open(path)
    pixels = read_pixels(inp, inp.spec(), oiio.UINT8)
    inp.close()
    with open(f"{sys.argv[1]}/{i}.raw", "wb") as f:  # a mosaic's 16-bit samples
        write_pieces(f, np.zeros(pixels.shape[:2], np.uint16))
    print(f"done: {path}", file=sys.stderr, flush=True)
"""


def batch_24mp(tmp: Path, rounds: int) -> None:
    """Per 24 MP JPEG in a batch, ``rawsim unprocess`` (DNG + JSON; the next image
    decoded while this one is unprocessed) beside the floor, OpenImageIO's strip
    decode plus the mosaic's 16-bit samples written in 1 MiB pieces, each run in
    fresh processes after ``sync``, ``rounds`` interleaved rounds, medians:

    * the marginal seconds of 3 more copies (a folder of 4 less a folder of 1),
      which include what a process's first file costs more in a batch than alone
      (its engine loads while two decodes wait for the interpreter: 0.5–0.8 s
      from one run to the next);
    * the steady state of a batch of 8: the time from one file's end to the
      next's (each reported as it ends), files 2 to 7 (the first loads the
      engine, the last has no next image to decode beside it).
    """
    folders = {}
    for n in (1, 4, 8):
        folders[n] = tmp / f"jpegs{n}"
        folders[n].mkdir()
        for i in range(n):
            shutil.copy(tmp / "photo24.jpg", folders[n] / f"copy{i}.jpg")
    out = tmp / "batch_out"
    runs = {}
    for n in (1, 4, 8):
        files = [str(p) for p in sorted(folders[n].iterdir())]
        runs[f"floor {n}"] = [sys.executable, "-c", BATCH_FLOOR, str(out), *files]
        runs[f"rawsim {n}"] = ["rawsim", "-v", "unprocess", str(folders[n]), "-o", str(out)]
        runs[f"rawsim {n}"] += ["-p", "sony_a7s2", "--iso", "1600"]
    times: dict[str, list[float]] = {name: [] for name in runs}
    steady: dict[str, list[float]] = {"rawsim": [], "floor": []}
    for _ in range(rounds):
        for name, cmd in runs.items():
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            os.sync()
            start = time.perf_counter()
            ends = _file_ends(cmd)
            times[name].append(time.perf_counter() - start)
            if name.endswith(" 8"):
                steady[name.split()[0]] += list(np.diff(ends)[:-1])
    shutil.rmtree(out, ignore_errors=True)
    med = {name: statistics.median(t) for name, t in times.items()}
    ours, floor = ((med[f"{k} 4"] - med[f"{k} 1"]) / 3 for k in ("rawsim", "floor"))
    print(f"   in a batch, per file ({rounds} rounds, medians):")
    print(
        f"   marginal over 3 copies: rawsim {ours:.3f} s, floor (strip decode + 16-bit "
        f"mosaic written) {floor:.3f} s = {ours / floor:.2f}× (issue 28: ≤ 1.3×)"
    )
    ours, floor = (statistics.median(steady[k]) for k in ("rawsim", "floor"))
    print(
        f"   steady state, files 2–7 of 8: rawsim {ours:.3f} s, floor {floor:.3f} s "
        f"= {ours / floor:.2f}× (issue 28: ≤ 1.3×)"
    )
    print(
        f"   one file, fresh process: rawsim {med['rawsim 1']:.3f} s = steady + "
        f"{med['rawsim 1'] - ours:.3f} s (issue 42: ≤ 0.3 s); floor {med['floor 1']:.3f} s "
        f"= steady + {med['floor 1'] - floor:.3f} s"
    )


def _file_ends(cmd: list[str]) -> list[float]:
    """Run ``cmd``; the times (perf_counter) at which it reported each file done
    (its ``done:`` lines on stderr, read as they come)."""
    ends = []
    pipes = {"stderr": subprocess.PIPE, "stdout": subprocess.DEVNULL, "text": True}
    with subprocess.Popen(cmd, **pipes) as proc:
        for line in proc.stderr:
            if line.startswith("done:"):
                ends.append(time.perf_counter())
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode})")
    return ends


def compute_24mp(tmp: Path, repeat: int) -> None:
    pixels = oiio_decode(tmp / "photo24.jpg")
    image = torch.from_numpy(pixels).permute(2, 0, 1).unsqueeze(0)
    profile = load_profile("sony_a7s2")
    print(f"2. compute only, 24 MP: engine vs torch reference ({torch.get_num_threads()} threads)")
    engine = {}
    physics = UnprocessOptions(profile=profile, iso=1600, noise="physics")
    for _ in range(5):  # a fresh process's first large arrays are slow to come by
        simulate(physics.make_sensor(), pixels, physics, 1, engine=True)
    for noise in ("none", "gaussian", "poisson-gaussian", "physics"):
        options = UnprocessOptions(profile=profile, iso=1600, noise=noise)
        sensor = options.make_sensor()
        engine[noise] = best(partial(simulate, sensor, pixels, options, 1, engine=True), repeat)
        torch_s = best(partial(simulate, sensor, image, options, 1, engine=False), 1)
        print(
            f"   {f'noise={noise}':<22} engine {engine[noise]:6.3f} s   torch {torch_s:6.3f} s"
            f"   {torch_s / engine[noise]:5.1f}× (target ≥ 6×)"
        )
    print(
        f"   physics / gaussian on the engine: {engine['physics'] / engine['gaussian']:.2f}× "
        "(target ≤ 1.5×)"
    )
    options = UnprocessOptions(profile=dark_profile(tmp, 4000, 6000), iso=1600, noise="physics")
    sensor = options.make_sensor()
    simulate(sensor, pixels, options, 1, engine=True)  # the maps decoded once (cached)
    runs = {
        "physics": partial(simulate, physics.make_sensor(), pixels, physics, 1, engine=True),
        "dark": partial(simulate, sensor, pixels, options, 1, engine=True),
    }
    times = {name: min(t) for name, t in interleaved(runs, repeat).items()}
    print(
        f"   physics + dark shading and black-level error {times['dark']:6.3f} s, without "
        f"{times['physics']:6.3f} s: {times['dark'] / times['physics']:.2f}× (issue 30: ≤ 1.2×)"
    )


def dark_profile(tmp: Path, h: int, w: int):
    """sony_a7s2 with random dark-shading maps (h × w, one gain range; k σ 0.01 DN/ISO,
    b σ 5 DN) and a black-level error of σ 2 DN."""
    data = json.loads(Path(load_profile("sony_a7s2").path).read_text())
    rng = np.random.default_rng(0)
    k = rng.normal(0, 0.01, (1, h, w)).astype(np.float32)
    b = rng.normal(0, 5.0, (1, h, w)).astype(np.float32)
    write_maps(tmp / "bench.dark.npz", [(100.0, 102400.0)], k, b, data["cfa_pattern"])
    data["noise"]["dark_shading"] = {
        "file": "bench.dark.npz",
        "iso_ranges": [[100, 102400]],
        "size": [h, w],
    }
    data["noise"]["black_level_error"] = {"iso": [100], "sigma": [2.0]}
    data["source"]["noise.dark_shading"] = data["source"]["noise.black_level_error"] = "random"
    path = tmp / "dark.json"
    path.write_text(json.dumps(data))
    return load_profile(path)


def batch_seconds(folder: Path, out: Path, jobs: int) -> tuple[float, float]:
    """(summary time, wall time incl. start-up) of ``rawsim unprocess`` on ``folder``."""
    cmd = ["rawsim", "-q", "unprocess", str(folder), "-o", str(out), "-p", "sony_a7s2"]
    cmd += ["--iso", "1600", "--jobs", str(jobs)]
    start = time.perf_counter()
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    shutil.rmtree(out)
    return float(re.search(r"in ([0-9.]+) s", done.stderr).group(1)), elapsed


def throughput(tmp: Path, count: int) -> None:
    """Whole-file rate on ``count`` and ``2·count`` files: the difference of the two
    batches' times (from the summary, best of two runs) is the steady-state rate,
    without the start-up (imports, compiled-code load, workers)."""
    sources = sorted(DATA.glob("*"))
    folders = {n: tmp / f"jpegs{n}" for n in (count, 2 * count)}
    for n, folder in folders.items():
        folder.mkdir()
        for i in range(n):
            resized(sources[i % len(sources)], folder / f"img{i:03d}.jpg", 1224, 816)
    decode_s = best(lambda: [oiio_decode(p) for p in sorted(folders[count].glob("*.jpg"))], 3)
    print("3. whole files: JPEGs of 1 MP (1224×816), ISO 1600, DNG + JSON out")
    print(f"   {'OpenImageIO decode only (reference)':<44} {count / decode_s:7.1f} images/s")
    for jobs in (1, 2):
        # Best of two runs each: the machine is noisy and start-up varies by seconds.
        one, one_wall = min(batch_seconds(folders[count], tmp / "out", jobs) for _ in range(2))
        two, _ = min(batch_seconds(folders[2 * count], tmp / "out", jobs) for _ in range(2))
        print(
            f"   {f'--jobs {jobs}: {count} files, whole command':<44} "
            f"{count / one_wall:7.1f} images/s   (start-up {one_wall - one:.1f} s)"
        )
        print(
            f"   {f'--jobs {jobs}: {count} files, batch (summary time)':<44} "
            f"{count / one:7.1f} images/s"
        )
        rate = f"{count / (two - one):7.1f}" if two > one else "    n/a (too noisy)"
        print(
            f"   {f'--jobs {jobs}: steady state ({count} more files)':<44} "
            f"{rate} images/s   (target ≥ 50 with --jobs 2)"
        )


def help_latency() -> None:
    times = []
    for _ in range(5):
        start = time.perf_counter()
        subprocess.run(["rawsim", "--help"], check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    print(
        f"4. rawsim --help: median {statistics.median(times):.3f} s, best {min(times):.3f} s "
        "(target ≤ 0.3 s)"
    )


def deeplens_sensor(checkout: Path):
    """DeepLens's RGBSensor from a checkout, its Canon R6 config where it ships one.

    Only ``deeplens.sensor`` is loaded (torch alone): the package's ``__init__``,
    which imports its optics, is bypassed by a namespace module.
    """
    package = types.ModuleType("deeplens")
    package.__path__ = [str(checkout / "deeplens")]
    sys.modules.setdefault("deeplens", package)
    from deeplens.sensor import RGBSensor as DeepLensSensor

    config = checkout / "datasets" / "sensors" / "canon_r6.json"
    return DeepLensSensor.from_config(str(config)) if config.exists() else DeepLensSensor()


def api_24mp(photo: Path, repeat: int, deeplens: Path | None) -> None:
    """The API call, the kernel alone and DeepLens on one (1, 3, 4000, 6000) uint8
    tensor (``photo`` decoded), interleaved rounds; medians (and bests) and ratios."""
    pixels = oiio_decode(photo)
    image = torch.from_numpy(pixels).permute(2, 0, 1)[None].contiguous()  # channels-first
    sensor = rawsim.RGBSensor(load_profile("sony_a7s2"))
    options = UnprocessOptions(profile=sensor.profile, iso=1600, clean=True)
    hwc = np.ascontiguousarray(pixels)
    sim = simulate(sensor, hwc, options, 7)  # the parameters and noise levels of seed 7
    out = (np.empty(hwc.shape[:2], np.float32), np.empty(hwc.shape[:2], np.float32))
    key = derive_seed(7, "noise")

    def kernel() -> None:
        engine_unprocess(sensor, hwc, sim.params, noise=sim.levels, key=key, clean=True, out=out)

    reused = (torch.empty(1, 1, *hwc.shape[:2]), torch.empty(1, 1, *hwc.shape[:2]))
    runs = {
        "api": lambda: rawsim.unprocess(image, sensor, [7], iso=1600),
        "api out=": lambda: rawsim.unprocess(image, sensor, [7], iso=1600, out=reused),
        "kernel": kernel,
    }
    if deeplens is not None:
        peer = deeplens_sensor(deeplens)
        iso = torch.tensor([800.0])  # its noise model's limit; the cost is the same

        def peer_run() -> None:
            with torch.no_grad():
                raw = peer.linrgb2raw(peer.unprocess(image.float() / 255))
                peer.simu_noise(raw, iso)

        runs["deeplens"] = peer_run
    for fn in runs.values():  # warm: compiled code for this layout loaded from the cache
        fn()
    times = interleaved(runs, repeat)
    labels = {
        "api": "rawsim.unprocess, channels-first uint8",
        "api out=": "the same, into the same out= tensors",
        "kernel": "kernel alone (contiguous HWC, preallocated)",
        "deeplens": "DeepLens RGBSensor (unprocess+mosaic+noise)",
    }
    print(f"5. Python API on a (1, 3, 4000, 6000) uint8 tensor ({repeat} rounds, noise + clean)")
    for name, t in times.items():
        print(f"   {labels[name]:<46} median {statistics.median(t):6.3f} s   best {min(t):6.3f} s")
    med = {name: statistics.median(t) for name, t in times.items()}
    for name in ("api", "api out="):
        print(f"   {name} / kernel alone: {med[name] / med['kernel']:.2f}× (target ≤ 1.2×)")
    if "deeplens" in med:
        for name in ("api", "api out=", "kernel"):
            target = "" if name == "kernel" else " (target ≥ 10×)"
            print(f"   DeepLens / {name}: {med['deeplens'] / med[name]:.1f}×{target}")
    else:
        print("   DeepLens: skipped (give --deeplens PATH, a checkout of singer-yang/DeepLens)")


#: The spectral scene's size and bands (section 6).
SPECTRAL_W, SPECTRAL_H = 2448, 1632
SPECTRAL_NM = np.arange(400, 701, 10.0)


def spectral_scene(tmp: Path) -> dict[str, Path]:
    """The 4 MP, 31-band reflectance scene of section 6 and the same image as RGB:
    astronaut.png resized, its linear sRGB spread over three smooth bells (red, green
    and blue reflectances, clipped to 0–1); the RGB files are the resized sRGB itself.
    Returns label → file."""
    from rawsim.io.images import write_image

    roi = oiio.ROI(0, SPECTRAL_W, 0, SPECTRAL_H, 0, 1, 0, 3)
    buf = oiio.ImageBufAlgo.resize(oiio.ImageBuf(str(DATA / "astronaut.png")), roi=roi)
    srgb = buf.get_pixels(oiio.FLOAT)[:, :, :3]
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    bell = lambda centre, width: np.exp(-0.5 * ((SPECTRAL_NM - centre) / width) ** 2)  # noqa: E731
    basis = np.stack([bell(610, 45), bell(540, 40), bell(455, 35)])  # (3, 31)
    flat = np.clip(linear.reshape(-1, 3) @ basis, 0, 1).astype(np.float32)
    spectra = flat.reshape(SPECTRAL_H, SPECTRAL_W, len(SPECTRAL_NM))
    folder = tmp / "spectral"
    folder.mkdir()
    files = {
        "npz": folder / "scene.npz",
        "npz compressed": folder / "compressed.npz",
        "exr": folder / "scene.exr",
        "rgb png16": folder / "scene.png",
        "rgb jpeg": folder / "scene.jpg",
    }
    np.savez(files["npz"], spectra=spectra, wavelengths=SPECTRAL_NM)
    np.savez_compressed(files["npz compressed"], spectra=spectra, wavelengths=SPECTRAL_NM)
    spec = oiio.ImageSpec(SPECTRAL_W, SPECTRAL_H, len(SPECTRAL_NM), oiio.FLOAT)
    spec.channelnames = tuple(f"{v:g}nm" for v in SPECTRAL_NM)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(files["exr"]))
    assert out.open(str(files["exr"]), spec) and out.write_image(spectra), oiio.geterror()
    out.close()
    write_image(files["rgb png16"], np.round(srgb * 65535).astype(np.uint16), "png")
    write_image(files["rgb jpeg"], np.round(srgb * 255).astype(np.uint8), "jpg")
    return files


def _command_seconds_and_memory(cmd: list[str]) -> tuple[float, float, float]:
    """(wall seconds, peak anonymous and peak file-backed resident MiB) of one fresh
    process running ``cmd``, its /proc status read every 5 ms (the kernel's own
    ru_maxrss of a child counts the pages of the process that forked it, this one,
    and does not tell a mapped file's pages, which the page cache keeps, from the
    process's own)."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peak = {"RssAnon": 0, "RssFile": 0}
    status = Path(f"/proc/{proc.pid}/status")
    while proc.poll() is None:
        try:
            for line in status.read_text().splitlines():
                key, _, value = line.partition(":")
                if key in peak:
                    peak[key] = max(peak[key], int(value.split()[0]))
        except (OSError, ValueError, IndexError):
            pass
        time.sleep(0.005)
    seconds = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.read()}")
    proc.stderr.close()
    return seconds, peak["RssAnon"] / 1024, peak["RssFile"] / 1024


def spectral_4mp(tmp: Path, rounds: int) -> None:
    """Section 6: the whole command on each of :func:`spectral_scene`'s files,
    ``rounds`` interleaved rounds (a first, untimed, loads every kernel and the
    files into the page cache), then :func:`spectral_stages`."""
    files = spectral_scene(tmp)
    out = tmp / "spectral_out"
    options = ["-p", "nikon_d850", "--iso", "800", "--jobs", "1"]
    runs = {
        name: ["rawsim", "-q", "unprocess", str(path), "-o", str(out), *options]
        for name, path in files.items()
    }

    def fresh(cmd: list[str]) -> tuple[float, float, float]:
        shutil.rmtree(out, ignore_errors=True)  # new files, as a batch writes (section 1)
        return _command_seconds_and_memory(cmd)

    for cmd in runs.values():
        fresh(cmd)
    times: dict[str, list[float]] = {name: [] for name in runs}
    memory: dict[str, tuple[float, float]] = {}
    for _ in range(rounds):
        for name, cmd in runs.items():
            seconds, anon, mapped = fresh(cmd)
            times[name].append(seconds)
            before = memory.get(name, (0.0, 0.0))
            memory[name] = (max(before[0], anon), max(before[1], mapped))
    shutil.rmtree(out, ignore_errors=True)
    mib = {name: path.stat().st_size / 2**20 for name, path in files.items()}
    print(
        f"6. spectral: {SPECTRAL_W}×{SPECTRAL_H}, {len(SPECTRAL_NM)} bands, whole command "
        f"(rawsim unprocess {' '.join(options)}), {rounds} rounds"
    )
    print("   (peak resident MiB: the process's own memory, and pages of files it maps)")
    for name, t in times.items():
        print(
            f"   {name:<16} {mib[name]:5.0f} MiB file   median {statistics.median(t):6.3f} s"
            f"   best {min(t):6.3f} s   peak own {memory[name][0]:5.0f}, files "
            f"{memory[name][1]:4.0f} MiB"
        )
    rgb = statistics.median(times["rgb png16"])
    for name in ("npz", "npz compressed", "exr"):
        target = " (issue 63: ≤ 2×)" if name == "npz" else ""
        print(
            f"   {name} / rgb png16: median {statistics.median(times[name]) / rgb:.2f}×, "
            f"best {min(times[name]) / min(times['rgb png16']):.2f}×{target}"
        )
    spectral_stages(files["npz"], files["exr"], tmp, max(rounds, 3))


def spectral_stages(npz: Path, exr: Path, tmp: Path, repeat: int) -> None:
    """The spectral path's stages in this process, best of ``repeat``: reading the
    scene (the npz mapped and its values checked; the EXR decoded), the integral
    (the compiled kernel, and numpy's float64 matmul it replaced), the colour
    matrices' fit (once per camera and process) and the whole file."""
    from rawsim.cameras import spectra
    from rawsim.io.spectral import read_spectral
    from rawsim.spectral import render, tables

    scene = read_spectral(npz)
    curves = spectra.of_profile(load_profile("nikon_d850"))
    light = tables.illuminant("D65")
    weights = render.band_weights(scene.wavelengths, curves.rgb, light, scene.kind)
    render.camera_rgb(scene.spectra, scene.wavelengths, curves.rgb, light, scene.kind)

    def numpy_matmul() -> None:
        h, w, n = scene.spectra.shape
        (scene.spectra.reshape(-1, n).astype(np.float64) @ weights).astype(np.float32)

    options = UnprocessOptions(profile=load_profile("nikon_d850"), iso=800)
    task = Task(npz, "scene.npz", {"dng": tmp / "s.dng", "json": tmp / "s.json"}, 7)
    unprocess_file(task, options)
    stages = {
        "read npz (mapped, values checked)": lambda: read_spectral(npz),
        "read EXR (OpenImageIO, ZIP)": lambda: read_spectral(exr),
        "integral, compiled kernel": lambda: render.camera_rgb(
            scene.spectra, scene.wavelengths, curves.rgb, light, scene.kind, engine=True
        ),
        "integral, numpy float64 matmul (before)": numpy_matmul,
        "colour matrices' fit (first file)": lambda: (
            render._fits.clear(),
            render.dng_matrices(curves),
        ),
        "whole file (unprocess_file)": lambda: unprocess_file(task, options),
    }
    print(f"   stages in one process, best of {repeat}:")
    for name, fn in stages.items():
        print(f"     {name:<42} {best(fn, repeat):6.3f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats and files")
    ap.add_argument(
        "--only", type=int, action="append", choices=range(1, 7), help="run only these sections"
    )
    ap.add_argument("--spectral", action="store_true", help="run only section 6 (spectral)")
    ap.add_argument(
        "--deeplens",
        type=Path,
        default=os.environ.get("RAWSIM_DEEPLENS"),
        help="a checkout of singer-yang/DeepLens for section 5 (default: $RAWSIM_DEEPLENS)",
    )
    args = ap.parse_args()
    print("\n".join(describe()), flush=True)
    run = {6} if args.spectral else set(args.only or range(1, 7))
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if run & {1, 2, 5}:
            photo = resized(DATA / "astronaut.png", tmp / "photo24.jpg", 6000, 4000)
        if 1 in run:
            file_24mp(tmp, 7 if args.quick else 15)
            batch_24mp(tmp, 3 if args.quick else 5)
        if 2 in run:
            compute_24mp(tmp, 2 if args.quick else 5)
        if 3 in run:
            throughput(tmp, 40 if args.quick else 200)
        if 4 in run:
            help_latency()
        if 5 in run:
            api_24mp(photo, 5 if args.quick else 11, args.deeplens)
        if 6 in run:
            spectral_4mp(tmp, 3 if args.quick else 7)
    sys.stdout.flush()
    if 5 in run and not any(k in os.environ for k in KEEP_HEAP):
        settings = " ".join(f"{k}={v}" for k, v in KEEP_HEAP.items())
        print(f"5b. the same in a process started with {settings}:", flush=True)
        command = [sys.executable, __file__, "--only", "5", *(["--quick"] if args.quick else [])]
        if args.deeplens is not None:
            command += ["--deeplens", str(args.deeplens)]
        subprocess.run(command, check=True, env={**os.environ, **KEEP_HEAP})


#: glibc serves allocations of 32 MiB and more (unless told otherwise) with their own
#: mmap, returned to the system when freed: each call's new tensors then fault in
#: and zero fresh pages. With a higher threshold they come from the heap, and with
#: a higher trim threshold the heap keeps what is freed, for the next call's.
KEEP_HEAP = {"MALLOC_MMAP_THRESHOLD_": str(1 << 30), "MALLOC_TRIM_THRESHOLD_": str(4 << 30)}


if __name__ == "__main__":
    main()
