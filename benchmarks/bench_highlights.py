"""Highlight recovery against a known truth: rawsim's highlight modes beside LibRaw's
``-H 0/1/2/5`` and darktable's default reconstruction, measured in the same run.

Each scene-linear EXR (``--images``, one folder or more; default tests/data/exr)
is unprocessed by ``rawsim unprocess --clean --exposure EV --wb-inverse exact``
at +1, +2 and +3 EV (``--profile``, default sony_a7s2) over the exposure that
puts its brightest value (the 99.99th percentile of each pixel's largest
channel) at white, so the sensor clips as a real one does, and once at −3 EV,
or lower where the image's largest value would still clip (a lamp, the sun),
so that nothing clips: the truth (an image whose largest value lies more than 2
stops above its brightest 0.01 % is left out: its truth would need more than the
DNG's 14 bits). The tables are per folder, then for all. The noise-free
DNGs (``*.clean.dng``) are rendered scene-linear (sRGB primaries, no tone
curve) by

* rawsim (the engine, as ``rawsim process --format exr``) with each highlight
  mode, the truth with ``unclip`` (nothing is clipped there);
* LibRaw (rawpy ``postprocess``: camera white balance, sRGB, linear, 16 bits, no
  auto-brightening) with ``highlight_mode`` 0 (clip), 1 (unclip), 2 (blend) and 5
  (rebuild), the truth with 0;
* darktable (``darktable-cli``, its default pipeline with the workflow ``none``:
  no tone mapping, EXR in linear Rec. 709), whose raw default includes its
  highlight reconstruction; the truth through the same pipeline.

Each render is compared with its own pipeline's render of the truth, after one
gain that matches the two on the pixels far from any clipped site (the truth DNG
is 3 + EV stops darker, and LibRaw scales its highlight modes by the largest
white-balance gain), inside the clipped region: every pixel within 2 px of a site
at ≥ 99 % of white in the clipped DNG. Scores, per exposure, the mean over the
region's pixels of every image:

* ΔE00: CIEDE2000 of CIELAB (D65) with the truth's brightest pixel in the region
  as white (L = 100), so errors in highlights up to 8× white are measured;
* log-lum: mean |log2(Y / Y_truth)|, stops of luminance error;
* magenta %: lit pixels of the region (truth ≥ 5 % of its white: the highlights,
  not the dark side of their edges, where demosaicking next to a clip tints a few
  pixels in every mode) whose hue turned magenta (hue 290°–345°, chroma > 15,
  where the truth's is not within 30° of that hue range).

Then a real raw (``--real``, default the tests' Canon EOS 60D DNG of a cloudy
sky, whose brightest site is at 14 % of its white level): its mosaic as
recorded is the truth, and copies of it clipped as a sensor with less headroom
would clip it, their white level set 0.5, 1 and 2 stops below the brightest
green site and every site above it cut to it, are scored the same way (the
clipped DNGs are rawsim's writing of the camera's mosaic, levels, matrix and
white balance). Real noise, a real CFA and real colours; the clip is the one
thing simulated. ``--pictures DIR`` writes the docs' crops of it
(``highlights_real.png``): the truth, then clip, LibRaw -H 5, darktable and
reconstruct at 1 stop, each matched to the truth by its gain, shown in sRGB with
the truth's brightest at white (what a sensor with more headroom would show).

Then real raws with blown highlights (``--corpus``, one folder or more; default
tests/data/highlights, crops of seven cameras' raws, and the real raws of
tests/data/raw): no truth there, but where LibRaw renders white rawsim should
too. Of the pixels that LibRaw's ``dcraw_emu -w -H 0`` (camera white balance,
clip, its auto-brightening, 8 bits) renders at 0.9 or more in every channel,
each mode's 8-bit sRGB render (``rawsim process`` with ``--highlights MODE``, its
defaults otherwise) is scored by

* magenta %: green below 0.85 × the lesser of red and blue (target ≤ 0.1 %);
* ΔC*: its CIELAB chroma less that of LibRaw's render matched to it
  (``dcraw_emu -w -H 0 -W -g 2.4 12.92``: no auto-brightening, the sRGB curve),
  the mean and the 95th percentile (target: the mean within 5);

with LibRaw's ``-H 2`` and ``-H 5`` (``-W -g 2.4 12.92``) and darktable's default
(sRGB, its default tone mapping) scored for magenta in the same pixels. Every
render is as the sensor recorded it, unrotated (LibRaw does not mirror, and GoPro's
DNGs are mirrored). Each file's saturation levels (``rawsim info``'s) are printed.

The machine is printed first. Usage::

    python benchmarks/bench_highlights.py [--images DIR] [--profile NAME] [--keep DIR]
        [--real RAW] [--pictures DIR] [--corpus DIR ...] [--corpus-only]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import describe  # noqa: E402
from photos import save_strip  # noqa: E402

from rawsim.color import SRGB_TO_XYZ, XYZ_D65, delta_e_2000, xyz_to_lab  # noqa: E402

HERE = Path(__file__).resolve().parents[1]
EVS = (1, 2, 3)
TRUTH_EV = -3
#: Images whose largest value is more stops than this above their brightest 0.01 %
#: are left out: their truth, put wholly below white, would be quantised coarsely.
TRUTH_RANGE = 2.0
MODES = ("clip", "unclip", "blend", "reconstruct")
LIBRAW_MODES = (0, 1, 2, 5)
#: Rows of the table, in order.
ROWS = (*(f"rawsim {m}" for m in MODES), *(f"libraw -H {h}" for h in LIBRAW_MODES), "darktable")


# ------------------------------------------------------------------ colour
def lab(rgb: np.ndarray, white_y: float) -> np.ndarray:
    """CIELAB (N, 3) of linear sRGB (N, 3), Y = ``white_y`` being L = 100."""
    return xyz_to_lab(rgb @ SRGB_TO_XYZ.T / white_y, XYZ_D65)


def _magenta(lab_: np.ndarray, margin: float = 0.0) -> np.ndarray:
    hue = np.degrees(np.arctan2(lab_[:, 2], lab_[:, 1])) % 360
    chroma = np.hypot(lab_[:, 1], lab_[:, 2])
    return (hue >= 290 - margin) & (hue <= 345 + margin) & (chroma > 15 - margin / 2)


# ------------------------------------------------------------------ inputs
def brightest(exr: Path) -> tuple[float, float]:
    """Stops that put ``exr``'s brightest value (99.99th percentile of each pixel's
    largest channel) at 1, and stops that put its largest value at 1."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(exr))
    pixels = buf.get_pixels(oiio.FLOAT)
    if buf.has_error or pixels is None:
        sys.exit(f"{exr}: OpenImageIO cannot read it ({buf.geterror()})")
    largest = pixels[..., :3].max(-1)
    return -float(np.log2(np.percentile(largest, 99.99))), -float(np.log2(largest.max()))


