"""Regenerate the Kodak crops here from the original PNGs (kodim02.png … kodim24.png).

    python tests/data/kodak/make_crops.py DIR_WITH_KODIM_PNGS

Each crop is the centre 256 × 256 of the 768 × 512 (or 512 × 768) original,
8-bit RGB, written losslessly as PNG. The even-numbered photos were chosen
before any tuning of calibrate (the held-out set of tests/test_calibrate_heldout.py).
"""

import sys
from pathlib import Path

import OpenImageIO as oiio

SIDE = 256
PHOTOS = [f"kodim{i:02d}" for i in range(2, 25, 2)]


def main(src: Path) -> None:
    here = Path(__file__).parent
    for name in PHOTOS:
        image = oiio.ImageBuf(str(src / f"{name}.png"))
        spec = image.spec()
        x0, y0 = (spec.width - SIDE) // 2, (spec.height - SIDE) // 2
        roi = oiio.ROI(x0, x0 + SIDE, y0, y0 + SIDE, 0, 1, 0, 3)
        crop = oiio.ImageBufAlgo.cut(image, roi)
        if not crop.write(str(here / f"{name}_crop.png"), "uint8"):
            raise RuntimeError(crop.geterror())


if __name__ == "__main__":
    main(Path(sys.argv[1]))
