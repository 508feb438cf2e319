"""Regenerate the highlight crops here from the original raws.

    python tests/data/highlights/make_crops.py ORIGINAL... [--out DIR]

Each ORIGINAL is recognised by its sha256 (the names do not matter; SOURCES.md
says where each comes from). The GoPro files are given as the DNGs that
gopro/gpr's own ``gpr_tools -i X.GPR -o X.DNG`` decodes them to (LibRaw cannot
read GPR): their sha256 below is the decoded DNG's. Files not listed are refused.

Each crop is a window of the mosaic as ``rawsim.io.raw.read_raw`` gives it (LibRaw's
visible area), copied unchanged (no scaling, no clipping) into an uncompressed
16-bit DNG by :func:`rawsim.io.dng.write_dng`. Windows start on a CFA period
boundary and span whole periods, so each crop's CFA pattern is its original's.
Its DNG tags:

* CFA: the original's, as read_raw gives it;
* BlackLevel: the original's (every file here has one black level for all sites,
  which is checked); WhiteLevel: the original's nominal white level (LibRaw's
  ``white_level``), not one measured from the data;
* ColorMatrix1: the D65 XYZ → camera matrix rawsim renders the original with
  (:func:`rawsim.io.raw.xyz_to_camera_of`: LibRaw's table, the DNG's own matrix,
  or for the Kodak DC50, which has none, LibRaw's built-in camera → sRGB matrix
  measured through LibRaw and inverted);
* AsShotNeutral: 1 / the camera's white-balance gains where LibRaw would use
  them (read_raw's ``as_shot_wb``: for the Kodak DC50 and the Nikon D1 the files'
  unity gains, which LibRaw uses as they are). The Canon EOS D30's are unusable
  (−1: LibRaw balances automatically over the whole frame); a DNG cannot ask for
  that, and an automatic balance over the crop alone would differ, so the crop
  records the gains LibRaw's automatic balance chose for the whole original
  (:data:`D30_LIBRAW_AUTO_WB`);
* Make, Model, ISO: the original's (read_raw); UniqueCameraModel as listed;
  Orientation: the original's (LibRaw's ``flip``; the GoPro DNGs say 2, mirrored);
  NoiseProfile: the GoPro DNGs' own.

No EXIF beyond that (no capture time, exposure or GPS) and no opcodes: the
GoPro DNGs' OpcodeList2 (HERO6: a GainMap, lens shading) and OpcodeList3
(Fusion: WarpRectilinear, the fisheye) are left out, as LibRaw ignores them.
The output is byte-identical run to run.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The gains (R, G, B) LibRaw 0.22.2 (rawpy 0.28.0) applies to the whole
#: RAW_CANON_D30_SRGB.CRW when asked for the camera's white balance: its
#: multipliers are (−1, …), so LibRaw balances automatically. Measured as the
#: ratio, at each colour's own sites, of a linear camera-space render (bilinear,
#: LibRaw's default adjust_maximum_thr 0.75) with ``use_camera_wb`` to one with
#: unity gains; G = 1 is the mean of the two greens' gains, which LibRaw sets 2.3 %
#: apart (AsShotNeutral holds one).
D30_LIBRAW_AUTO_WB = (1.0485, 1.0, 1.6174)

#: LibRaw's flip code → TIFF orientation (dcraw's "50132467", inverted).
_FLIP_TO_ORIENTATION = {0: 1, 1: 2, 3: 3, 2: 4, 4: 5, 6: 6, 7: 7, 5: 8}


@dataclass(frozen=True)
class Crop:
    """One crop: the output name, its original (sha256, a name for messages), the
    window (top, left, height, width) in read_raw's mosaic, the CFA it must have,
    the UniqueCameraModel to write, and what it shows."""

    name: str
    original: str
    sha256: str
    window: tuple[int, int, int, int]
    cfa: str
    unique_model: str
    shows: str
    as_shot_wb: tuple[float, float, float] | None = None  # only where the camera's is unusable


CROPS = (
    Crop(
        "canon_powershot_s40_flash.dng",
        "CRW_0119.CRW (Canon PowerShot S40)",
        "ee27cc8806ded2d7a9fd2c7715cae20e4669ece5b03e8e446c534b5238d8ac34",
        (824, 872, 384, 384),
        "RGGB",
        "Canon PowerShot S40",
        "the flash's reflection on the box's glossy print: a speckled disc ~300 px across, "
        "clipped at 1023 in every colour, on a colourful unclipped print",
    ),
    Crop(
        "kodak_dc50_chart.dng",
        "DC0008L.KDC (Kodak DC50)",
        "941b1ffcb54d637f1d5bd58c4d9134154660829b085037b9e87e6cfd10f84804",
        (96, 96, 320, 320),
        "GRBG",
        "Kodak DC50",
        "overexposed colour chart: the white and light patches clip (at and just below "
        "16383) inside their black borders, next to unclipped colour patches",
    ),
    Crop(
        "gopro_hero6_sky.dng",
        "GOPR0024.GPR (GoPro HERO6 Black), decoded to DNG",
        "f73f770ce91d390d2515f62077a7586e7b4591bca93580abd849e58d61ea5232",
        (384, 1104, 384, 384),
        "RGGB",
        "GoPro HERO6 Black",
        "bright sky through a glass canopy: green and blue saturate below the white "
        "level (piles at ~15583 and ~15118 of 16383), red at ~16364 in the brightest "
        "cloud; with the canopy's frame and the wall beside it unclipped",
    ),
    Crop(
        "gopro_fusion_sun.dng",
        "GPBK7066.GPR (GoPro FUSION, back lens), decoded to DNG",
        "37eb725e06eae255bc88d5d0922b3bf59652021f55fff26bd615b994781da069",
        (720, 368, 384, 384),
        "RGGB",
        "GoPro FUSION",
        "the sun in frame (fisheye) and its glare: every colour saturates at ~15565 of "
        "16383, spread ±150 by the codec; sky, a cable and a tree around it",
    ),
    Crop(
        "canon_eos_d30_chrome.dng",
        "RAW_CANON_D30_SRGB.CRW (Canon EOS D30)",
        "6a58e2cda297b370ac2a83945cf1adee14737f854e9b68970b7965fa4fd85667",
        (272, 904, 384, 384),
        "RGGB",
        "Canon EOS D30",
        "specular streaks on a chrome lighter's hinge by a lamp: every colour saturates "
        "a little below the white level (R ~4070, G ~4078, B ~4079 of 4095), with the "
        "unclipped brushed chrome and the flint wheel around them",
        as_shot_wb=D30_LIBRAW_AUTO_WB,
    ),
    Crop(
        "nikon_d1_roofs.dng",
        "RAW_NIKON_D1.NEF (Nikon D1)",
        "7886d8b0e1257897faa7404b98fe1086ee2d95606531b6285aed83a0939b768f",
        (40, 1424, 384, 384),
        "BGGR",
        "Nikon D1",
        "sunlit roof edges and facades of a city square: red and blue clip at 4095, the "
        "greens pile up at ~3998 (97.6 % of the white level)",
    ),
    Crop(
        "canon_powershot_g2_tent.dng",
        "RAW_CANON_G2.CRW (Canon PowerShot G2)",
        "05bdd52c725dcd1aedb0f642731c7397711bdb91ed596f0bc12e1642b5ece98a",
        (624, 1160, 320, 384),
        "RGGB",
        "Canon PowerShot G2",
        "a white tent in sunlight: green and blue clip at 1023, red mostly not; people, "
        "grass and trees around it",
    ),
)


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _flip(path: Path) -> int:
    import rawpy

    with rawpy.imread(str(path)) as raw:
        return int(raw.sizes.flip)


def _noise_profile(path: Path) -> tuple[float, float] | None:
    """A DNG's NoiseProfile (S, O) for its one colour plane set, or None."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            tag = tif.pages.first.tags.get(51041)
            value = None if tag is None else tuple(tag.value)
    except Exception:  # not a TIFF-based file
        return None
    if value is None or len(value) != 2:
        return None
    return float(value[0]), float(value[1])