def unprocess(exr: Path, out: Path, ev: float, profile: str) -> Path:
    """The noise-free DNG of ``exr`` at ``ev`` stops (its own scale)."""
    folder = out / f"ev{ev:+g}"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "rawsim_cli.main",
            "unprocess",
            str(exr),
            "-o",
            str(folder),
            "-p",
            profile,
            "--clean",
            "--exposure",
            str(ev),
            "--wb-inverse",
            "exact",
            "--iso",
            "200",  # in every bundled profile's range (noise-free DNGs: no effect)
            "-q",
        ],
        check=True,
        capture_output=True,
    )
    return folder / f"{exr.stem}.clean.dng"


def clipped_region(dng: Path) -> np.ndarray:
    """(H, W) bool: pixels within 2 px of a site at ≥ 99 % of white."""
    from scipy.ndimage import binary_dilation

    from rawsim.io.raw import read_raw

    raw = read_raw(dng)
    black = float(np.max(raw.black_level))
    sites = raw.data >= black + 0.99 * (raw.white_level - black)
    return binary_dilation(sites, iterations=2)


# ------------------------------------------------------------------ renders
def rawsim_render(dng: Path, mode: str) -> np.ndarray:
    from rawsim.io.raw import read_raw
    from rawsim.isp.config import IspConfig, ToneStage, TransferStage, YCbCrStage
    from rawsim.pipelines.process import render_float

    config = IspConfig.default().override(highlights=mode, baseline_exposure="ignore")
    config = config.with_disabled(ToneStage, TransferStage, YCbCrStage)
    out, _ = render_float(read_raw(dng), config)
    return out[0].permute(1, 2, 0).double().numpy()


def libraw_render(dng: Path, mode: int) -> np.ndarray | None:
    """LibRaw's render, or None where it fails (LibRaw 0.21 cannot demosaic some
    small X-Trans DNGs)."""
    import rawpy

    with rawpy.imread(str(dng)) as raw:
        try:
            rgb = raw.postprocess(
                highlight_mode=mode,
                output_color=rawpy.ColorSpace.sRGB,
                gamma=(1, 1),
                no_auto_bright=True,
                output_bps=16,
                use_camera_wb=True,
                user_flip=0,
            )
        except rawpy.LibRawError:
            return None
    return rgb.astype(np.float64) / 65535


