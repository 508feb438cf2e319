"""The ``learned`` demosaic's filters as arrays (no torch: the engine's renders start
without it): loading, their form, and the weights the engine takes.

The filters, (4, 3, 3, SIZE, SIZE) float32: site class (R, Gr, Gb, B), output
colour, input colour, rows, columns. Each class's filter for the colour its site
measured is zero; each filter's taps on each input colour sum to zero; each is
symmetric in rows and in columns (:mod:`rawsim.learned_demosaic.correction`).
"""

from __future__ import annotations

import functools
from importlib import resources

import numpy as np

from rawsim.cfa import CFA

#: The weights, in the package (``weights/``).
WEIGHTS = "bayer.safetensors"
#: The filters' side (sites) and reach (sites each side).
SIZE = 5
REACH = SIZE // 2
#: The colour each class's site measures (R, Gr, Gb, B).
OWN_COLOUR = (0, 1, 1, 2)


@functools.lru_cache(maxsize=1)
def load_filters() -> np.ndarray:
    """The shipped filters, checked (:func:`check_filters`); read on first use. Treat
    the result as read-only."""
    from safetensors.numpy import load_file

    path = resources.files("rawsim.learned_demosaic") / "weights" / WEIGHTS
    with resources.as_file(path) as file:
        filters = load_file(str(file))["filters"]
    check_filters(filters)
    return filters


def check_filters(filters: np.ndarray) -> None:
    """Raise ValueError unless ``filters`` has the documented form: the shape, zero
    on each class's own colour, taps summing to zero on each input colour, and
    symmetry in rows and in columns."""
    filters = np.asarray(filters)
    if filters.shape != (4, 3, 3, SIZE, SIZE):
        raise ValueError(f"demosaic filters: shape {filters.shape}, expected (4, 3, 3, 5, 5)")
    if np.abs(filters[np.arange(4), OWN_COLOUR]).max() > 0:
        raise ValueError("demosaic filters: a class changes the colour its site measured")
    if np.abs(filters.astype(np.float64).sum((-2, -1))).max() > 1e-5:
        raise ValueError("demosaic filters: taps on an input colour do not sum to zero")
    if not (
        np.array_equal(filters, filters[..., ::-1])
        and np.array_equal(filters, filters[..., ::-1, :])
    ):
        raise ValueError("demosaic filters: not symmetric in rows and in columns")


def site_filters(cfa: CFA, filters: np.ndarray | None = None) -> np.ndarray:
    """The weights the engine takes (``rawsim.engine.process._correct``): (2, 2, 2, 3,
    REACH + 1, REACH + 1) float32, by row and column parity of ``cfa``'s 2 × 2 tile;
    then the colour the row's other column measures and the colour the row lacks
    (the two a site lacks); input colour; |dy|, |dx| (one tap of each symmetric
    group). From ``filters`` (default :func:`load_filters`). Bayer only."""
    filters = load_filters() if filters is None else np.asarray(filters)
    colours = np.array(cfa.colors).reshape(2, 2)
    out = np.empty((2, 2, 2, 3, REACH + 1, REACH + 1), np.float32)
    for k, (r, c) in enumerate(cfa.packed_sites):
        other = colours[r, 1 - c]
        for slot, colour in enumerate((other, 3 - other - colours[r, c])):
            out[r, c, slot] = filters[k, colour, :, REACH:, REACH:]
    return out