def make_crop(crop: Crop, path: Path, out: Path) -> Path:
    """Write ``crop`` of the original at ``path`` into ``out``; return the crop's path."""
    from rawsim.io.dng import DngInfo, write_dng
    from rawsim.io.raw import read_raw, xyz_to_camera_of

    raw = read_raw(path)
    if raw.cfa is None or raw.cfa.pattern != crop.cfa:
        raise SystemExit(f"{path}: CFA {raw.cfa} is not {crop.cfa}")
    top, left, height, width = crop.window
    ph, pw = raw.cfa.period
    if top % ph or left % pw or height % ph or width % pw:
        raise SystemExit(f"{crop.name}: window {crop.window} is not whole CFA periods")
    if top + height > raw.data.shape[0] or left + width > raw.data.shape[1]:
        raise SystemExit(f"{crop.name}: window {crop.window} outside {raw.data.shape}")
    black = np.asarray(raw.black_level, dtype=np.float64)
    if np.ptp(black) != 0:  # DngInfo holds one black level
        raise SystemExit(f"{path}: black levels differ per site ({black.tolist()})")
    matrix, _ = xyz_to_camera_of(raw)
    if matrix is None:
        raise SystemExit(f"{path}: no colour matrix")
    gains = crop.as_shot_wb or raw.as_shot_wb
    if gains is None:
        raise SystemExit(f"{path}: the camera's white balance is unusable and none is listed")
    info = DngInfo(
        cfa=raw.cfa,
        black_level=float(black.flat[0]),
        white_level=float(raw.white_level),
        xyz_to_camera=tuple(tuple(float(v) for v in row) for row in matrix),
        as_shot_neutral=tuple(1.0 / float(g) for g in gains),
        make=raw.make,
        model=raw.model,
        unique_model=crop.unique_model,
        iso=float(raw.iso),
        noise_profile=_noise_profile(path),
        baseline_exposure=float(raw.baseline_exposure),
        orientation=_FLIP_TO_ORIENTATION.get(_flip(path), 1),
        software="rawsim tests/data/highlights/make_crops.py",
    )
    mosaic = np.ascontiguousarray(raw.data[top : top + height, left : left + width])
    target = out / crop.name
    write_dng(target, mosaic.astype(np.uint16), info)
    return target


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("originals", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent)
    args = parser.parse_args(argv)
    by_hash = {c.sha256: c for c in CROPS}
    for path in args.originals:
        crop = by_hash.get(sha256(path))
        if crop is None:
            known = "\n  ".join(f"{c.sha256}  {c.original}" for c in CROPS)
            sys.exit(f"{path}: not one of the originals (by sha256):\n  {known}")
        target = make_crop(crop, path, args.out)
        print(f"{target}  {target.stat().st_size} bytes  (window {crop.window} of {crop.original})")


if __name__ == "__main__":
    main()
