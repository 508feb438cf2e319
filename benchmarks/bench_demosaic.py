"""Demosaic on linear raws: rawsim's methods on square roots (the default) and on linear
values, beside LibRaw's, through whole renders.

Each photo (``--images``: the Kodak set at 768 × 512, ``kodim*.png``; else the test
photos in tests/data/srgb) is unprocessed noise-free (``--noise none``, Nikon D850
profile, ISO 100): a linear 14-bit DNG, as a camera writes. It is rendered by
``rawsim process`` (sRGB, 16 bits) with each demosaic method, on square roots
(``--demosaic-domain sqrt``, the default) and on linear values, and by LibRaw
(``rawpy.postprocess``: camera white balance, sRGB with its curve, 16 bits, no
auto-brightening)
with AHD, AAHD, DHT and VNG. Each render, after the 3 × 3 linear-light matrix that
best maps it onto the photo (so that the pipelines' colour differences are left
out), is compared with the photo over the central 90 % in CPSNR (all three
channels, on the [0, 1] scale of sRGB-encoded values). What is left is what the
demosaic loses on linear data.

The square-root domain was chosen, against a 2.2 power law and a cube root, on the
photos in tests/data (``srgb``, ``srgb16``); the Kodak set was not used to choose.

Run: ``python benchmarks/bench_demosaic.py --images /tmp/kodak``
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import describe  # noqa: E402
from photos import centre, linked, rawsim  # noqa: E402

from rawsim.colorspaces import SRGB_CURVE  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PROFILE = "nikon_d850"
METHODS = ("learned", "wcd", "menon", "malvar", "bilinear")
LIBRAW = ("AHD", "AAHD", "DHT", "VNG")


def _png(path: Path) -> np.ndarray:
    """(H, W, 3) sRGB-encoded values in [0, 1] of an 8- or 16-bit PNG."""
    import OpenImageIO as oiio

    return oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)[..., :3].astype(np.float64)


def _score(render: np.ndarray, photo: np.ndarray) -> float:
    """CPSNR of ``render`` (:func:`_matched`) against ``photo``, on their common size
    (a DNG keeps whole CFA periods: an odd side loses its last row or column)."""
    h, w = min(render.shape[0], photo.shape[0]), min(render.shape[1], photo.shape[1])
    render, photo = render[:h, :w], photo[:h, :w]
    return _cpsnr(_matched(render, photo), photo)


def _matched(render: np.ndarray, photo: np.ndarray) -> np.ndarray:
    """``render`` after the 3 × 3 matrix, in linear light, that best maps it onto
    ``photo`` (least squares over the central 90 %): what differs in colour between
    the pipelines (matrices, white balance, scaling) is taken out, and what is left
    is the demosaic's structure."""
    a, b = (SRGB_CURVE.decode(centre(x)).reshape(-1, 3) for x in (render, photo))
    m, *_ = np.linalg.lstsq(a, b, rcond=None)
    return SRGB_CURVE.encode(np.clip(SRGB_CURVE.decode(render) @ m, 0, 1))


def _cpsnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1 / np.mean((centre(a) - centre(b)) ** 2)))


def _libraw(dng: Path, algorithm: str) -> np.ndarray:
    import rawpy

    with rawpy.imread(str(dng)) as raw:
        rgb = raw.postprocess(
            demosaic_algorithm=rawpy.DemosaicAlgorithm[algorithm],
            use_camera_wb=True,
            output_color=rawpy.ColorSpace.sRGB,
            gamma=(2.4, 12.92),  # sRGB's curve (rawpy's default is BT.709's)
            no_auto_bright=True,
            output_bps=16,
            user_flip=0,
        )
    return rgb.astype(np.float64) / 65535


def run(images: list[Path]) -> dict[str, list[float]]:
    rows: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        src = linked(images, work / "src")
        unprocess = ["-p", PROFILE, "--iso", 100, "--noise", "none"]
        rawsim("unprocess", src, "-o", work / "dng", *unprocess)
        for method in METHODS:
            for domain in ("sqrt", "linear"):
                out = work / f"{method}-{domain}"
                flags = ["--demosaic", method, "--demosaic-domain", domain, "--bits", 16]
                rawsim("process", work / "dng", "-o", out, *flags)
                rows[f"rawsim {method}, {domain}"] = [
                    _score(_png(out / p.with_suffix(".png").name), _png(p)) for p in images
                ]
        for algorithm in LIBRAW:
            dngs = [work / "dng" / p.with_suffix(".dng").name for p in images]
            rows[f"LibRaw {algorithm}"] = [
                _score(_libraw(dng, algorithm), _png(p))
                for dng, p in zip(dngs, images, strict=True)
            ]
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=Path, default=ROOT / "tests" / "data" / "srgb")
    args = parser.parse_args()
    images = sorted(args.images.glob("kodim*.png")) or sorted(args.images.glob("*.png"))
    for line in describe():
        print(line)
    rows = run(images)
    print(f"\n{len(images)} photos from {args.images}, unprocessed noise-free ({PROFILE}),")
    print("CPSNR of each render against the photo, central 90 % (mean, worst):")
    for name, values in rows.items():
        print(f"  {name:24s} {statistics.mean(values):6.2f} dB  {min(values):6.2f} dB")


if __name__ == "__main__":
    main()
