"""Write the small spectral test scene of ``tests/data/spectral/`` from rawsim's tables.

Run from the repository root::

    python tools/spectra/make_test_scene.py

A 64 × 48 reflectance chart of 8 × 6 patches, 8 × 8 pixels each, sampled at
400, 410, …, 700 nm (31 bands): a perfect white reflector (1 at every wavelength), a
flat 18 % grey, then 46 of rawtoaces' 190 training reflectances (rawtoaces-data
v1.1.0, ``data/training/training_spectral.json``, Apache-2.0; carried in
``rawsim/spectral/tables.json``), every fourth one from the first. Two files, the
same figures:

- ``chart.npz``: ``spectra`` (48, 64, 31) float32, ``wavelengths`` (31,) nm,
  ``kind`` "reflectance", ``illuminant`` "D65";
- ``chart.exr``: float32, ZIP, one channel per band named ``400nm``, …, ``700nm``,
  with the string attribute ``illuminant`` = "D65".
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from rawsim.spectral import tables  # noqa: E402

OUT = ROOT / "tests" / "data" / "spectral"
BANDS = np.arange(400, 701, 10, dtype=np.float64)
COLS, ROWS, SIDE = 8, 6, 8


def chart() -> np.ndarray:
    """(ROWS · SIDE, COLS · SIDE, 31) float32 reflectances (see the module's notes)."""
    on_bands = np.searchsorted(tables.WAVELENGTHS, BANDS)  # 400–700 lie on the 5 nm grid
    training = tables.training_reflectances()[on_bands]  # (31, 190)
    picked = training[:, : 4 * (COLS * ROWS - 2) : 4]
    patches = np.column_stack([np.ones(len(BANDS)), np.full(len(BANDS), 0.18), picked])
    grid = patches.T.reshape(ROWS, COLS, len(BANDS))
    return np.repeat(np.repeat(grid, SIDE, axis=0), SIDE, axis=1).astype(np.float32)


def write_exr(path: Path, spectra: np.ndarray) -> None:
    """``spectra`` as a float EXR, one channel per band (``400nm``, …)."""
    import OpenImageIO as oiio

    h, w, n = spectra.shape
    spec = oiio.ImageSpec(w, h, n, oiio.FLOAT)
    spec.channelnames = tuple(f"{nm:g}nm" for nm in BANDS)
    spec.attribute("compression", "zip")
    spec.attribute("illuminant", "D65")
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        sys.exit(f"{path}: cannot write ({oiio.geterror()})")
    out.write_image(np.ascontiguousarray(spectra))
    out.close()


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    spectra = chart()
    np.savez_compressed(
        OUT / "chart.npz",
        spectra=spectra,
        wavelengths=BANDS,
        kind=np.array("reflectance"),
        illuminant=np.array("D65"),
    )
    write_exr(OUT / "chart.exr", spectra)
    for name in ("chart.npz", "chart.exr"):
        print(f"{OUT / name}: {(OUT / name).stat().st_size / 1024:.0f} KiB")


if __name__ == "__main__":
    main()
