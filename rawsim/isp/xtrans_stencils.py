"""The X-Trans demosaics' stencils, constants and extents: one definition read by
the torch reference (:mod:`rawsim.isp.xtrans`) and the compiled kernels
(:mod:`rawsim.engine.xtrans`). Neither torch nor numba here."""

from __future__ import annotations

import numpy as np

from rawsim.cfa import CFA
from rawsim.errors import check_choice

XTRANS_DEMOSAIC_METHODS = ("icd", "bilinear")
#: Rounds of the ``icd`` refinement by default.
ICD_ITERATIONS = 3
#: Added to every gradient before the inverse square (float32 in both backends).
GRAD_EPS = 1e-4
#: The 3×3 neighbours in the order both backends sum them, and their weights.
NEIGHBOURS_3 = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))
EDGE_WEIGHTS_3 = tuple(2.0 if dy == 0 or dx == 0 else 1.0 for dy, dx in NEIGHBOURS_3)
#: The 5×5 neighbours (row-major) and 1 / distance².
NEIGHBOURS_5 = tuple((dy, dx) for dy in range(-2, 3) for dx in range(-2, 3) if (dy, dx) != (0, 0))
INV_DIST_5 = tuple(1.0 / (dy * dy + dx * dx) for dy, dx in NEIGHBOURS_5)


#: The 3×3 window of the ``icd`` median refinement: the site, then its 8 neighbours.
WINDOW_3 = ((0, 0), *NEIGHBOURS_3)


def reach(method: str, iterations: int = ICD_ITERATIONS) -> int:
    """Pixels of context each output pixel depends on: the bilinear start (1), each
    ``icd`` round (3), and its final median refinement (1)."""
    check_choice("X-Trans demosaic method", method, XTRANS_DEMOSAIC_METHODS)
    return 1 if method == "bilinear" else 2 + 3 * iterations


def padding(cfa: CFA, method: str, iterations: int = ICD_ITERATIONS) -> int:
    """Extension on each side: the reach, rounded up to whole periods of the CFA."""
    step = int(np.lcm(*cfa.period))
    return -(-reach(method, iterations) // step) * step


def min_size(cfa: CFA, method: str, iterations: int = ICD_ITERATIONS) -> int:
    """The fewest rows and columns a mosaic may have for ``method``."""
    return padding(cfa, method, iterations) + max(cfa.period)
