"""Demosaicking: a Bayer mosaic (B, 1, H, W) → RGB (B, 3, H, W), for every CFA pattern.

Methods (``DEMOSAIC_METHODS``):

* ``bilinear``: each missing value is the mean of its nearest same-colour
  neighbours (3×3 kernels on the sparse colour planes).
* ``malvar``: Malvar, He and Cutler (ICASSP 2004), gradient-corrected linear
  5×5 filters.
* ``menon``: Menon, Andriani and Calvagno, "Demosaicing with directional
  filtering and a posteriori decision" (IEEE TIP 2007): horizontal and vertical
  green estimates, a decision from colour-difference gradients, directional
  red/blue interpolation and the paper's refining step.
* ``wcd`` (default): weighted colour-difference interpolation after the
  gradient-based threshold-free method of Pekkucuksen and Altunbasak (ICASSP
  2010): Hamilton–Adams colour differences along rows and columns, averaged one
  side at a time towards north, south, east and west and blended with weights
  1/(gradient sum)²; red and blue then follow the green through colour
  differences, weighted the same way (diagonally for red at blue sites).
* ``learned``: ``wcd``, then a learned linear correction of the colours each site
  did not measure, from the 5 × 5 ``wcd`` values around it
  (:mod:`rawsim.learned_demosaic`: its weights, how they were fitted and on what).
  Not the default: on held-out modern photos it gains 0.5 dB over ``wcd`` on
  average but loses up to 1.3 dB on saturated colour edges, for about 1.8× the
  render's time (docs/guide/process.md, "Demosaic").

All are linear or piecewise linear in the input, differentiable, and keep the
input's values at its own CFA sites (before Menon's refining step); all but Menon's
decision are linear in the input's scale (the learned correction is linear). Borders are
handled by mirror padding, which keeps the CFA phase. No clipping.

The stage interpolates square roots by default (:class:`RootDomain`, the config's
``domain = "sqrt"``): :func:`to_root` before any method, :func:`from_root` after,
so that errors fall where a display's gamma hides them; ``linear`` interpolates
the linear values as they are.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import check_choice, check_image
from rawsim.isp.config import DEMOSAIC_METHODS, DEMOSAIC_ROOT_EPS
from rawsim.isp.planes import correlate
from rawsim.learned_demosaic.correction import correct
from rawsim.learned_demosaic.filters import REACH


def _box(x: torch.Tensor, size: int) -> torch.Tensor:
    """Sum over a ``size`` × ``size`` window (separable: two 1-D passes)."""
    ones = torch.ones(size)
    return _v(_h(x, ones), ones)


def _h(x: torch.Tensor, kernel) -> torch.Tensor:
    return correlate(x, torch.as_tensor(kernel)[None])


def _v(x: torch.Tensor, kernel) -> torch.Tensor:
    return correlate(x, torch.as_tensor(kernel)[:, None])


def _sites(cfa: CFA, x: torch.Tensor) -> torch.Tensor:
    """R, Gr, Gb, B site masks (4, 1, H, W) broadcastable over a batch."""
    return cfa.site_masks(*x.shape[-2:], device=x.device, dtype=x.dtype)[:, None]


def demosaic_bilinear(mosaic: torch.Tensor, cfa: CFA) -> torch.Tensor:
    """Bilinear demosaic: (B, 1, H, W) → (B, 3, H, W)."""
    check_image(mosaic, "mosaic", channels=1)
    r, gr, gb, b = _sites(cfa, mosaic)
    cross = [[0.0, 0.25, 0.0], [0.25, 1.0, 0.25], [0.0, 0.25, 0.0]]
    box = [[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]]
    red = correlate(mosaic * r, box)
    green = correlate(mosaic * (gr + gb), cross)
    blue = correlate(mosaic * b, box)
    return torch.cat([red, green, blue], dim=1)


# Malvar–He–Cutler 2004 filters (×1/8): green at R/B sites; R (or B) at a green
# site whose row holds R (B); the same for its column; R at B sites (and B at R).
_MHC_G = [[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]]
_MHC_ROW = [
    [0, 0, 0.5, 0, 0],
    [0, -1, 0, -1, 0],
    [-1, 4, 5, 4, -1],
    [0, -1, 0, -1, 0],
    [0, 0, 0.5, 0, 0],
]
_MHC_COL = [list(r) for r in zip(*_MHC_ROW, strict=True)]
_MHC_DIAG = [
    [0, 0, -1.5, 0, 0],
    [0, 2, 0, 2, 0],
    [-1.5, 0, 6, 0, -1.5],
    [0, 2, 0, 2, 0],
    [0, 0, -1.5, 0, 0],
]


def demosaic_malvar(mosaic: torch.Tensor, cfa: CFA) -> torch.Tensor:
    """Malvar–He–Cutler demosaic: (B, 1, H, W) → (B, 3, H, W)."""
    check_image(mosaic, "mosaic", channels=1)
    r, gr, gb, b = _sites(cfa, mosaic)
    g_at_rb = correlate(mosaic, torch.tensor(_MHC_G) / 8)
    along_row = correlate(mosaic, torch.tensor(_MHC_ROW) / 8)
    along_col = correlate(mosaic, torch.tensor(_MHC_COL) / 8)
    diagonal = correlate(mosaic, torch.tensor(_MHC_DIAG) / 8)
    # Gr sits on a red row (red left/right, blue above/below); Gb the other way round.
    red = mosaic * r + along_row * gr + along_col * gb + diagonal * b
    green = mosaic * (gr + gb) + g_at_rb * (r + b)
    blue = mosaic * b + along_row * gb + along_col * gr + diagonal * r
    return torch.cat([red, green, blue], dim=1)


_H0 = [0.0, 0.5, 0.0, 0.5, 0.0]
_H1 = [-0.25, 0.0, 0.5, 0.0, -0.25]
_PAIR = [0.5, 0.0, 0.5]
_MEAN3 = [1 / 3, 1 / 3, 1 / 3]
# Menon's classifier: sums the gradient of the current and the next-but-one
# column (row), weighting the centre line.
_CLASSIFIER = [[0, 0, 1, 0, 1], [0, 0, 0, 1, 0], [0, 0, 3, 0, 3], [0, 0, 0, 1, 0], [0, 0, 1, 0, 1]]


def demosaic_menon(mosaic: torch.Tensor, cfa: CFA, refine: bool = True) -> torch.Tensor:
    """Menon et al. 2007 (DDFAPD) demosaic: (B, 1, H, W) → (B, 3, H, W)."""
    check_image(mosaic, "mosaic", channels=1)
    r, gr, gb, b = _sites(cfa, mosaic)
    g_sites = gr + gb
    rb_sites = r + b
    # 1. Directional green estimates at R/B sites.
    g_h = mosaic * g_sites + (_h(mosaic, _H0) + _h(mosaic, _H1)) * rb_sites
    g_v = mosaic * g_sites + (_v(mosaic, _H0) + _v(mosaic, _H1)) * rb_sites
    # 2. Decision: colour differences vary less along the true edge direction.
    c_h = (mosaic - g_h) * rb_sites
    c_v = (mosaic - g_v) * rb_sites
    d_h = (c_h - F.pad(c_h, (0, 2, 0, 0), mode="reflect")[..., :, 2:]).abs()
    d_v = (c_v - F.pad(c_v, (0, 0, 0, 2), mode="reflect")[..., 2:, :]).abs()
    d_h = correlate(d_h, _CLASSIFIER)
    d_v = correlate(d_v, [list(row) for row in zip(*_CLASSIFIER, strict=True)])
    horizontal = (d_v >= d_h).to(mosaic.dtype)
    green = g_h * horizontal + g_v * (1 - horizontal)
    # 3. Red and blue at green sites, from the colour difference along the row or column.
    red, blue = mosaic * r, mosaic * b
    red_h = green + _h(red, _PAIR) - _h(green * r, _PAIR)
    red_v = green + _v(red, _PAIR) - _v(green * r, _PAIR)
    blue_h = green + _h(blue, _PAIR) - _h(green * b, _PAIR)
    blue_v = green + _v(blue, _PAIR) - _v(green * b, _PAIR)
    red = red + red_h * gr + red_v * gb
    blue = blue + blue_h * gb + blue_v * gr
    # 4. Red at blue sites and blue at red sites, along the decided direction.
    red_at_b = _directional(
        blue + _h(red, _PAIR) - _h(blue, _PAIR), blue + _v(red, _PAIR) - _v(blue, _PAIR), horizontal
    )
    blue_at_r = _directional(
        red + _h(blue, _PAIR) - _h(red, _PAIR), red + _v(blue, _PAIR) - _v(red, _PAIR), horizontal
    )
    red = red + red_at_b * b
    blue = blue + blue_at_r * r
    if refine:
        red, green, blue = _menon_refine(red, green, blue, (r, gr, gb, b), horizontal)
    return torch.cat([red, green, blue], dim=1)


def _directional(along_h: torch.Tensor, along_v: torch.Tensor, horizontal: torch.Tensor):
    return along_h * horizontal + along_v * (1 - horizontal)


def _menon_refine(red, green, blue, sites, horizontal):
    """Menon et al.'s refining step: smooth the colour differences along the decision."""
    r, gr, gb, b = sites

    def smoothed(diff, kernel):
        return _directional(_h(diff, kernel), _v(diff, kernel), horizontal)

    # Green at R and B sites from the smoothed R−G and B−G differences.
    green = (
        green * (gr + gb)
        + (red - smoothed(red - green, _MEAN3)) * r
        + (blue - smoothed(blue - green, _MEAN3)) * b
    )
    # Red and blue at green sites from the differences of their same-colour neighbours.
    red_g, blue_g = red - green, blue - green
    red = red * (r + b) + (green + _h(red_g, _PAIR)) * gr + (green + _v(red_g, _PAIR)) * gb
    blue = blue * (r + b) + (green + _h(blue_g, _PAIR)) * gb + (green + _v(blue_g, _PAIR)) * gr
    # Red at blue sites and blue at red sites from the smoothed R−B difference.
    red_blue = smoothed(red - blue, _MEAN3)
    red = red * (1 - b) + (blue + red_blue) * b
    blue = blue * (1 - r) + (red - red_blue) * r
    return red, green, blue


