"""The learned correction after ``wcd`` (torch reference; the engine's form is
:func:`rawsim.engine.process._correct`): (B, 3, H, W) → (B, 3, H, W).

At each site of a Bayer mosaic, each colour the site did not measure gets a
linear filter of the ``wcd`` values of all three colours in the 5 × 5 window
around it: 75 taps, one set for each site class (R, Gr, Gb, B) and colour. The
site's own colour is never changed (its filter is zero), and each filter's taps
on each input colour sum to zero: a flat colour passes unchanged, and the
correction is linear, so it commutes with scaling the image (exposure). Borders
are mirror-padded, as the demosaics' are (a 2-site reflection keeps the CFA
phase). No clipping; differentiable.
"""

from __future__ import annotations

import functools
from importlib import resources

import numpy as np
import torch
import torch.nn.functional as F

from rawsim.cfa import CFA

#: The weights, in the package (``weights/``).
WEIGHTS = "bayer.safetensors"
#: The filters' side (sites) and reach (sites each side).
SIZE = 5
REACH = SIZE // 2


@functools.lru_cache(maxsize=1)
def load_filters() -> torch.Tensor:
    """The shipped filters, (4, 3, 3, SIZE, SIZE) float32: site class (R, Gr, Gb, B),
    output colour, input colour, rows, columns. Read on first use."""
    from safetensors.torch import load_file

    path = resources.files("rawsim.learned_demosaic") / "weights" / WEIGHTS
    with resources.as_file(path) as file:
        filters = load_file(str(file))["filters"]
    check_filters(filters)
    return filters


def check_filters(filters: torch.Tensor) -> None:
    """Raise ValueError unless ``filters`` has the documented form: the shape, zero
    on each class's own colour, taps summing to zero on each input colour, and
    symmetry in rows and in columns."""
    if filters.shape != (4, 3, 3, SIZE, SIZE):
        raise ValueError(
            f"demosaic filters: shape {tuple(filters.shape)}, expected (4, 3, 3, 5, 5)"
        )
    own = filters[[0, 1, 2, 3], [0, 1, 1, 2]]
    if own.abs().max() > 0:
        raise ValueError("demosaic filters: a class changes the colour its site measured")
    if filters.double().sum((-2, -1)).abs().max() > 1e-5:
        raise ValueError("demosaic filters: taps on an input colour do not sum to zero")
    if not (torch.equal(filters, filters.flip(-1)) and torch.equal(filters, filters.flip(-2))):
        raise ValueError("demosaic filters: not symmetric in rows and in columns")


def site_filters(cfa: CFA, filters: torch.Tensor | None = None) -> np.ndarray:
    """The weights the engine takes (``rawsim.engine.process._correct``): (2, 2, 2, 3,
    REACH + 1, REACH + 1) float32, by row and column parity of ``cfa``'s 2 × 2 tile;
    then the colour the row's other column measures and the colour the row lacks
    (the two a site lacks); input colour; |dy|, |dx| (one tap of each symmetric
    group). From ``filters`` (default :func:`load_filters`). Bayer only."""
    filters = load_filters() if filters is None else filters
    colours = np.array(cfa.colors).reshape(2, 2)
    out = np.empty((2, 2, 2, 3, REACH + 1, REACH + 1), np.float32)
    for k, (r, c) in enumerate(cfa.packed_sites):
        other = colours[r, 1 - c]
        for slot, colour in enumerate((other, 3 - other - colours[r, c])):
            out[r, c, slot] = filters[k, colour, :, REACH:, REACH:].numpy()
    return out


def correct(rgb: torch.Tensor, cfa: CFA, filters: torch.Tensor | None = None) -> torch.Tensor:
    """``rgb`` (B, 3, H, W), a ``wcd`` demosaic of a ``cfa`` mosaic (any values: the
    demosaic's domain), plus the correction of ``filters`` (default :func:`load_filters`)."""
    filters = load_filters() if filters is None else filters
    h, w = rgb.shape[-2:]
    weight = filters.to(rgb).reshape(12, 3, SIZE, SIZE)
    padded = F.pad(rgb, (REACH,) * 4, mode="reflect")
    by_class = F.conv2d(padded, weight).unflatten(1, (4, 3))  # (B, 4, 3, H, W)
    sites = cfa.site_masks(h, w, device=rgb.device, dtype=rgb.dtype)[:, None]  # (4, 1, H, W)
    return rgb + (by_class * sites).sum(1)
