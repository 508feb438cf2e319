"""Raw denoising against known truth: rawsim's ``profiled`` beside BM3D, LibRaw's
wavelet denoise and rawsim's ``bilateral``, measured in the same run.

Each photo (default: the 12 Kodak crops in tests/data/kodak; the whole Kodak set
with ``--images DIR``) is unprocessed by ``rawsim unprocess --clean`` with each
``--profiles`` at each ``--isos``, seed 1: a noisy DNG and its noise-free
twin. Every method then denoises the noisy mosaic, and is scored by PSNR (peak:
white) against the clean mosaic (normalised, black 0, white 1), and against the
clean render:

* ``profiled``: rawsim's engine (:func:`rawsim.engine.denoise.denoise_mosaic`),
  with the noise model of the DNG's NoiseProfile tag (the true parameters);
* ``learned``: that, refined by the network (:func:`rawsim.denoise.learned.
  refine_mosaic`), trained on photos outside the Kodak set;
* ``bm3d``: the ``bm3d`` package (PyPI; a benchmark anchor only, not a dependency
  of rawsim, whose licence is not for shipping: ``pip install bm3d``) on each CFA
  plane after the same generalised Anscombe transform, with the same true
  parameters and the same unbiased inverse (an X-Trans mosaic is one plane, its
  colour pattern taken out first as ``profiled`` takes it out);
* ``bilateral``: rawsim's ``denoise`` stage on the mosaic planes, its range σ
  swept over 1, 2 and 3 × the noise σ at mid-grey and the best kept per image;
* ``libraw -n T``: LibRaw's wavelet denoise (``dcraw_emu -n T``), T swept over
  ``--libraw-thresholds`` and the best kept per image. It works inside LibRaw's
  own render, so it is scored on renders only: LibRaw's render of the noisy DNG
  with ``-n T`` against its render of the clean DNG.
* ``darktable dn``: darktable's "denoise (profiled)" through ``darktable-cli``
  (:class:`Darktable`: its non-local means and wavelets, the better kept per
  image), scored like LibRaw's: darktable's render of the noisy DNG with the
  module on against its render of the clean DNG with it off. darktable exports
  no image under ~300 px, so it is measured on full-size photos only (``--images``).

Renders: rawsim's (engine, its default ISP: camera white balance, ``wcd``, sRGB,
16 bits) of the denoised mosaic against rawsim's render of the clean DNG;
LibRaw's (``dcraw_emu -w -6 -W -T``: AHD, sRGB, 16 bits, no auto-brightening)
likewise; its times include starting the process (darktable's: the render's
time less the same render without the module). Times are per megapixel of
mosaic, on this machine (printed first).

    python benchmarks/bench_denoise.py                       # the vendored crops
    python benchmarks/bench_denoise.py --images /path/to/kodak
    python benchmarks/bench_denoise.py --tune                # the threshold, on other photos
    python benchmarks/bench_denoise.py --dng                 # --format dng through LibRaw
    python benchmarks/bench_denoise.py --images DIR --profiles sony_imx686:physics --isos 3200

``--tune`` sweeps the first pass's threshold on the vendored photos of
tests/data/srgb (not Kodak), so that the table's photos play no part in choosing it.
"""

from __future__ import annotations

import argparse
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import describe

from rawsim.denoise.layout import THRESHOLD, plane_layout
from rawsim.denoise.noise_model import dng_noise_profile, noise_model_for
from rawsim.engine.denoise import denoise_mosaic
from rawsim.io.raw import read_raw

HERE = Path(__file__).resolve().parents[1]
KODAK = HERE / "tests" / "data" / "kodak"
OTHER = HERE / "tests" / "data" / "srgb"


def unprocess(images: Path, out: Path, profile: str, iso: int) -> list[tuple[Path, Path]]:
    """(noisy, clean) DNG pairs of every photo in ``images``; ``profile`` is a name, or
    ``NAME:NOISE`` with unprocess's ``--noise`` model (default Poisson-Gaussian)."""
    name, _, noise = profile.partition(":")
    cmd = ["rawsim", "unprocess", str(images), "-o", str(out), "--profile", name]
    cmd += ["--noise", noise or "poisson-gaussian"]
    cmd += ["--iso", str(iso), "--clean", "--seed", "1", "-q"]
    subprocess.run(cmd, check=True)
    return [
        (p, p.with_name(p.stem + ".clean.dng"))
        for p in sorted(out.rglob("*.dng"))
        if not p.name.endswith(".clean.dng")
    ]


