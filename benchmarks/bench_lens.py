"""Lens round trip and lens-correction speed.

Quality: each photo is unprocessed through a real lens (lensfun's distortion, lateral CA
and vignetting, on the EOS 700D profile, no noise): the Canon EF-S 18-55mm STM at 18 mm,
f/3.5 (the issue's case), and the EF-S 10-18mm STM at 10 mm, f/4.5, whose corners move
most of the ultra-wide zooms lensfun has for that camera that were tried (Canon 10-18,
10-22, Sigma 10-20, Tokina 11-16: 13.9 px on 768 × 512 against the 18-55's 12.2 px);
then processed with ``--lens-correction auto``; it is
compared with the same photo unprocessed and processed without a lens (both through the
default ISP), over the central 90 %, in PSNR. What is left is what the two remaps and
the demosaic of a moved mosaic lose. The photos: the Kodak set at its native 768 × 512
(``--images``, ``kodim*.png``), else the crops vendored in tests/data/kodak. Nothing was
tuned on them.

Beside each photo, what moving it alone costs: the same comparison where the photo
is moved against the CFA by one whole pixel (right, down, and both: the three
pooled), exactly, with no lens and no resampling, then moved back (the photo
cropped by 2 px a side, so every copy is whole). The two renders then differ only
by their demosaics' errors on mosaics the move shifted against each other, as the
lens shifts its mosaic by up to 12 px; where the lens moves the image by a pixel
or more, its round trip cannot be expected above this.

Speed: one 24 MP (6000 × 4000) linear frame through the engine's remap
(:func:`rawsim.engine.lens.correct_lens`), beside the copy of the same frame (the
floor of any pass that reads and writes it); and the pre-pass that takes lateral CA
out of a 24 MP Bayer mosaic (:func:`rawsim.engine.lens.correct_mosaic_tca`) beside
the copy of the mosaic.

Run: ``python benchmarks/bench_lens.py --images /tmp/kodak``
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import describe  # noqa: E402
from photos import centre, linked, rawsim  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PROFILE = "canon_eos_700d"
#: (lens, focal length in mm, f-number): the first is also the speed test's.
LENSES = (
    ("Canon EF-S 18-55mm f/3.5-5.6 IS STM", 18.0, 3.5),
    ("Canon EF-S 10-18mm f/4.5-5.6 IS STM", 10.0, 4.5),
)


def _png(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), np.float64) / 255


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1 / np.mean((a - b) ** 2)))


#: The one-pixel moves against the CFA: (down, right) in pixels, and the crop's margin.
MOVES, MARGIN = ((0, 1), (1, 0), (1, 1)), 2


def _moved(images: list[Path], folder: Path) -> None:
    """Write into ``folder`` each photo cropped by :data:`MARGIN` a side (``NAME.png``) and
    moved by each of :data:`MOVES` (``NAME.DYDX.png``: pixel (y, x) is the crop's (y + dy,
    x + dx))."""
    folder.mkdir()
    m = MARGIN
    for p in images:
        rgb = (_png(p) * 255).round().astype(np.uint8)
        h, w = rgb.shape[:2]
        Image.fromarray(rgb[m : h - m, m : w - m]).save(folder / p.with_suffix(".png").name)
        for dy, dx in MOVES:
            moved = rgb[m + dy : h - m + dy, m + dx : w - m + dx]
            Image.fromarray(moved).save(folder / f"{p.stem}.{dy}{dx}.png")


def _moves(images: list[Path], folder: Path) -> dict[str, float]:
    """Per photo stem, the pooled PSNR of its moved renders in ``folder``, moved back,
    against its unmoved render, over the central 90 %."""
    moves = {}
    for p in images:
        still = _png(folder / p.with_suffix(".png").name)
        errors = []
        for dy, dx in MOVES:
            moved = _png(folder / f"{p.stem}.{dy}{dx}.png")
            h, w = still.shape[:2]
            back, ref = moved[: h - dy, : w - dx], still[dy:, dx:]
            errors.append(np.mean((centre(back) - centre(ref)) ** 2))
        moves[p.stem] = float(10 * np.log10(1 / np.mean(errors)))
    return moves


def quality(images: list[Path]) -> None:
    common = ["-p", PROFILE, "--iso", 100, "--noise", "none"]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        src = linked(images, work / "src")
        rawsim("unprocess", src, "-o", work / "plain", *common)
        rawsim("process", work / "plain", "-o", work / "back-plain")
        _moved(images, work / "moved")
        rawsim("unprocess", work / "moved", "-o", work / "moved-raw", *common)
        rawsim("process", work / "moved-raw", "-o", work / "back-moved")
        moves = _moves(images, work / "back-moved")
        for k, (lens, focal, aperture) in enumerate(LENSES):
            given = ["--lens", lens, "--focal-length", focal, "--aperture", aperture]
            rawsim("unprocess", src, "-o", work / f"lens{k}", *common, *given)
            rawsim(
                "process", work / f"lens{k}", "-o", work / f"back{k}", "--lens-correction", "auto"
            )
            rows = []
            for p in images:
                name = p.with_suffix(".png").name
                plain, corrected = (_png(work / d / name) for d in ("back-plain", f"back{k}"))
                rows.append((p.stem, _psnr(centre(corrected), centre(plain))))
            print(
                f"\nlens round trip ({lens} at {focal:g} mm f/{aperture:g}, {PROFILE}, no noise),"
            )
            print("PSNR against the same photo round-tripped without a lens, central 90 %,")
            print("beside the photo moved one pixel against the CFA, exactly, and back:")
            for name, db in rows:
                print(f"  {name:16s} {db:6.2f} dB   moved {moves[name]:6.2f} dB")
            values = [db for _, db in rows]
            worst = min(rows, key=lambda r: r[1])
            print(
                f"  mean {statistics.mean(values):.2f} dB, worst {worst[1]:.2f} dB ({worst[0]}), "
                f"{sum(v >= 30 for v in values)} of {len(values)} at 30 dB or more"
            )
            print(
                f"  moved one pixel: mean {statistics.mean(moves.values()):.2f} dB, worst "
                f"{min(moves.values()):.2f} dB ({min(moves, key=moves.get)}), "
                f"{sum(v >= 30 for v in moves.values())} of {len(moves)} at 30 dB or more"
            )


def speed(repeats: int) -> None:
    from rawsim.engine import process as ep
    from rawsim.engine.lens import correct_lens, correct_mosaic_tca
    from rawsim.io.lensfun import lens_params

    params, _ = lens_params(*LENSES[0], None, "Canon", "EOS 700D")
    rng = np.random.default_rng(0)
    frame = rng.random((4000, 6000, 3), dtype=np.float32)
    mosaic = rng.integers(512, 16383, (4000, 6000), dtype=np.uint16)
    colors = (0, 1, 1, 2)
    ops = np.array([ep.OP_LEVELS, ep.OP_WB, ep.OP_ROOT])
    opf = np.zeros((3, 18))
    opf[0, :4], opf[0, 4:8], opf[1, :3] = 512.0, 16383.0 - 512, (2.0, 1.0, 1.5)
    correct_lens(frame[:64, :96], params)  # compile or load the kernels
    correct_mosaic_tca(mosaic[:64, :96], colors, ops, opf, params)
    times: dict[str, list[float]] = {
        "copy (floor)": [],
        "lens correction": [],
        "mosaic copy (floor)": [],
        "mosaic lateral CA": [],
    }
    for _ in range(repeats):
        t = time.perf_counter()
        frame.copy()
        times["copy (floor)"].append(time.perf_counter() - t)
        t = time.perf_counter()
        correct_lens(frame, params)
        times["lens correction"].append(time.perf_counter() - t)
        t = time.perf_counter()
        mosaic.copy()
        times["mosaic copy (floor)"].append(time.perf_counter() - t)
        t = time.perf_counter()
        correct_mosaic_tca(mosaic, colors, ops, opf, params)
        times["mosaic lateral CA"].append(time.perf_counter() - t)
    print(
        f"\nseconds per 24 MP (6000 × 4000 × 3 float32; the mosaic 6000 × 4000 uint16, "
        f"levels, white balance, square roots), median of {repeats}:"
    )
    for name, ts in times.items():
        print(f"  {name:20s} {statistics.median(ts):6.3f} s   {[round(t, 3) for t in ts]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--images", type=Path, help="folder of kodim*.png (default: vendored)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-quality", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    args = parser.parse_args()
    for line in describe():
        print(line)
    folder = args.images or ROOT / "tests" / "data" / "kodak"
    images = sorted(folder.glob("kodim*.png"))
    if not args.skip_quality:
        quality(images)
    if not args.skip_speed:
        speed(args.repeats)


if __name__ == "__main__":
    main()