class Darktable:
    """darktable's default raw pipeline, headless, without tone mapping (workflow
    ``none``), exported as linear Rec. 709 EXR. Its library is in memory and its
    configuration in a folder of its own, so nothing of the user's is read."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.work.mkdir(parents=True, exist_ok=True)

    def render(self, dng: Path) -> np.ndarray | None:
        """The render, or None where darktable cannot export (images under ~300 px)."""
        import OpenImageIO as oiio

        src, out = self.work / "in.dng", self.work / "out.exr"
        shutil.copy(dng, src)
        out.unlink(missing_ok=True)
        cmd = ["darktable-cli", str(src), str(out), "--icc-type", "LIN_REC709", "--core"]
        cmd += ["--configdir", str(self.work / "config"), "--library", ":memory:"]
        cmd += ["--conf", "plugins/darkroom/workflow=none"]
        subprocess.run(cmd, capture_output=True, check=False)
        if not out.exists():
            return None
        return oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)[..., :3].astype(np.float64)


# ------------------------------------------------------------------ scores
def score(render: np.ndarray, truth: np.ndarray, region: np.ndarray) -> dict:
    """ΔE00, log-lum error and magenta share in ``region``, after matching ``render``
    to ``truth`` by one gain on the pixels far from any clip."""
    from scipy.ndimage import binary_dilation

    y_r = render @ SRGB_TO_XYZ[1]
    y_t = truth @ SRGB_TO_XYZ[1]
    far = ~binary_dilation(region, iterations=8)
    lit = far & (y_t > 0.05 * y_t[far].max()) & (y_r > 0)
    gain = float(np.median(y_t[lit] / y_r[lit]))
    rgb_r, rgb_t = render[region] * gain, truth[region]
    white = float((rgb_t @ SRGB_TO_XYZ[1]).max())
    lab_r, lab_t = lab(rgb_r, white), lab(rgb_t, white)
    y1 = np.maximum(rgb_r @ SRGB_TO_XYZ[1], 1e-6 * white)
    y0 = np.maximum(rgb_t @ SRGB_TO_XYZ[1], 1e-6 * white)
    magenta = _magenta(lab_r) & ~_magenta(lab_t, margin=30.0) & (y0 >= 0.05 * white)
    return {
        "de": delta_e_2000(lab_r, lab_t),
        "loglum": np.abs(np.log2(y1 / y0)),
        "magenta": magenta,
        "gain": gain,
    }


def truth_renders(dng: Path, darktable: Darktable | None) -> dict:
    """The truth through each pipeline: rawsim's (unclip), LibRaw's (-H 0), darktable's."""
    return {
        "rawsim": rawsim_render(dng, "unclip"),
        "libraw": libraw_render(dng, 0),
        "darktable": darktable.render(dng) if darktable else None,
    }


def compare(dng: Path, truths: dict, region: np.ndarray, darktable: Darktable | None) -> dict:
    """Each row's render of ``dng`` scored against its pipeline's truth in ``region``
    (rows whose pipeline cannot render it are left out), with the render: {row:
    score}, each score holding its ``render``."""
    out = {}
    for mode in MODES:
        render = rawsim_render(dng, mode)
        out[f"rawsim {mode}"] = {**score(render, truths["rawsim"], region), "render": render}
    for h in LIBRAW_MODES:
        render = libraw_render(dng, h) if truths["libraw"] is not None else None
        if render is not None:
            out[f"libraw -H {h}"] = {**score(render, truths["libraw"], region), "render": render}
    if truths["darktable"] is not None:
        render = darktable.render(dng)
        if render is not None:
            out["darktable"] = {**score(render, truths["darktable"], region), "render": render}
    return out