def _shifted(x: torch.Tensor, pad: int):
    """Mirror-pad once; return ``at(dy, dx)``, the view whose (i, j) is x(i + dy, j + dx)."""
    h, w = x.shape[-2:]
    padded = F.pad(x, (pad, pad, pad, pad), mode="reflect")

    def at(dy: int, dx: int) -> torch.Tensor:
        return padded[..., pad + dy : pad + dy + h, pad + dx : pad + dx + w]

    return at


_EPS = 1e-10
_DIRECTIONS = ((0, 1), (0, -1), (1, 0), (-1, 0))  # east, west, south, north (dy, dx)
_DIAGONALS = ((-1, -1), (-1, 1), (1, -1), (1, 1))


def demosaic_wcd(mosaic: torch.Tensor, cfa: CFA) -> torch.Tensor:
    """Weighted colour-difference demosaic (see the module doc): (B, 1, H, W) → (B, 3, H, W)."""
    check_image(mosaic, "mosaic", channels=1)
    r, gr, gb, b = _sites(cfa, mosaic)
    g_sites, rb_sites = gr + gb, r + b
    # Colour differences G − C along rows (h) and columns (v), Hamilton–Adams estimates.
    sign = g_sites - rb_sites
    diff = {
        "h": sign * (mosaic - _h(mosaic, _H0) - _h(mosaic, _H1)),
        "v": sign * (mosaic - _v(mosaic, _H0) - _v(mosaic, _H1)),
    }
    at = {k: _shifted(d, 1) for k, d in diff.items()}
    grad = {
        "h": (at["h"](0, -1) - at["h"](0, 1)).abs(),
        "v": (at["v"](-1, 0) - at["v"](1, 0)).abs(),
    }
    sums = {k: _shifted(_box(g, 5), 2) for k, g in grad.items()}
    ones = torch.tensor([1 / 3, 1 / 3, 1 / 3, 0.0, 0.0])
    weights, estimates = [], []
    for dy, dx in _DIRECTIONS:
        axis = "h" if dy == 0 else "v"
        step = dx or dy
        weights.append((sums[axis](2 * dy, 2 * dx) + _EPS) ** -2)
        # One-sided mean of the centre and the next two samples towards the direction.
        kernel = ones.flip(0) if step > 0 else ones
        estimates.append(_h(diff["h"], kernel) if axis == "h" else _v(diff["v"], kernel))
    total = weights[0] + weights[1] + weights[2] + weights[3]
    delta = sum(w * e for w, e in zip(weights, estimates, strict=True)) / total
    green = mosaic * g_sites + (mosaic + delta) * rb_sites
    # Red at blue sites (and blue at red sites): diagonal colour differences.
    diagonal = _diagonal_weights(mosaic, green)
    red = mosaic * r + (green - _diagonal_mean((green - mosaic) * r, diagonal)) * b
    blue = mosaic * b + (green - _diagonal_mean((green - mosaic) * b, diagonal)) * r
    # Red and blue at green sites: the four neighbours' differences, weighted as green.
    red = red + (green - _weighted_cross((green - red) * rb_sites, weights, total)) * g_sites
    blue = blue + (green - _weighted_cross((green - blue) * rb_sites, weights, total)) * g_sites
    return torch.cat([red, green, blue], dim=1)


