"""What the photo benchmarks share (bench_lens, bench_demosaic, and the docs' pictures
of bench_denoise and bench_highlights): rawsim run in a fresh interpreter, the photos
linked into a folder of their own, the central crop they are scored on, and a strip
of crops written as an image."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np


def rawsim(*args) -> None:
    """``rawsim ARGS -q`` in a fresh interpreter; raises if it fails."""
    cmd = [sys.executable, "-m", "rawsim_cli.main", *map(str, args), "-q"]
    subprocess.run(cmd, check=True)


def linked(images: list[Path], folder: Path) -> Path:
    """``folder`` made, holding a link to each of ``images``."""
    folder.mkdir()
    for p in images:
        (folder / p.name).symlink_to(p.resolve())
    return folder


def centre(a: np.ndarray, share: float = 0.9) -> np.ndarray:
    """The central ``share`` of ``a``'s height and width."""
    h, w = a.shape[:2]
    mh, mw = round(h * (1 - share) / 2), round(w * (1 - share) / 2)
    return a[mh : h - mh, mw : w - mw]


def save_strip(panels: list[np.ndarray], path: Path) -> None:
    """Write ``panels`` ((H, W, 3) display values in [0, 1], one height) side by side,
    4 white pixels apart, as an 8-bit image at ``path``."""
    import OpenImageIO as oiio

    gap = ((0, 0), (0, 4), (0, 0))
    strip = np.concatenate([np.pad(p, gap, constant_values=1.0) for p in panels], axis=1)[:, :-4]
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = oiio.ImageBuf(oiio.ImageSpec(strip.shape[1], strip.shape[0], 3, oiio.UINT8))
    buf.set_pixels(oiio.ROI(), np.clip(strip, 0, 1).astype(np.float32))
    assert buf.write(str(path)), oiio.geterror()