def run(images: list[Path], profile: str, work: Path, darktable: Darktable | None) -> dict:
    print(f"profile {profile}; images: {', '.join(p.name for p in images)}")
    results: dict = {ev: {row: [] for row in ROWS} for ev in EVS}
    for exr in images:
        offset, whole = brightest(exr)  # the truth: every value below white
        if offset - whole > TRUTH_RANGE:
            print(
                f"{exr.name}: left out, its largest value is {offset - whole:.1f} stops above its "
                f"brightest 0.01 %: a truth below white would need more than the DNG's 14 bits"
            )
            continue
        truth_dng = unprocess(exr, work / exr.stem, min(TRUTH_EV + offset, whole - 0.5), profile)
        assert not clipped_region(truth_dng).any(), f"{exr.name}: the truth clips"
        truths = truth_renders(truth_dng, darktable)
        for ev in EVS:
            dng = unprocess(exr, work / exr.stem, ev + offset, profile)
            region = clipped_region(dng)
            if region.sum() < 50:
                print(f"{exr.name} +{ev} EV: {region.sum()} clipped pixels, left out")
                continue
            for row, result in compare(dng, truths, region, darktable).items():
                results[ev][row].append(result)
            share = 100 * region.mean()
            print(
                f"{exr.name} +{ev} EV: {region.sum()} pixels in the clipped region ({share:.1f} %)"
            )
    return results


#: How far below the real raw's brightest green site its copies clip (stops).
REAL_STOPS = (0.5, 1, 2)


def clipped_copies(raw_path: Path, work: Path) -> tuple[Path, dict[float, Path]]:
    """The real raw as a DNG (the truth) and its copies clipped ``REAL_STOPS`` below
    its brightest green site: {stops: DNG}."""
    from rawsim.io.dng import DngInfo, write_dng
    from rawsim.io.raw import read_raw

    raw = read_raw(raw_path)
    if raw.cfa is None or not raw.cfa.is_bayer or raw.as_shot_wb is None:
        sys.exit(f"{raw_path}: a Bayer raw with camera white balance is needed")
    black = float(np.max(raw.black_level))
    green = np.array(raw.cfa.colors).reshape(2, 2) == 1
    top = max(float(raw.data[i::2, j::2].max()) for i, j in zip(*np.nonzero(green), strict=True))
    info = DngInfo(
        cfa=raw.cfa,
        black_level=black,
        white_level=raw.white_level,
        xyz_to_camera=tuple(tuple(float(v) for v in row) for row in raw.xyz_to_camera),
        as_shot_neutral=tuple(1 / float(g) for g in raw.as_shot_wb),
        make=raw.make,
        model=raw.model,
        unique_model=raw.model,
        iso=raw.iso or 100,
    )
    work.mkdir(parents=True, exist_ok=True)
    truth = work / "truth.dng"
    write_dng(truth, raw.data.astype(np.uint16), info)
    copies = {}
    for stops in REAL_STOPS:
        white = round(black + (top - black) / 2**stops)
        copies[stops] = work / f"clipped_{stops:g}.dng"
        clipped = np.minimum(raw.data, white).astype(np.uint16)
        write_dng(copies[stops], clipped, replace(info, white_level=white))
    return truth, copies


def real(raw_path: Path, work: Path, darktable: Darktable | None, pictures: Path | None) -> dict:
    """Scores of every row on the real raw's clipped copies: {stops: {row: [score]}}."""
    truth_dng, copies = clipped_copies(raw_path, work / "real")
    truths = truth_renders(truth_dng, darktable)
    print(f"\nreal raw {raw_path.name}, clipped 0.5, 1 and 2 stops below its brightest green")
    results: dict = {}
    for stops, dng in copies.items():
        region = clipped_region(dng)
        print(f"  {stops:g} stops: {region.sum()} pixels in the clipped region")
        scored = compare(dng, truths, region, darktable)
        results[stops] = {row: [scored[row]] if row in scored else [] for row in ROWS}
        if pictures is not None and stops == 1:
            crops(scored, truths, region, pictures / "highlights_real.png")
    return results