def _weighted_cross(diff: torch.Tensor, weights, total) -> torch.Tensor:
    at = _shifted(diff, 1)
    return sum(w * at(dy, dx) for w, (dy, dx) in zip(weights, _DIRECTIONS, strict=True)) / total


def _diagonal_weights(mosaic: torch.Tensor, green: torch.Tensor):
    """Weights of the four diagonal neighbours: 1 / (local diagonal gradient)², and their sum."""
    m, g = _shifted(mosaic, 2), _shifted(green, 1)
    weights = []
    for dy, dx in _DIAGONALS:
        gradient = (m(dy, dx) - m(-dy, -dx)).abs() + (g(dy, dx) - g(0, 0)).abs()
        gradient = gradient + (m(2 * dy, 2 * dx) - m(0, 0)).abs()
        weights.append((gradient + _EPS) ** -2)
    return weights, weights[0] + weights[1] + weights[2] + weights[3]


def _diagonal_mean(diff: torch.Tensor, diagonal) -> torch.Tensor:
    """Mean of ``diff`` (zero off its sites) over the diagonal neighbours, weighted."""
    weights, total = diagonal
    d = _shifted(diff, 1)
    return sum(w * d(dy, dx) for w, (dy, dx) in zip(weights, _DIAGONALS, strict=True)) / total


