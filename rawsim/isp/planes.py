"""Filtering a CFA mosaic colour by colour, so that each site only sees its own colour.

Two ways to reach a site's same-colour neighbours, one per kind of pattern:

* **2×2 Bayer** (:func:`per_plane`): the mosaic (B, 1, H, W) is packed into its
  R, Gr, Gb, B planes (B, 4, H/2, W/2), filtered as images and unpacked. The
  two greens are separate planes (they differ by the green split), and a
  ``k``×``k`` window of plane pixels spans ``2·(k // 2)`` mosaic pixels on each
  side. Planes are mirror-padded at the image edges.
* **Any other periodic pattern** (X-Trans, 3×3 …; :func:`per_site`): the sites
  of one colour do not form a grid, so each *phase* of the period (the sites
  at (a + i·ph, b + j·pw)) is filtered on its own, with its own list of
  same-colour neighbours (:func:`same_colour_offsets`): the sites of its
  colour within the same window of ``radius`` mosaic pixels on each side. The
  mosaic is extended at the edges by the pattern-preserving reflection of
  :func:`rawsim.cfa.phase_reflect_index`, so a virtual neighbour has the right
  colour. On a Bayer layout this selects the same sites as its planes do for
  R and B (tested), and the filters give the same values inside the image.

Both fixed the original design's defect of filtering across the mosaic, which
mixes colours.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F

from rawsim.cfa import CFA
from rawsim.errors import ParameterError

#: A site's neighbours: (dy, dx) offsets in mosaic pixels.
Offsets = tuple[tuple[int, int], ...]


def per_plane(mosaic: torch.Tensor, cfa: CFA, fn: Callable[[torch.Tensor], torch.Tensor]):
    """Apply ``fn`` to the packed planes (B, 4, H/2, W/2) of a Bayer ``mosaic`` and unpack."""
    return cfa.unpack(fn(cfa.pack(mosaic)))


def plane_radius(size: int) -> int:
    """Mosaic pixels on each side that a ``size``×``size`` window of plane pixels spans
    (plane pixels are 2 mosaic pixels apart): the window of every pattern."""
    return 2 * (size // 2)


@functools.lru_cache(maxsize=32)
def same_colour_offsets(cfa: CFA, radius: int, centre: bool) -> tuple[Offsets, ...]:
    """For each site of one period (row-major), the offsets (dy, dx) of the sites of its
    colour with |dy|, |dx| ≤ ``radius``, row-major; (0, 0) among them when ``centre``.

    Raises :class:`ParameterError` when a site has no other site of its colour in the
    window (a sparse colour of some pattern): nothing would be filtered there.
    """
    ph, pw = cfa.period
    letters = "RGB"
    table = []
    for a in range(ph):
        for b in range(pw):
            colour = cfa.color_at(a, b)
            window = range(-radius, radius + 1)
            found = tuple(
                (dy, dx)
                for dy in window
                for dx in window
                if cfa.color_at(a + dy, b + dx) == colour and (centre or (dy, dx) != (0, 0))
            )
            if len(found) < 1 + centre:
                raise ParameterError(
                    f"the {cfa.name} pattern has no other {letters[colour]} site within "
                    f"{radius} pixels of its site ({a}, {b}): a filter of this window "
                    "cannot act on it with its own colour"
                )
            table.append(found)
    return tuple(table)


def per_site(
    mosaic: torch.Tensor,
    cfa: CFA,
    radius: int,
    fn: Callable[[torch.Tensor, list[torch.Tensor], Offsets], torch.Tensor],
    centre: bool = True,
) -> torch.Tensor:
    """Filter a mosaic (B, 1, H, W) of any periodic ``cfa`` phase by phase of its period.

    For each phase (a, b), ``fn(sites, values, offsets)`` gets that phase's sites
    (B, 1, ⌈(H − a) / ph⌉, ⌈(W − b) / pw⌉) and the values of their same-colour
    neighbours (:func:`same_colour_offsets` within ``radius``, the sites themselves
    among them when ``centre``), one tensor of that shape per offset, and returns
    the filtered sites. Differentiable.
    """
    from rawsim.isp.xtrans import extend  # the pattern-preserving edge extension

    ph, pw = cfa.period
    check_size(mosaic, radius + max(ph, pw), f"a {cfa.name} mosaic filtered {radius} pixels wide")
    table = same_colour_offsets(cfa, radius, centre)
    h, w = mosaic.shape[-2:]
    padded = extend(mosaic, cfa, radius)
    out = torch.empty_like(mosaic)
    for a in range(ph):
        for b in range(pw):
            rows, cols = len(range(a, h, ph)), len(range(b, w, pw))
            offsets = table[a * pw + b]
            values = [
                padded[..., y : y + ph * (rows - 1) + 1 : ph, x : x + pw * (cols - 1) + 1 : pw]
                for y, x in ((radius + a + dy, radius + b + dx) for dy, dx in offsets)
            ]
            out[..., a::ph, b::pw] = fn(mosaic[..., a::ph, b::pw], values, offsets)
    return out


def check_size(x: torch.Tensor, need: int, what: str) -> None:
    """Raise :class:`ParameterError` unless ``x`` (…, H, W) has ``need`` rows and columns."""
    h, w = x.shape[-2:]
    if h < need or w < need:
        raise ParameterError(f"{what} needs at least {need}×{need} pixels, got {h}×{w}")


def neighbourhood(x: torch.Tensor, size: int) -> torch.Tensor:
    """All ``size``×``size`` shifted copies, mirror-padded: (B, C, H, W) → (size², B, C, H, W)."""
    pad = size // 2
    check_size(x, pad + 1, f"a {size}×{size} window")
    h, w = x.shape[-2:]
    padded = F.pad(x, (pad, pad, pad, pad), mode="reflect")
    return torch.stack(
        [padded[..., i : i + h, j : j + w] for i in range(size) for j in range(size)]
    )


def weighted_sum(values: Sequence[torch.Tensor], weights: Sequence[float]) -> torch.Tensor:
    """Σ weights[k] · values[k], tap by tap (``values`` alike in shape; at least one)."""
    out = None
    for view, weight in zip(values, weights, strict=True):
        if out is None:
            out = view * weight
        else:
            out.add_(view, alpha=weight)
    return out


def correlate(x: torch.Tensor, kernel) -> torch.Tensor:
    """Correlate (N, C, H, W) with a small 2-D kernel, mirror-padded to keep the size.

    Every channel is filtered alike. Summed tap by tap over shifted views: for small
    kernels on few channels that is many times faster than ``conv2d``, and still
    differentiable.
    """
    k = torch.as_tensor(kernel, dtype=torch.float64)
    if k.ndim == 1:
        k = k[None]
    kh, kw = k.shape
    check_size(x, max(kh, kw) // 2 + 1, f"a {kh}×{kw} kernel")
    h, w = x.shape[-2:]
    padded = F.pad(x, (kw // 2, kw // 2, kh // 2, kh // 2), mode="reflect")
    taps = k.nonzero().tolist()
    if not taps:
        return torch.zeros_like(x)
    views = [padded[..., i : i + h, j : j + w] for i, j in taps]
    return weighted_sum(views, k[k != 0].tolist())


def gaussian_size(sigma: float) -> int:
    """The default width of :func:`gaussian_kernel`: the odd size ≥ 6σ, at least 3."""
    return max(3, 2 * int(3 * sigma + 0.5) + 1)


def gaussian_kernel(sigma: float, size: int | None = None) -> torch.Tensor:
    """A normalised 2-D Gaussian (size × size, default :func:`gaussian_size`), float64."""
    size = size or gaussian_size(sigma)
    t = torch.arange(size, dtype=torch.float64) - size // 2
    g = torch.exp(-(t**2) / (2 * sigma**2))
    k = g[:, None] * g[None, :]
    return k / k.sum()
