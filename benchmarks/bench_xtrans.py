"""X-Trans demosaic quality and speed: ours (rawsim.engine.xtrans) beside LibRaw, same run.

Quality: each ground-truth image (default: the Kodak set, kodim01..24.png in
``--images``; else the vendored tests/data/srgb photos) is mirrored 2×2 (LibRaw's
X-Trans demosaics need ≥ 512 px), as coded and linearised (``--domain``: value**2.2),
mosaicked on the X-Trans layout, written as a 16-bit DNG with CFARepeatPatternDim 6×6
(which LibRaw treats exactly as an X-Trans raw) and rendered by rawpy at quality
0 (lin_interpolate), 1 (Markesteijn 1 pass) and 3 (3 passes), raw colour, linear,
no scaling. CPSNR on the 8-bit scale, 12-pixel border cropped.

Speed: a 6000×4000 mosaic, ours on ``--threads`` numba threads vs LibRaw 3-pass
(rawpy postprocess, its own threading), interleaved repeats, medians.

    python benchmarks/bench_xtrans.py --images /path/to/kodak --repeats 3

Ours runs ``icd`` as the pipeline does: on square roots for linearised images
(:func:`rawsim.isp.demosaic.to_root`), on the values as they are for display-coded ones.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import rawpy
import torch

from rawsim.cfa import CFA
from rawsim.engine import set_threads
from rawsim.engine.xtrans import demosaic_xtrans
from rawsim.io.dng import DngInfo, write_dng
from rawsim.isp.demosaic import from_root, to_root

XT = CFA("XTRANS")
INFO = DngInfo(XT, 0, 65535, ((1, 0, 0), (0, 1, 0), (0, 0, 1)), (1, 1, 1), "t", "t", "t", 100)
QUALITIES = {"libraw linear": 0, "libraw 1-pass": 1, "libraw 3-pass": 3}
SRGB = Path(__file__).resolve().parents[1] / "tests" / "data" / "srgb"


def libraw(path: Path, quality: int) -> np.ndarray:
    with rawpy.imread(str(path)) as raw:
        y = raw.postprocess(
            demosaic_algorithm=rawpy.DemosaicAlgorithm(quality),
            output_color=rawpy.ColorSpace.raw,
            gamma=(1, 1),
            no_auto_bright=True,
            user_wb=[1, 1, 1, 1],
            output_bps=16,
            user_flip=0,
            adjust_maximum_thr=0,
        )
    return y.astype(np.float32).transpose(2, 0, 1) / 65535


def mosaic(rgb: np.ndarray) -> np.ndarray:
    h, w = rgb.shape[1:]
    cmap = np.array(XT.colors).reshape(6, 6)
    cmap = np.tile(cmap, (-(-h // 6), -(-w // 6)))[:h, :w]
    return np.take_along_axis(rgb, cmap[None], 0)[0]


def cpsnr(y: np.ndarray, x: np.ndarray, border: int = 12) -> float:
    a = np.round(np.clip(y, 0, 1) * 255)[:, border:-border, border:-border].astype(np.float64)
    b = np.round(x * 255)[:, border:-border, border:-border].astype(np.float64)
    return float(10 * np.log10(255**2 / np.mean((a - b) ** 2)))


def load(path: Path, linear: bool) -> np.ndarray:
    x = oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)[:, :, :3].transpose(2, 0, 1)
    x = np.concatenate([x, x[:, :, ::-1]], 2)
    x = np.concatenate([x, x[:, ::-1]], 1)
    return np.ascontiguousarray(x**2.2 if linear else x, dtype=np.float32)


def quality(paths: list[Path], linear: bool) -> None:
    names = [*QUALITIES, "ours bilinear", "ours icd"]
    scores: dict[str, list[float]] = {n: [] for n in names}
    with tempfile.TemporaryDirectory() as tmp:
        dng = Path(tmp) / "x.dng"
        for path in paths:
            x = load(path, linear)
            m = np.round(mosaic(x) * 65535) / 65535
            write_dng(dng, np.round(m * 65535).astype(np.uint16), INFO)
            row = {n: cpsnr(libraw(dng, q), x) for n, q in QUALITIES.items()}
            m = m.astype(np.float32)
            row["ours bilinear"] = cpsnr(demosaic_xtrans(m, XT, "bilinear"), x)
            # on linear data the pipeline demosaics square roots, display-coded data as is
            if linear:
                root = to_root(torch.from_numpy(m)).numpy()
                icd = from_root(torch.from_numpy(demosaic_xtrans(root, XT, "icd"))).numpy()
            else:
                icd = demosaic_xtrans(m, XT, "icd")
            row["ours icd"] = cpsnr(icd, x)
            for n in names:
                scores[n].append(row[n])
            print(path.name, "  ".join(f"{n} {row[n]:.2f}" for n in names), flush=True)
    print(f"\nmean CPSNR over {len(paths)} images ({'linear' if linear else 'as coded'}):")
    for n in names:
        print(f"  {n:15s} {statistics.mean(scores[n]):6.2f} dB")
    gain = statistics.mean(scores["ours icd"]) - statistics.mean(scores["libraw 3-pass"])
    print(f"  ours icd − libraw 3-pass: {gain:+.2f} dB")


def speed(repeats: int, threads: int) -> None:
    set_threads(threads)
    rng = np.random.default_rng(0)
    m = rng.random((4000, 6000), dtype=np.float32) * 0.5 + 0.1
    demosaic_xtrans(m[:64, :64], XT)  # compile / load the cache
    with tempfile.TemporaryDirectory() as tmp:
        dng = Path(tmp) / "big.dng"
        write_dng(dng, np.round(m * 65535).astype(np.uint16), INFO)
        times: dict[str, list[float]] = {"ours icd": [], "ours bilinear": [], "libraw 3-pass": []}
        for _ in range(repeats):
            for name in times:
                t = time.perf_counter()
                if name == "libraw 3-pass":
                    libraw(dng, 3)
                else:
                    demosaic_xtrans(m, XT, name.split()[1])
                times[name].append(time.perf_counter() - t)
    print(f"\nseconds per 24 MP (6000×4000), median of {repeats}, ours on {threads} threads:")
    for name, ts in times.items():
        print(f"  {name:15s} {statistics.median(ts):6.2f} s   {[round(t, 2) for t in ts]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--images", type=Path, help="folder of kodim*.png (default: vendored)")
    parser.add_argument(
        "--domain",
        choices=("both", "coded", "linear"),
        default="both",
        help="the images as coded, linearised (value**2.2), or both (default)",
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--skip-quality", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    args = parser.parse_args()
    if not args.skip_quality:
        paths = sorted(args.images.glob("kodim*.png")) if args.images else sorted(SRGB.glob("*"))
        for linear in {"both": (False, True), "coded": (False,), "linear": (True,)}[args.domain]:
            quality(paths, linear)
    if not args.skip_speed:
        speed(args.repeats, args.threads)


if __name__ == "__main__":
    main()