def crops(scored: dict, truths: dict, region: np.ndarray, path: Path) -> None:
    """The docs' strip: the truth, then clip, LibRaw -H 5, darktable and reconstruct,
    cropped around the clipped region's densest window, each times its gain, with
    the truth's brightest (99.9th percentile of luminance) at white, sRGB-encoded."""
    from scipy.ndimage import uniform_filter

    from rawsim.colorspaces import SRGB_CURVE

    h, w = region.shape
    ch, cw = min(h, 240), min(w, 320)
    density = uniform_filter(region.astype(np.float64), size=(ch, cw), mode="constant")
    cy, cx = np.unravel_index(np.argmax(density), density.shape)
    y0, x0 = min(max(cy - ch // 2, 0), h - ch), min(max(cx - cw // 2, 0), w - cw)
    window = (slice(y0, y0 + ch), slice(x0, x0 + cw))

    bright = float(np.percentile(truths["rawsim"][window] @ SRGB_TO_XYZ[1], 99.9))

    def shown(rgb: np.ndarray) -> np.ndarray:
        return SRGB_CURVE.encode(np.clip(rgb[window] / bright, 0, 1))

    panels = [shown(truths["rawsim"])]
    for row in ("rawsim clip", "libraw -H 5", "darktable", "rawsim reconstruct"):
        if row in scored:
            panels.append(shown(scored[row]["render"] * scored[row]["gain"]))
    save_strip(panels, path)
    print(f"  wrote {path} (window rows {y0}–{y0 + ch}, columns {x0}–{x0 + cw})")


# ------------------------------------------------------------------ real raws
#: The corpus's magenta test and its bound (the issue's): green below this share of the
#: lesser of red and blue.
MAGENTA_GREEN = 0.85
RAW_SUFFIXES = {".dng", ".crw", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2", ".pef"}
RAW_SUFFIXES |= {".kdc", ".qtk", ".srw", ".x3f", ".3fr", ".iiq", ".mrw", ".dcr"}


def srgb_chroma(rgb: np.ndarray) -> np.ndarray:
    """CIELAB chroma (D65) of sRGB-encoded values in [0, 1], (..., 3) → (...)."""
    linear = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    out = lab(linear.reshape(-1, 3), 1.0)
    return np.hypot(out[:, 1], out[:, 2]).reshape(rgb.shape[:-1])


def dcraw_emu(raw: Path, work: Path, *flags: str) -> np.ndarray:
    """LibRaw's 8-bit render (``dcraw_emu -w FLAGS -T``) as floats in [0, 1]."""
    import tifffile

    out = work / f"{raw.name}.{'_'.join(f.strip('-') for f in flags)}.tiff"
    cmd = ["dcraw_emu", "-w", "-t", "0", *flags, "-T", "-Z", str(out), str(raw)]
    subprocess.run(cmd, check=True, capture_output=True)
    return tifffile.imread(out).astype(np.float64) / 255


def rawsim_png(raw: Path, work: Path, mode: str) -> np.ndarray:
    """rawsim's default 8-bit sRGB render with ``--highlights mode`` in [0, 1], as the
    sensor recorded it (no orientation: LibRaw does not mirror, GoPro's DNGs are)."""
    from rawsim.io.raw import read_raw
    from rawsim.isp.config import IspConfig, OrientationStage
    from rawsim.pipelines.process import render_samples

    config = IspConfig.default().override(highlights=mode).with_disabled(OrientationStage)
    samples, _ = render_samples(read_raw(raw), config, "png", 8)
    return samples.astype(np.float64) / 255


def darktable_png(raw: Path, work: Path) -> np.ndarray | None:
    """darktable's default render (sRGB PNG), or None where it cannot export."""
    import OpenImageIO as oiio

    src, out = work / f"dt{raw.suffix}", work / "dt.png"  # (oriented: compared where it fits)
    shutil.copy(raw, src)
    out.unlink(missing_ok=True)
    cmd = ["darktable-cli", str(src), str(out), "--core", "--configdir", str(work / "dtconf")]
    subprocess.run([*cmd, "--library", ":memory:"], capture_output=True, check=False)
    if not out.exists():
        return None
    return oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)[..., :3].astype(float)


def magenta(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., 1] < MAGENTA_GREEN * np.minimum(rgb[..., 0], rgb[..., 2])


def corpus(folders: list[Path], work: Path) -> None:
    """The real raws' table (module docstring)."""
    from rawsim.io.raw import read_raw
    from rawsim.isp.config import IspConfig, resolve

    files = sorted(
        p for f in folders for p in Path(f).iterdir() if p.suffix.lower() in RAW_SUFFIXES
    )
    print(f"\nreal raws: {len(files)} files; where dcraw_emu -w -H 0 renders ≥ 0.9 everywhere")
    head = "  ".join(f"{m:>20s}" for m in MODES)
    print(f"{'file':34s} {'pixels':>7s}  {head}  {'LibRaw -H 2/-H 5, darktable':>28s}")
    worst = {m: (0.0, 0.0) for m in MODES}
    for raw in files:
        work.mkdir(parents=True, exist_ok=True)
        white = (dcraw_emu(raw, work, "-H", "0") >= 0.9).all(-1)
        matched = dcraw_emu(raw, work, "-H", "0", "-W", "-g", "2.4", "12.92")
        cells = []
        for mode in MODES:
            ours = rawsim_png(raw, work, mode)
            h, w = min(ours.shape[0], white.shape[0]), min(ours.shape[1], white.shape[1])
            region = white[:h, :w]
            n = max(int(region.sum()), 1)
            share = 100 * (magenta(ours[:h, :w]) & region).sum() / n
            dc = (srgb_chroma(ours[:h, :w]) - srgb_chroma(matched[:h, :w]))[region]
            mean, p95 = (float(dc.mean()), float(np.percentile(dc, 95))) if dc.size else (0, 0)
            cells.append(f"{share:5.2f}% {mean:+5.2f}/{p95:5.1f}")
            worst[mode] = (max(worst[mode][0], share), max(worst[mode][1], mean))
        anchors = []
        for render in (
            dcraw_emu(raw, work, "-H", "2", "-W", "-g", "2.4", "12.92"),
            dcraw_emu(raw, work, "-H", "5", "-W", "-g", "2.4", "12.92"),
            darktable_png(raw, work),
        ):
            if render is None or render.shape[:2] != white.shape:
                anchors.append("   —")
                continue
            anchors.append(f"{100 * (magenta(render) & white).sum() / max(white.sum(), 1):5.2f}%")
        print(f"{raw.name[:34]:34s} {int(white.sum()):7d}  {'  '.join(cells)}  {' '.join(anchors)}")
        levels = resolve(IspConfig.default(), read_raw(raw)).info["saturation"]
        if levels:
            found = [f"{c} {v:g}" for c, v in zip("RGB", levels["levels"], strict=True)]
            print(f"{'':34s} saturation: {', '.join(found)}")
    print("worst file: " + ", ".join(f"{m} {s:.2f}% ΔC* {d:+.2f}" for m, (s, d) in worst.items()))


def table(results: dict, unit: str = "EV") -> None:
    for ev, rows in results.items():
        where = f"+{ev} EV" if unit == "EV" else f"{ev:g} stops below the brightest green"
        print(f"\n{where} (clipped regions of every image; mean over their pixels)")
        print(
            f"{'':18s} {'ΔE00':>7s} {'log-lum':>8s} {'magenta %':>10s} {'(px)':>6s}  per image ΔE00"
        )
        for row, scores in rows.items():
            if not scores:
                print(f"{row:18s} {'—':>7s}")
                continue
            de = np.concatenate([s["de"] for s in scores])
            ll = np.concatenate([s["loglum"] for s in scores])
            mg = np.concatenate([s["magenta"] for s in scores])
            each = " ".join(f"{s['de'].mean():6.2f}" for s in scores)
            share = f"{100 * mg.mean():10.2f} {mg.sum():6d}"
            print(f"{row:18s} {de.mean():7.2f} {ll.mean():8.3f} {share}  {each}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=Path, nargs="+", default=[HERE / "tests" / "data" / "exr"])
    parser.add_argument("--profile", default="sony_a7s2")
    parser.add_argument("--keep", type=Path, help="keep the DNGs and renders here")
    parser.add_argument(
        "--real", type=Path, default=HERE / "tests" / "data" / "raw" / "canon_eos60d_mlv.dng"
    )
    parser.add_argument("--pictures", type=Path, help="write the docs' crops of the real raw here")
    parser.add_argument(
        "--corpus",
        type=Path,
        nargs="+",
        default=[HERE / "tests" / "data" / "highlights", HERE / "tests" / "data" / "raw"],
        help="folders of real raws with blown highlights",
    )
    parser.add_argument("--corpus-only", action="store_true", help="only the real raws' table")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_highlights_"))
    if args.corpus_only:
        for line in describe():
            print(line)
        corpus(args.corpus, work / "corpus")
        return
    sets = {folder: sorted(folder.glob("*.exr")) for folder in args.images}
    for folder, images in sets.items():
        if not images:
            sys.exit(f"no EXR images in {folder}")
    darktable = Darktable(work / "darktable") if shutil.which("darktable-cli") else None
    if darktable is None:
        print("darktable-cli is not installed: its row is left out")
    for line in describe():
        print(line)
    merged: dict = {ev: {row: [] for row in ROWS} for ev in EVS}
    for folder, images in sets.items():
        results = run(images, args.profile, work, darktable)
        print(f"\n== {folder}")
        table(results)
        for ev, rows in results.items():
            for row, scores in rows.items():
                merged[ev][row] += scores
    if len(sets) > 1:
        print("\n== every folder")
        table(merged)
    table(real(args.real, work, darktable, args.pictures), unit="stops")
    corpus(args.corpus, work / "corpus")


if __name__ == "__main__":
    main()
