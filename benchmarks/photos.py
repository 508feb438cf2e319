"""What the photo round-trip benchmarks share (bench_lens, bench_demosaic): rawsim run
in a fresh interpreter, the photos linked into a folder of their own, and the central
crop they are scored on."""

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