def normalised(raw) -> np.ndarray:
    """The mosaic as float64, black 0, white 1."""
    b = black_map(raw)
    return (raw.data.astype(np.float64) - b) / (raw.white_level - b)


def model_of(raw, estimated: bool = False) -> tuple[list[float], list[float]]:
    """(gain, offset) per colour, white = 1: the DNG NoiseProfile's (the true noise),
    or with ``estimated`` the model ``process`` would take (:func:`noise_model_for`)."""
    model = noise_model_for(raw) if estimated else dng_noise_profile(raw)
    return model.normalised(raw.white_level - float(np.mean(raw.black_level)))


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float:
    return 10 * math.log10(peak**2 / float(np.mean((a - b) ** 2)))


def as_dn(raw, x: np.ndarray) -> np.ndarray:
    """Normalised values back to the raw's uint16 DN."""
    black = black_map(raw)
    return np.clip(np.round(black + x * (raw.white_level - black)), 0, 65535).astype(np.uint16)


def black_map(raw) -> np.ndarray:
    """The black level of every site (DN)."""
    black = np.broadcast_to(np.asarray(raw.black_level, np.float64), raw.cfa.period)
    reps = (-(-raw.data.shape[0] // black.shape[0]), -(-raw.data.shape[1] // black.shape[1]))
    return np.tile(black, reps)[: raw.data.shape[0], : raw.data.shape[1]]


# ------------------------------------------------------------------ methods
def profiled(raw, threshold: float = THRESHOLD) -> np.ndarray:
    gain, offset = model_of(raw)
    black = np.asarray(raw.black_level, np.float64)
    return denoise_mosaic(raw.data, raw.cfa, black, raw.white_level, gain, offset, 1.0, threshold)


def learned(raw) -> np.ndarray:
    from rawsim.denoise.learned import refine_mosaic

    gain, offset = model_of(raw)
    black = np.asarray(raw.black_level, np.float64)
    estimate = profiled(raw)
    return refine_mosaic(raw.data, estimate, raw.cfa, black, raw.white_level, gain, offset)


def bm3d_planes(raw) -> np.ndarray:
    """BM3D on each CFA plane after the transform (a one-plane mosaic such as X-Trans:
    with its colour pattern taken out first and put back after, as ``profiled`` does,
    so that BM3D does not keep the pattern as detail, and the noise with it)."""
    import bm3d
    import torch

    from rawsim.denoise.profiled import colour_modulation, forward_vst, inverse_vst

    gain, offset = model_of(raw)
    x = normalised(raw)
    offsets, step, _ = plane_layout(raw.cfa)
    out = x.copy()
    for oy, ox in offsets:
        plane = x[oy::step, ox::step]
        c = raw.cfa.color_at(int(oy), int(ox))
        v = forward_vst(torch.from_numpy(plane), gain[c], offset[c])
        pattern = 0.0 if raw.cfa.is_bayer else colour_modulation(v, raw.cfa).numpy()
        d = bm3d.bm3d(v.numpy() - pattern, 1.0) + pattern
        out[oy::step, ox::step] = inverse_vst(torch.from_numpy(d), gain[c], offset[c]).numpy()
    return as_dn(raw, out)


def bilateral(raw, clean: np.ndarray) -> tuple[np.ndarray, float]:
    import torch

    from rawsim.isp.filters import denoise

    gain, offset = model_of(raw)
    sigma = math.sqrt(gain[1] * 0.18 + offset[1])
    x = torch.from_numpy(normalised(raw)).float()[None, None]
    best = None
    for k in (1.0, 2.0, 3.0):
        y = denoise(x, raw.cfa, "bilateral", 5, 1.0, k * sigma)[0, 0].double().numpy()
        score = psnr(y, clean)
        if best is None or score > best[1]:
            best = (y, score)
    return as_dn(raw, best[0]), best[1]


def render(raw, data: np.ndarray | None = None) -> np.ndarray:
    """rawsim's render (sRGB, 16 bits) of ``raw``, or of ``data`` as its mosaic."""
    from dataclasses import replace

    from rawsim.isp.config import IspConfig
    from rawsim.pipelines.process import render_samples

    if data is not None:
        raw = replace(raw, data=data)
    samples, _ = render_samples(raw, IspConfig.default(), "png", 16)
    return samples.astype(np.float64) / 65535


def libraw_bilinear(period: tuple[int, int], shape: tuple[int, ...]) -> bool:
    """Whether LibRaw must take its bilinear demosaic for a mosaic of ``period`` and
    ``shape``: an X-Trans one smaller than its 3-pass interpolation takes (it writes
    nothing for the 256-pixel Kodak crops)."""
    return tuple(period) == (6, 6) and min(shape) < 512


def libraw_render(path: Path, threshold: float) -> np.ndarray:
    """LibRaw's render (``dcraw_emu``: camera white balance, sRGB, 16 bits, no
    auto-brightening; AHD, or bilinear where :func:`libraw_bilinear` says so), with its
    wavelet denoise at ``threshold`` (0: none). A separate process: rawpy's
    ``noise_thr`` corrupts the heap on these DNGs here."""
    import tifffile

    raw = read_raw(path)
    bilinear = libraw_bilinear(raw.cfa.period, raw.data.shape)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.tiff"
        cmd = ["dcraw_emu", "-w", "-6", "-W", "-T", "-Z", str(out), str(path)]
        if bilinear:
            cmd[1:1] = ["-q", "0"]
        if threshold:
            cmd[1:1] = ["-n", f"{threshold:g}"]
        subprocess.run(cmd, check=True, capture_output=True)
        return tifffile.imread(out).astype(np.float64) / 65535


class Darktable:
    """darktable's "denoise (profiled)" through ``darktable-cli`` (Debian's darktable),
    headless. The module's parameters (version 11: 8 floats, a[3], b[3], mode, the
    wavelet curves x[7][6], y[7][6], three flags, the colour mode; 412 bytes) start
    from darktable's own preset, read from the library darktable creates, with its
    curves set to their default 0.5, the strength 1 and the noise fit left to
    darktable (a[0] = −1: its profile for the camera and ISO, else its generic
    one). A render's XMP history holds only that module, enabled or not, so the
    reference (the clean DNG, the module off) goes through the same pipeline.
    Modes: 3 non-local means auto, 4 wavelets auto; the better is kept per image."""

    MODES = (3, 4)

    def __init__(self, work: Path) -> None:
        import sqlite3

        self.work, self.config = work, work / "config"
        self.work.mkdir(parents=True, exist_ok=True)
        self._run(HERE / "tests" / "data" / "raw" / "synthetic_colorchecker_bggr.dng", None)
        with sqlite3.connect(self.config / "data.db") as db:
            params, self.blend_version, blend = db.execute(
                "select op_params, blendop_version, blendop_params from presets "
                "where operation = 'denoiseprofile' and op_version = 11"
            ).fetchone()
        self.params, self.blend = bytearray(params), blend.hex()

    def _params(self, mode: int) -> str:
        import struct

        p = bytearray(self.params)
        floats = list(struct.unpack("<8f", p[:32]))
        floats[2] = 1.0  # strength
        p[:32] = struct.pack("<8f", *floats)
        p[32:56] = struct.pack("<6f", -1.0, 0, 0, 0, 0, 0)  # darktable's own noise fit
        p[56:60] = struct.pack("<i", mode)
        p[228:396] = struct.pack("<42f", *([0.5] * 42))  # every curve at its default
        return p.hex()

    def _xmp(self, mode: int | None) -> str:
        enabled, params = (0, self._params(3)) if mode is None else (1, self._params(mode))
        return f"""<?xml version="1.0" encoding="UTF-8"?>
<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
<rdf:Description rdf:about="" xmlns:darktable="http://darktable.sf.net/"
 darktable:xmp_version="4" darktable:history_end="1"><darktable:history><rdf:Seq>
<rdf:li darktable:num="0" darktable:operation="denoiseprofile" darktable:enabled="{enabled}"
 darktable:modversion="11" darktable:params="{params}" darktable:multi_name=""
 darktable:multi_priority="0" darktable:blendop_version="{self.blend_version}"
 darktable:blendop_params="{self.blend}"/>
</rdf:Seq></darktable:history></rdf:Description></rdf:RDF></x:xmpmeta>
"""

    def _run(self, dng: Path, mode: int | None, xmp: bool = False) -> np.ndarray | None:
        import shutil

        import tifffile

        src, out = self.work / "in.dng", self.work / "out.tif"
        shutil.copy(dng, src)
        out.unlink(missing_ok=True)
        cmd = ["darktable-cli", str(src)]
        if xmp:
            (self.work / "in.dng.xmp").write_text(self._xmp(mode))
            cmd.append(str(self.work / "in.dng.xmp"))
        cmd += [
            str(out),
            "--core",
            "--configdir",
            str(self.config),
            "--library",
            ":memory:",
            "--conf",
            "plugins/imageio/format/tiff/bpp=16",
        ]
        subprocess.run(cmd, capture_output=True, check=False)
        return tifffile.imread(out).astype(np.float64) / 65535 if out.exists() else None

    def render(self, dng: Path, mode: int | None) -> np.ndarray | None:
        """darktable's 16-bit render of ``dng`` with the module in ``mode`` (None: off),
        or None where darktable cannot export it (it fails on images under ~300 px)."""
        return self._run(dng, mode, xmp=True)


# ------------------------------------------------------------------ the table
def run(
    images: Path, profiles: list[str], isos: list[int], thresholds: list[float], dt: bool = True
) -> None:
    import shutil

    darktable = None
    if not dt:
        print("darktable left out (--no-darktable)")
    elif shutil.which("darktable-cli"):
        darktable = Darktable(Path(tempfile.mkdtemp()))
    else:
        print("darktable-cli is not installed (apt-get install darktable): its column is left out")
    try:
        import bm3d  # noqa: F401

        have_bm3d = True
    except ImportError:
        have_bm3d = False
        print("bm3d is not installed (pip install bm3d): its column is left out")
    rows = []
    for profile in profiles:
        for iso in isos:
            with tempfile.TemporaryDirectory() as tmp:
                pairs = unprocess(images, Path(tmp), profile, iso)
                scores: dict[str, list[tuple[float, float, float]]] = {}

                def add(name, raw_psnr, render_psnr, seconds, mp, scores=scores):
                    scores.setdefault(name, []).append((raw_psnr, render_psnr, seconds / mp))

                for noisy_path, clean_path in pairs:
                    noisy, clean = read_raw(noisy_path), read_raw(clean_path)
                    mp = noisy.data.size / 1e6
                    truth, truth_render = normalised(clean), render(clean)
                    add(
                        "noisy",
                        psnr(normalised(noisy), truth),
                        psnr(render(noisy), truth_render),
                        0.0,
                        mp,
                    )
                    methods = [("profiled", profiled), ("learned", learned)]
                    methods += [("bm3d", bm3d_planes)] if have_bm3d else []
                    for name, method in methods:
                        if name != "bm3d":
                            method(noisy)  # loads the kernel or the weights: not timed
                        t = time.perf_counter()
                        out = method(noisy)
                        dt = time.perf_counter() - t
                        raw_psnr = psnr(normalised_as(noisy, out), truth)
                        add(name, raw_psnr, psnr(render(noisy, out), truth_render), dt, mp)
                    t = time.perf_counter()
                    out, score = bilateral(noisy, truth)
                    dt = (time.perf_counter() - t) / 3  # one of the three sweeps
                    add("bilateral", score, psnr(render(noisy, out), truth_render), dt, mp)
                    lib_truth = libraw_render(clean_path, 0)
                    add("libraw", math.nan, psnr(libraw_render(noisy_path, 0), lib_truth), 0, mp)
                    best = (-math.inf, 0.0)
                    for thr in thresholds:
                        t = time.perf_counter()
                        score = psnr(libraw_render(noisy_path, thr), lib_truth)
                        dt = time.perf_counter() - t
                        best = max(best, (score, dt))
                    add("libraw -n", math.nan, best[0], best[1], mp)
                    dt_truth = darktable and darktable.render(clean_path, None)
                    if dt_truth is not None:
                        start = time.perf_counter()
                        plain = darktable.render(noisy_path, None)
                        base_time = time.perf_counter() - start
                        add("darktable", math.nan, psnr(plain, dt_truth), 0.0, mp)
                        best = (-math.inf, 0.0)
                        for mode in darktable.MODES:
                            t = time.perf_counter()
                            score = psnr(darktable.render(noisy_path, mode), dt_truth)
                            best = max(best, (score, time.perf_counter() - t - base_time))
                        add("darktable dn", math.nan, best[0], best[1], mp)
                for name, values in scores.items():
                    raw_p = statistics.fmean(v[0] for v in values)
                    ren_p = statistics.fmean(v[1] for v in values)
                    sec = statistics.fmean(v[2] for v in values)
                    rows.append((profile, iso, name, raw_p, ren_p, sec))
                    print(
                        f"{profile:14s} ISO {iso:6d}  {name:12s}  raw {raw_p:6.2f} dB  "
                        f"render {ren_p:6.2f} dB  {sec:7.3f} s/MP",
                        flush=True,
                    )
    # each method's render beside the same renderer's render of the noisy raw
    base = {"libraw -n": "libraw", "darktable dn": "darktable"}
    print("\nMean over profiles and ISOs: raw PSNR, render PSNR and its gain over the same")
    print("renderer's noisy render (dB), seconds per MP; then ISO ≥ 3200 alone:")
    for high in (False, True):
        chosen = [r for r in rows if r[1] >= 3200] if high else rows
        mean = {
            name: [statistics.fmean(r[k] for r in chosen if r[2] == name) for k in (3, 4, 5)]
            for name in dict.fromkeys(r[2] for r in chosen)
        }
        print("  ISO ≥ 3200:" if high else "  all ISOs:")
        for name, (raw_p, ren_p, sec) in mean.items():
            gain = ren_p - mean[base.get(name, "noisy")][1]
            print(
                f"    {name:12s}  raw {raw_p:6.2f}  render {ren_p:6.2f}  gain {gain:+5.2f}  "
                f"{sec:7.3f} s/MP"
            )


def normalised_as(raw, data: np.ndarray) -> np.ndarray:
    from dataclasses import replace

    return normalised(replace(raw, data=data))


def tune(profiles: list[str], isos: list[int]) -> None:
    """Mean raw PSNR of ``profiled`` per threshold, on the non-Kodak photos."""
    grid = (2.2, 2.5, 2.7, 3.0, 3.3)
    totals = {t: [] for t in grid}
    for profile in profiles:
        for iso in isos:
            with tempfile.TemporaryDirectory() as tmp:
                for noisy_path, clean_path in unprocess(OTHER, Path(tmp), profile, iso):
                    noisy, truth = read_raw(noisy_path), normalised(read_raw(clean_path))
                    for thr in grid:
                        totals[thr].append(psnr(normalised_as(noisy, profiled(noisy, thr)), truth))
    for thr in grid:
        print(f"threshold {thr:.1f} σ: mean raw PSNR {statistics.fmean(totals[thr]):.3f} dB")


def figures(out: Path) -> None:
    """The docs' before-and-after crops: a Kodak crop unprocessed at ISO 25600 (noisy,
    bilateral, profiled, learned, BM3D, clean) and the real raw in the tests, its
    shadows lifted 2 stops (noisy, bilateral, profiled, learned), rendered by
    rawsim's default ISP."""
    from dataclasses import replace

    from photos import save_strip

    from rawsim.denoise.learned import refine_mosaic
    from rawsim.isp.config import IspConfig
    from rawsim.pipelines.process import render_samples

    with tempfile.TemporaryDirectory() as tmp:
        noisy_path, clean_path = [
            p
            for p in unprocess(KODAK, Path(tmp), "nikon_d850", 25600)
            if p[0].stem == "kodim20_crop"
        ][0]
        noisy, clean = read_raw(noisy_path), read_raw(clean_path)
        crop = (slice(64, 192), slice(64, 192))
        panels = [
            render(noisy)[crop],
            render(noisy, bilateral(noisy, normalised(clean))[0])[crop],
            render(noisy, profiled(noisy))[crop],
            render(noisy, learned(noisy))[crop],
        ]
        try:
            panels.append(render(noisy, bm3d_planes(noisy))[crop])
        except ImportError:
            pass
        save_strip([*panels, render(clean)[crop]], out / "denoise_kodak.png")
    real = read_raw(HERE / "tests" / "data" / "raw" / "canon_eos60d_mlv.dng")
    config = IspConfig.default().override(exposure=2.0)
    gain, offset = model_of(real, estimated=True)
    black = np.asarray(real.black_level, np.float64)
    ours = denoise_mosaic(real.data, real.cfa, black, real.white_level, gain, offset)
    refined = refine_mosaic(real.data, ours, real.cfa, black, real.white_level, gain, offset)
    x = normalised(real)
    import torch

    from rawsim.isp.filters import denoise

    sigma = math.sqrt(gain[1] * 0.05 + offset[1])
    blurred = (
        denoise(torch.from_numpy(x).float()[None, None], real.cfa, "bilateral", 5, 1.0, 2 * sigma)[
            0, 0
        ]
        .double()
        .numpy()
    )
    crop = (slice(150, 310), slice(180, 420))
    panels = [
        render_samples(replace(real, data=d), config, "png", 16)[0][crop] / 65535
        for d in (real.data, as_dn(real, blurred), ours, refined)
    ]
    save_strip(panels, out / "denoise_real.png")
    print(f"wrote {out / 'denoise_kodak.png'} and {out / 'denoise_real.png'}")


def speed(profile: str = "nikon_d850", repeats: int = 3) -> None:
    """Seconds per 24 MP raw (6000 × 4000, a noisy Kodak capture of ``profile`` at ISO
    6400, tiled by whole CFA periods): ``profiled``, ``learned`` (both on the mosaic
    only), and in the same run LibRaw's whole render of that raw with and without its
    wavelet denoise (``dcraw_emu -n 200``)."""
    from dataclasses import replace

    from rawsim.io.dng import DngInfo, write_dng

    with tempfile.TemporaryDirectory() as tmp:
        noisy_path, _ = unprocess(KODAK, Path(tmp), profile, 6400)[0]
        small = read_raw(noisy_path)
        ph, pw = small.cfa.period
        h, w = small.data.shape[0] // ph * ph, small.data.shape[1] // pw * pw
        small = replace(small, data=small.data[:h, :w])
        reps = (-(-4000 // small.data.shape[0]), -(-6000 // small.data.shape[1]))
        raw = replace(small, data=np.ascontiguousarray(np.tile(small.data, reps)[:4000, :6000]))
        profiled(raw), learned(replace(raw, data=raw.data[:512, :512]))  # loads: not timed
        times = {"profiled": [], "learned": [], "libraw": [], "libraw -n 200": []}
        big = Path(tmp) / "big.dng"
        gain, offset = model_of(raw)
        info = DngInfo(
            raw.cfa,
            float(np.mean(raw.black_level)),
            raw.white_level,
            ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
            (1, 1, 1),
            "rawsim",
            "bench",
            "bench",
            6400,
            noise_profile=(gain[1], offset[1]),
        )
        write_dng(big, raw.data, info)
        for _ in range(repeats):
            for name, fn in (("profiled", profiled), ("learned", learned)):
                t = time.perf_counter()
                fn(raw)
                times[name].append(time.perf_counter() - t)
            for name, thr in (("libraw", 0), ("libraw -n 200", 200)):
                t = time.perf_counter()
                libraw_render(big, thr)
                times[name].append(time.perf_counter() - t)
    for name, values in times.items():
        print(
            f"24 MP: {name:14s} median {statistics.median(values):6.2f} s "
            f"(of {', '.join(f'{v:.2f}' for v in values)})"
        )


def libraw_dng_render(path: Path) -> np.ndarray:
    """LibRaw's render through rawpy: camera white balance, sRGB, 16 bits, no
    auto-brightening; AHD, or bilinear where :func:`libraw_bilinear` says so."""
    import rawpy

    with rawpy.imread(str(path)) as raw:
        algorithm = rawpy.DemosaicAlgorithm.AHD
        if libraw_bilinear(raw.raw_pattern.shape, raw.raw_image.shape):
            algorithm = rawpy.DemosaicAlgorithm.LINEAR
        rgb = raw.postprocess(
            demosaic_algorithm=algorithm, use_camera_wb=True, no_auto_bright=True, output_bps=16
        )
    return rgb.astype(np.float64) / 65535


def dng_out(images: Path, profiles: list[str], isos: list[int]) -> None:
    """``rawsim process --format dng --denoise METHOD`` through an editor's reader: for
    each photo unprocessed with each profile and ISO (ISOs beyond a profile's range
    are left out), LibRaw's render (rawpy, :func:`libraw_dng_render`) of the denoised
    DNG against its render of the clean DNG, beside its render of the noisy DNG
    against the same: how much closer the DNG is (target ≥ 3 dB)."""
    from rawsim.cameras.profiles import load_profile

    print("--format dng through LibRaw: render PSNR gain over the noisy DNG (dB), mean (worst)")
    for profile in profiles:
        low, high = load_profile(profile.partition(":")[0]).iso_range
        for iso in [i for i in isos if low <= i <= high]:
            with tempfile.TemporaryDirectory() as tmp:
                pairs = unprocess(images, Path(tmp) / "raw", profile, iso)
                noisy = [libraw_dng_render(n) for n, _ in pairs]
                clean = [libraw_dng_render(c) for _, c in pairs]
                before = [psnr(a, c) for a, c in zip(noisy, clean, strict=True)]
                for method in ("profiled", "learned"):
                    out = Path(tmp) / method
                    cmd = ["rawsim", "-q", "process", *(str(n) for n, _ in pairs), "-o", str(out)]
                    subprocess.run([*cmd, "--format", "dng", "--denoise", method], check=True)
                    gain = [
                        psnr(libraw_dng_render(out / n.name), c) - b
                        for (n, _), c, b in zip(pairs, clean, before, strict=True)
                    ]
                    print(
                        f"  {profile:14s} ISO {iso:6d} {method:9s} "
                        f"{statistics.mean(gain):+6.2f} ({min(gain):+6.2f}) dB over "
                        f"{statistics.mean(before):5.2f} dB noisy, {len(gain)} photos",
                        flush=True,
                    )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--images", type=Path, default=KODAK, help="folder of photos")
    ap.add_argument(
        "--profiles",
        default="nikon_d850,sony_a7s2",
        help="profile names, each NAME or NAME:NOISE (unprocess --noise, e.g. sony_imx686:physics)",
    )
    ap.add_argument("--isos", default="1600,6400,25600")
    ap.add_argument("--libraw-thresholds", default="50,100,200,400,800")
    ap.add_argument("--tune", action="store_true", help="sweep the threshold on non-Kodak photos")
    ap.add_argument("--figures", type=Path, help="write the docs' before-and-after crops here")
    ap.add_argument(
        "--speed", action="store_true", help="seconds per 24 MP raw (--profiles: the D850's)"
    )
    ap.add_argument(
        "--dng",
        action="store_true",
        help="--format dng through LibRaw (--profiles default: the D850 and the X-Trans X-T3)",
    )
    ap.add_argument(
        "--no-darktable", action="store_true", help="leave darktable out (4 renders per image)"
    )
    args = ap.parse_args(argv)
    print("\n".join(describe()), flush=True)
    profiles = args.profiles.split(",")
    given = "--profiles" in (argv if argv is not None else sys.argv)  # else the mode's own
    isos = [int(v) for v in args.isos.split(",")]
    if args.tune:
        tune(profiles, isos)
        return
    if args.figures:
        figures(args.figures)
        return
    if args.speed:
        for profile in profiles if given else ["nikon_d850"]:
            print(profile)
            speed(profile)
        return
    if args.dng:
        dng_out(args.images, profiles if given else ["nikon_d850", "fujifilm_xt3"], isos)
        return
    thresholds = [float(v) for v in args.libraw_thresholds.split(",")]
    run(args.images, profiles, isos, thresholds, not args.no_darktable)


if __name__ == "__main__":
    sys.exit(main())
