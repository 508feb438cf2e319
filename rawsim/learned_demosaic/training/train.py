"""Fit the ``learned`` demosaic's filters (:mod:`rawsim.learned_demosaic.correction`).

Each photo (8- or 16-bit RGB; grey ones are skipped) and its mirror images (left
to right, top to bottom) and transpose are mosaicked RGGB as coded, demosaicked
by ``wcd`` (:func:`rawsim.isp.demosaic.demosaic_wcd`), and ``--sites`` random
sites of each class (R, Gr, Gb, B) are drawn from each. At each site, the error
of each colour the site did not measure (the photo's value less ``wcd``'s) is
regressed on the ``wcd`` values of all three colours around it, less the
centre's, summed over each group of sites that mirroring rows or columns
exchanges (|dy|, |dx| ≤ REACH, the centre left out: 8 groups a colour for 5 × 5):
ridge least squares (``--ridge`` times the mean diagonal of the normal matrix),
one fit per class, in float64. The filters are then symmetric by construction.
Each photo's draw comes from the seed and its file name, so the result does not
depend on the folders' order.

``--check DIR`` reports the CPSNR of ``wcd`` and of the correction on other
photos (mosaicked the same way, quantised to 8 bits, all but a 10-pixel border).

Run: ``python -m rawsim.learned_demosaic.training.train --photos DIR ... --out
rawsim/learned_demosaic/weights/bayer.safetensors`` (README.md here: the photos).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from rawsim.cfa import CFA
from rawsim.io.images import even_rgb
from rawsim.isp.demosaic import demosaic_wcd
from rawsim.learned_demosaic.correction import correct
from rawsim.learned_demosaic.filters import OWN_COLOUR, REACH, SIZE, check_filters

#: The mosaic the filters are fitted on; the classes (its sites R, Gr, Gb, B: its
#: ``packed_sites``) make them hold for every Bayer layout.
PATTERN = CFA("RGGB")
#: The colours each class did not measure.
MISSING = tuple(tuple(c for c in range(3) if c != own) for own in OWN_COLOUR)
#: The groups of taps (|dy|, |dx|) that share a weight; the centre is (0, 0).
GROUPS = tuple((a, b) for a in range(REACH + 1) for b in range(REACH + 1) if (a, b) != (0, 0))
FEATURES = 3 * len(GROUPS)
EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def read_photo(path: Path) -> np.ndarray | None:
    """(H, W, 3) float32 coded values in [0, 1], cropped to even sides
    (:func:`~rawsim.io.images.even_rgb`); None if the photo is grey (a grey file's
    one channel comes back repeated)."""
    import OpenImageIO as oiio

    rgb = even_rgb(oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT))
    if max(np.abs(rgb[..., 0] - rgb[..., 1]).max(), np.abs(rgb[..., 2] - rgb[..., 1]).max()) < 0.02:
        return None
    return rgb.astype(np.float32)


def padded_flat(rgb: torch.Tensor) -> torch.Tensor:
    """(3, (H + 2·REACH)·(W + 2·REACH)): ``rgb`` (3, H, W) mirror-padded, flattened."""
    return F.pad(rgb[None], (REACH,) * 4, mode="reflect")[0].reshape(3, -1)


def features(padded: torch.Tensor, width: int, rows: torch.Tensor, cols: torch.Tensor):
    """(FEATURES, N): at sites (``rows``, ``cols``) of an image ``width`` wide
    (:func:`padded_flat`), each colour's values less the centre's, summed over
    each of :data:`GROUPS` (colour-major)."""
    stride = width + 2 * REACH
    centre = (rows + REACH) * stride + cols + REACH
    values = padded.index_select(1, centre)
    sums = []
    for a, b in GROUPS:
        members = {(sy * a, sx * b) for sy in (-1, 1) for sx in (-1, 1)}
        taken = [padded.index_select(1, centre + dy * stride + dx) for dy, dx in members]
        sums.append(sum(taken) - len(taken) * values)
    return torch.stack(sums, 1).reshape(FEATURES, -1)


def accumulate(rgb: np.ndarray, sites: int, rng: np.random.Generator, normal, rhs) -> None:
    """Add one photo's sites (each orientation) to the normal equations, per class."""
    for view in (rgb, rgb[:, ::-1], rgb[::-1], rgb.transpose(1, 0, 2)):
        truth = torch.from_numpy(np.ascontiguousarray(view)).permute(2, 0, 1)
        with torch.no_grad():
            estimate = demosaic_wcd(PATTERN.mosaic(truth[None]), PATTERN)[0]
        h, w = truth.shape[1:]
        padded = padded_flat(estimate)
        for k, (r, c) in enumerate(PATTERN.packed_sites):
            count = (h // 2) * (w // 2)
            pick = torch.from_numpy(rng.choice(count, min(sites, count), replace=False))
            rows, cols = 2 * (pick // (w // 2)) + r, 2 * (pick % (w // 2)) + c
            x = features(padded, w, rows, cols).double()
            error = (truth - estimate)[list(MISSING[k])][:, rows, cols].double()
            normal[k] += (x @ x.T).numpy()
            rhs[k] += (x @ error.T).numpy()


def solve(normal: np.ndarray, rhs: np.ndarray, ridge: float) -> np.ndarray:
    """The filters (4, 3, 3, SIZE, SIZE) float32 from the normal equations: each
    group's weight on its taps, the centre's minus their sum."""
    filters = np.zeros((4, 3, 3, SIZE, SIZE), np.float32)
    for k in range(4):
        a = normal[k] + ridge * np.trace(normal[k]) / len(normal[k]) * np.eye(len(normal[k]))
        weights = np.linalg.solve(a, rhs[k]).reshape(3, len(GROUPS), 2).astype(np.float32)
        for slot, colour in enumerate(MISSING[k]):
            for g, (a_, b_) in enumerate(GROUPS):
                for dy in {-a_, a_}:
                    for dx in {-b_, b_}:
                        filters[k, colour, :, REACH + dy, REACH + dx] = weights[:, g, slot]
            taps = filters[k, colour].astype(np.float64).sum((-2, -1))
            filters[k, colour, :, REACH, REACH] = -taps
    return filters


def photos(folders: list[Path]) -> list[Path]:
    found = (p for d in folders for p in d.rglob("*") if p.suffix.lower() in EXTENSIONS)
    return sorted(found, key=lambda p: (p.name, str(p)))


def cpsnr(estimate: torch.Tensor, truth: torch.Tensor, border: int = 10) -> float:
    """CPSNR (dB) of (3, H, W) ``estimate`` quantised to 8 bits, against ``truth``."""
    q = (estimate.clamp(0, 1) * 255).round() / 255
    e = (q - truth)[:, border:-border, border:-border].double()
    return float(10 * torch.log10(1 / e.square().mean()))


def check(folder: Path, filters: torch.Tensor) -> None:
    rows = []
    for path in photos([folder]):
        rgb = read_photo(path)
        if rgb is None:
            continue
        truth = torch.from_numpy(rgb).permute(2, 0, 1)
        with torch.no_grad():
            estimate = demosaic_wcd(PATTERN.mosaic(truth[None]), PATTERN)
            corrected = correct(estimate, PATTERN, torch.from_numpy(filters))
        rows.append((cpsnr(estimate[0], truth), cpsnr(corrected[0], truth)))
    base, learned = np.array(rows).T
    print(
        f"{folder}: {len(rows)} photos, wcd {base.mean():.2f} dB, learned {learned.mean():.2f} dB"
    )
    print(
        f"  gain {learned.mean() - base.mean():+.2f} dB, worst photo {(learned - base).min():+.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=Path, nargs="+", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--sites", type=int, default=20000, help="per class, orientation, photo")
    parser.add_argument("--ridge", type=float, default=1e-4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--check", type=Path, nargs="*", default=[])
    args = parser.parse_args()
    start = time.monotonic()
    normal, rhs = np.zeros((4, FEATURES, FEATURES)), np.zeros((4, FEATURES, 2))
    used = []
    for path in photos(args.photos):
        rgb = read_photo(path)
        if rgb is None:
            continue
        digest = hashlib.sha256(f"{args.seed}:{path.name}".encode()).digest()
        rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        accumulate(rgb, args.sites, rng, normal, rhs)
        used.append(path.name)
        if len(used) % 50 == 0:
            print(f"{len(used)} photos, {time.monotonic() - start:.0f} s", file=sys.stderr)
    filters = solve(normal, rhs, args.ridge)
    check_filters(filters)
    from safetensors.numpy import save_file

    metadata = {
        "photos": str(len(used)),
        "photos_sha256": hashlib.sha256("\n".join(used).encode()).hexdigest(),
        "sites": str(args.sites),
        "ridge": str(args.ridge),
        "seed": str(args.seed),
        "fit_seconds": f"{time.monotonic() - start:.0f}",
        "trainer": "rawsim.learned_demosaic.training.train",
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_file({"filters": filters}, str(args.out), metadata=metadata)
    print(json.dumps(metadata))
    for folder in args.check:
        check(folder, filters)


if __name__ == "__main__":
    main()