def demosaic_learned(mosaic: torch.Tensor, cfa: CFA) -> torch.Tensor:
    """``wcd`` then the learned correction (see the module doc): (B, 1, H, W) → (B, 3, H, W)."""
    return correct(demosaic_wcd(mosaic, cfa), cfa)


def demosaic(mosaic: torch.Tensor, cfa: CFA, method: str = "learned") -> torch.Tensor:
    """Demosaic (B, 1, H, W) with ``method`` (see ``DEMOSAIC_METHODS``)."""
    check_choice("demosaic method", method, DEMOSAIC_METHODS)
    if method == "bilinear":
        return demosaic_bilinear(mosaic, cfa)
    if method == "malvar":
        return demosaic_malvar(mosaic, cfa)
    if method == "menon":
        return demosaic_menon(mosaic, cfa)
    if method == "wcd":
        return demosaic_wcd(mosaic, cfa)
    return demosaic_learned(mosaic, cfa)


#: float32 constants of the root domain, shared with the engine (its OP_ROOT/OP_SQUARE).
ROOT_EPS = np.float32(DEMOSAIC_ROOT_EPS)
ROOT_SQRT_EPS = np.sqrt(ROOT_EPS)


def to_root(x: torch.Tensor) -> torch.Tensor:
    """The odd root sign(x)·(√(|x| + ε) − √ε) of linear values (any shape, any range):
    the domain the demosaic interpolates in; :func:`from_root` inverts it. Computed as
    x / (√(|x| + ε) + √ε): no cancellation near 0, and the gradient there is 1/(2√ε)."""
    eps, sqrt_eps = (torch.tensor(float(v), dtype=x.dtype) for v in (ROOT_EPS, ROOT_SQRT_EPS))
    # The root in float64, rounded once: correctly rounded, as the engine's float32
    # sqrt is (torch's float32 sqrt on the CPU is not, by 1 ulp in 1 value of 6).
    root = torch.sqrt((x.abs() + eps).double()).to(x.dtype)
    return x / (root + sqrt_eps)


def from_root(y: torch.Tensor) -> torch.Tensor:
    """Linear values of root-domain ``y``: sign(y)·((|y| + √ε)² − ε), computed as
    y·(|y| + 2√ε) (the gradient at 0 is 2√ε)."""
    twice = torch.tensor(float(2 * ROOT_SQRT_EPS), dtype=y.dtype)
    return y * (y.abs() + twice)


class RootDomain(nn.Module):
    """A demosaic stage ``inner`` that interpolates square roots: ``forward`` is
    from_root ∘ inner ∘ to_root; ``reverse`` (sampling, pointwise) is inner's."""

    def __init__(self, inner: nn.Module) -> None:
        super().__init__()
        self.inner = inner

    @property
    def radius(self) -> int:
        return self.inner.radius

    def forward(self, mosaic: torch.Tensor) -> torch.Tensor:
        return from_root(self.inner(to_root(mosaic)))

    def reverse(self, rgb: torch.Tensor) -> torch.Tensor:
        return self.inner.reverse(rgb)


class Demosaic(nn.Module):
    """Demosaic stage: ``forward`` mosaic → RGB, ``reverse`` RGB → mosaic (sampling)."""

    def __init__(self, cfa: CFA, method: str = "learned") -> None:
        super().__init__()
        self.cfa = cfa
        self.method = check_choice("demosaic method", method, DEMOSAIC_METHODS)

    @property
    def radius(self) -> int:
        """Rows of context each output row depends on (bounded generously)."""
        wcd = 16
        return {"bilinear": 2, "malvar": 2, "menon": 12, "wcd": wcd, "learned": wcd + REACH}[
            self.method
        ]

    def forward(self, mosaic: torch.Tensor) -> torch.Tensor:
        return demosaic(mosaic, self.cfa, self.method)

    def reverse(self, rgb: torch.Tensor) -> torch.Tensor:
        return self.cfa.mosaic(rgb)
