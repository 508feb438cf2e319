"""Highlight handling after white balance: clip, unclip, blend (dcraw's method) or
reconstruct.

Each colour c clips at its own level L_c, white = 1 before the white balance: its
white-balance gain × the share of its span where it saturates
(:attr:`rawsim.isp.config.ResolvedIsp.clip_levels`; 1 × the gain where the data
say nothing else). White balance pushes saturated sites to different levels per
colour, which turns clipped highlights magenta. ``clip`` limits every value to the
least level (the one intended clipping here; value by value, so on a mosaic of any
CFA as on RGB, as LibRaw does before demosaicking): with the gains LibRaw scales
for its clip, that least level is 1 and every saturated site reaches it, so what
clipped in every colour is white. ``blend`` (RGB only) keeps the clipped image's
lightness and the unclipped image's hue, with the chroma scaled to the clipped
chroma's size, where any channel exceeds the least level — dcraw's ``-H 2``.

``unclip`` (:func:`unclip_highlights`) keeps values above white (LibRaw's ``-H 1``),
but a clipped value (``HIGHLIGHT_UNCLIP_CLIPPED`` of its colour's level or above) is
only a lower bound: clipped light is never darker in one colour than the colours beside it
measured. On a mosaic, before the demosaic (the demosaic would otherwise pull a
clipped green's interpolated value at red and blue sites below its level, so that
green is not raised and the pixel turns magenta), it is read in b × b blocks that
hold every colour (:func:`~rawsim.isp.config.highlight_block`: 2 for Bayer, 3 for
X-Trans; rows and columns beyond the whole blocks take the last block's decision).
In each block: which colours clipped (any of their sites); each clipped site of
those becomes max(its value, T), T the largest value among the block's sites of the
colours that did not clip, or, where every colour clipped, among all the block's
sites (a block clipped in every colour is neutral). Sites of unclipped colours keep
their values. On RGB (after the demosaic, or 3-channel data) a pixel is the block.

``reconstruct`` (:func:`reconstruct_highlights`) rebuilds the clipped colours of
a mosaic (or RGB image) from the colours that did not clip and from the hue of
the unclipped surround, in the spirit of darktable's "inpaint opposed": each
colour clips at its own level, so where one or two colours clip the others still
measure the light. The compiled engine's form of ``unclip`` and ``reconstruct`` on
the mosaic is :mod:`rawsim.engine.highlights`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import ParameterError, check_choice, check_image
from rawsim.isp.config import (
    HIGHLIGHT_BORDER,
    HIGHLIGHT_BORDER_POWER,
    HIGHLIGHT_CLIPPED,
    HIGHLIGHT_HEADROOM,
    HIGHLIGHT_HUE_PRIOR,
    HIGHLIGHT_HUE_REACH,
    HIGHLIGHT_HUE_SIGMA,
    HIGHLIGHT_HUE_SPREAD,
    HIGHLIGHT_MODES,
    HIGHLIGHT_RATIO_FLOOR,
    HIGHLIGHT_SCALE_WEIGHT,
    HIGHLIGHT_SCALES,
    HIGHLIGHT_TRANSFORM,
    HIGHLIGHT_UNCLIP_CLIPPED,
    HIGHLIGHT_WHITE_MARGIN,
    highlight_block,
)

# An orthonormal-ish transform separating lightness from two chroma axes (dcraw).
_TRANS = torch.tensor(HIGHLIGHT_TRANSFORM, dtype=torch.float64)


def handle_highlights(
    x: torch.Tensor, mode: str = "clip", levels=None, cfa: CFA | None = None
) -> torch.Tensor:
    """Apply ``mode`` to white-balanced linear data, colour c clipping at ``levels[c]``
    (R, G, B; default 1 each; ``reconstruct`` needs them): a mosaic (B, 1, H, W) of any
    CFA or an image (B, C, H, W) for ``clip`` (values ≤ the least level out), a mosaic
    with its ``cfa`` or RGB (B, 3, H, W) for ``unclip`` (:func:`unclip_highlights`)
    and ``reconstruct`` (:func:`reconstruct_highlights`), RGB for ``blend`` (values
    above the least level may remain)."""
    check_choice("highlight mode", mode, HIGHLIGHT_MODES)
    check_image(x, "image")
    if mode == "reconstruct":
        if levels is None:
            raise ParameterError("highlight mode 'reconstruct' needs the colours' clip levels")
        return reconstruct_highlights(x, levels, cfa)
    if mode == "unclip":
        return unclip_highlights(x, (1.0, 1.0, 1.0) if levels is None else levels, cfa)
    level = _levels(x, (1.0, 1.0, 1.0) if levels is None else levels)
    least = float(level.min())
    if mode == "clip":
        return x.clamp(max=least)
    if x.shape[1] != 3:
        raise ParameterError(f"highlight mode {mode!r} needs RGB: put the stage after demosaic")
    trans = _TRANS.to(x.dtype).to(x.device)
    inverse = torch.linalg.inv(_TRANS).to(x.dtype).to(x.device)
    clipped = x.clamp(max=least)
    cam = torch.einsum("ij,bjhw->bihw", trans, x)
    lab = torch.einsum("ij,bjhw->bihw", trans, clipped)
    chroma_cam = (cam[:, 1:] ** 2).sum(1, keepdim=True)
    chroma_lab = (lab[:, 1:] ** 2).sum(1, keepdim=True)
    # Fully clipped pixels have no chroma left: clamp inside the root keeps its
    # gradient finite there (the value changes by < 1e-15).
    scale = torch.sqrt((chroma_lab / chroma_cam.clamp_min(1e-20)).clamp_min(1e-30))
    blended = torch.cat([lab[:, :1], cam[:, 1:] * scale], dim=1)
    out = torch.einsum("ij,bjhw->bihw", inverse, blended)
    over = (x > least).any(dim=1, keepdim=True)
    return torch.where(over, out, x)


def _levels(x: torch.Tensor, levels) -> torch.Tensor:
    """The clip levels (3,) as a tensor of ``x``'s dtype and device, checked positive."""
    g = torch.as_tensor(levels, dtype=x.dtype, device=x.device).reshape(3)
    if not bool((g > 0).all()):
        raise ParameterError("the colours' clip levels must be positive")
    return g


def unclip_highlights(x: torch.Tensor, levels, cfa: CFA | None = None) -> torch.Tensor:
    """Values above white kept, clipped values raised to what the colours beside them
    measured: a white-balanced mosaic (B, 1, H, W) of ``cfa``, or RGB (B, 3, H, W),
    linear, colour c clipping at ``levels[c]`` (R, G, B). Returns the same shape; no
    value is lowered, none is clipped.

    A clipped value (a site ≥ ``HIGHLIGHT_UNCLIP_CLIPPED`` of its colour's level) is
    only a lower bound. The mosaic is read in b × b blocks that hold every colour
    (:func:`highlight_block`: 2 for Bayer, 3 for X-Trans; rows and columns beyond the
    whole blocks take the last block's decision, as :func:`reconstruct_highlights`
    does); on RGB a pixel is the block. In each block, the colours that clipped (any
    of their sites clipped) are found; each clipped site of those becomes max(its
    value, T), T the largest value among the block's sites of the colours that did
    not clip, or, where every colour clipped, the largest among all the block's sites
    (a block clipped in every colour is neutral, at its brightest site). Sites of
    colours that did not clip in their block, and sites below their colour's clip
    threshold, keep their values. Differentiable almost everywhere (the maxima pass
    the gradient to the values they take).
    """
    check_image(x, "image")
    g = _levels(x, levels)
    cmap, b = _layout(x, cfa, "unclip")
    h, w = x.shape[-2:]
    hb, wb = h // b, w // b
    if hb == 0 or wb == 0:
        return x
    _, clipped, peaks = _blocks(x, g, cmap, b, hb, wb, HIGHLIGHT_UNCLIP_CLIPPED)
    # T: the largest value of the colours that did not clip; of all where all did
    every = clipped.all(1, keepdim=True)
    top = torch.where(clipped & ~every, -torch.inf, peaks).amax(1, keepdim=True)
    if cmap is None:
        return torch.where(clipped, torch.maximum(x, top), x)
    index = cmap.expand(x.shape[0], 1, h, w)
    level = (HIGHLIGHT_UNCLIP_CLIPPED * g)[cmap]
    clip_site = (_grow(clipped.to(x.dtype), b, h, w).gather(1, index) > 0) & (x >= level)
    return torch.where(clip_site, torch.maximum(x, _grow(top, b, h, w)), x)


def _layout(x: torch.Tensor, cfa: CFA | None, mode: str):
    """(colour map, block side) of a mosaic of ``cfa`` (:func:`colour_map`,
    :func:`highlight_block`), or (None, 1) for RGB: a pixel is the block."""
    if x.shape[1] == 3:
        return None, 1
    if x.shape[1] != 1:
        raise ParameterError(f"{mode} needs a mosaic or RGB, got shape {tuple(x.shape)}")
    if cfa is None:
        raise ParameterError("a mosaic (B, 1, H, W) needs its CFA pattern")
    return colour_map(cfa, *x.shape[-2:], x.device), highlight_block(cfa.colors, cfa.period)


def _grow(t: torch.Tensor, b: int, h: int, w: int) -> torch.Tensor:
    """Block values (B, C, Hb, Wb) at each site (B, C, H, W) of their b × b blocks;
    the rows and columns beyond whole blocks take the last block's."""
    hb, wb = t.shape[-2:]
    sites = t.repeat_interleave(b, -2).repeat_interleave(b, -1)
    return F.pad(sites, (0, w - wb * b, 0, h - hb * b), mode="replicate")


def reconstruct_highlights(x: torch.Tensor, levels, cfa: CFA | None = None) -> torch.Tensor:
    """Rebuild clipped colours: a white-balanced mosaic (B, 1, H, W) of ``cfa``, or RGB
    (B, 3, H, W), linear, colour c clipping at ``levels[c]`` (R, G, B; its
    white-balance gain where it saturates at white = 1). Returns the same shape; values
    may exceed 1 (at most ``HIGHLIGHT_HEADROOM`` × the colour's clip level) and none is
    lowered.

    The mosaic is read in b × b blocks that hold every colour (:func:`highlight_block`:
    2 for Bayer, 3 for X-Trans; a pixel of RGB). In each block: the mean of each
    colour, and which colours clipped (a site ≥ ``HIGHLIGHT_CLIPPED`` of its level).
    Blocks within ``HIGHLIGHT_BORDER`` blocks of a clipped one, but with no clipped
    colour in their 3 × 3 neighbourhood, measure the hue: each colour's share of the
    colours' sum over their 3 × 3 blocks, weighted by that brightness (its brightest
    colour over its clip level, at most 1) to the power ``HIGHLIGHT_BORDER_POWER``. Box means of
    those shares over the ``HIGHLIGHT_SCALES`` (each scale weighted
    ``HIGHLIGHT_SCALE_WEIGHT`` times the one before), normalised by the weights',
    carry the border's hue into clipped blocks; without any within reach the hue is
    neutral (equal shares).

    Where one colour clipped, the other two test that hue against white light
    (equal shares): the hue is blended with neutral by the odds of each predicting
    their ratio and raising the clipped colour to at least its clipped mean (misses
    squared in logs, a Gaussian of width ``HIGHLIGHT_HUE_SIGMA``; the hue ahead by
    ``HIGHLIGHT_HUE_PRIOR`` in log odds, so where both predict alike the border's hue
    is kept), and by how far the hue reaches beyond white light (:func:`_hue_reach`):
    a hue that would raise the clipped colour to more than ``HIGHLIGHT_HUE_REACH``
    times what white light gives it came from the border, not from the light the
    other two measured (a lamp in a room lit deep blue by an LED stays white, as every
    raw converter's clip shows it, where the border's hue made it purple).
    Where two clipped, the third tests white light, at any depth: white light would
    have put it at least at their clip levels, so κ is how far below it lies
    (:func:`_white_refuted`): a sky whose green and blue clipped stays blue, and a
    highlight whose third colour nears their levels stays white, beside a coloured
    border too; unless the border's hue is refuted as well, putting a clipped colour
    below its clipped mean (:func:`_hue_refuted`): then neither is kept, and the block
    goes neutral (κ falls by how surely the hue is refuted). Where the hue gives green
    the least share, κ also falls by the border's spread of hue
    (``HIGHLIGHT_HUE_SPREAD``): brown and blue borders average to a purple that none
    of them has.
    Where three clipped nothing measured the light: it is white (on the real raws of
    ``tests/data/highlights``, lamps, glints and windows that clipped in every colour
    are white in every raw converter's render; on the synthetic benchmark white is
    the better guess there too).

    Each site that clipped (in a block where its colour clipped; its unclipped
    neighbours measured their light and keep it) then becomes max(its value, share ×
    level): the level is fitted, at that site, to the brightness-weighted means
    (:func:`_local_levels`) over its 3 × 3 neighbourhood of the colours its block did
    not clip (on RGB, the pixel's own), so a site at an edge is lit as its bright side
    is, or raised to the block's largest clipped mean over its share where that is
    higher. The fit is made twice: the second reads the neighbours the first rebuilt
    at their rebuilt values (a clipped value is only a lower bound). Differentiable
    almost everywhere; support: (largest scale + border + 2) blocks.
    """
    check_image(x, "image")
    g = _levels(x, levels)
    cmap, b = _layout(x, cfa, "reconstruct")
    h, w = x.shape[-2:]
    hb, wb = h // b, w // b
    if hb == 0 or wb == 0:
        return x
    means, clipped, _ = _blocks(x, g, cmap, b, hb, wb)
    anyclip = clipped.any(1, keepdim=True)
    if not bool(anyclip.any()):
        return x
    share, floor = _estimates(means, clipped, anyclip, g)
    if cmap is None:
        est = _level_estimates(means, share, floor, ~clipped, g)
        return torch.where(clipped, torch.maximum(x, est), x)
    # Each site takes its block's value (edge rows/columns beyond whole blocks the last).
    grow = lambda t: _grow(t, b, h, w)  # noqa: E731
    index = cmap.expand(x.shape[0], 1, h, w)
    free = grow((~clipped).to(x.dtype)) > 0
    share, floor = grow(share), grow(floor)
    # A site is rebuilt where it clipped itself, in a block where its colour clipped:
    # its neighbours in the block that did not clip measured their light.
    level = (HIGHLIGHT_CLIPPED * g)[cmap]
    clip_site = (grow(clipped.to(x.dtype)).gather(1, index) > 0) & (x >= level)
    out = x
    for _ in range(2):  # the second fit reads rebuilt neighbours, not their clipped values
        est_site = _level_estimates(_local_levels(out, cmap), share, floor, free, g)
        out = torch.where(clip_site, torch.maximum(x, est_site.gather(1, index)), x)
    return out


def colour_map(cfa: CFA, h: int, w: int, device) -> torch.Tensor:
    """(1, 1, H, W) int64: the colour (R=0, G=1, B=2) of each site."""
    ph, pw = cfa.period
    tile = torch.tensor(cfa.colors, device=device).reshape(ph, pw)
    return tile.repeat(-(-h // ph), -(-w // pw))[:h, :w].reshape(1, 1, h, w)


def _blocks(x, g, cmap, b, hb, wb, clipped: float = HIGHLIGHT_CLIPPED):
    """Per block (B, 3, Hb, Wb): each colour's mean, whether it clipped (a site ≥
    ``clipped`` × its level), and its largest value; on RGB (``cmap`` None) the
    pixel's."""
    level = (clipped * g).reshape(1, 3, 1, 1)
    if cmap is None:
        return x, x >= level, x
    n = x.shape[0]
    site = x[..., : hb * b, : wb * b]
    colour = cmap[..., : hb * b, : wb * b]
    onehot = colour == torch.arange(3, device=x.device).reshape(1, 3, 1, 1)  # (1, 3, h, w)
    split = (n, 3, hb, b, wb, b)
    sums = torch.where(onehot, site, 0.0).reshape(split).sum((3, 5))
    counts = onehot.to(x.dtype).reshape(1, *split[1:]).sum((3, 5))
    peaks = torch.where(onehot, site, -torch.inf).reshape(split).amax((3, 5))
    over = onehot & (site >= level.reshape(3)[colour])
    return sums / counts, over.reshape(split).any(5).any(3), peaks


def _box(a: torch.Tensor, s: int) -> torch.Tensor:
    """Sums of ``a`` (B, C, H, W) over (2s + 1)² boxes, zero outside (float64)."""
    h, w = a.shape[-2:]
    c = F.pad(a, (0, 0, s + 1, s)).cumsum(-2)
    rows = c[..., 2 * s + 1 : 2 * s + 1 + h, :] - c[..., :h, :]
    c = F.pad(rows, (s + 1, s)).cumsum(-1)
    return c[..., 2 * s + 1 : 2 * s + 1 + w] - c[..., :w]


def _estimates(means, clipped, anyclip, g):
    """Per block: each colour's share of the light, the hue rebuilt values take
    (B, 3, Hb, Wb), and the least level the clipped colours allow (B, 1, Hb, Wb)."""
    dtype = means.dtype
    near = F.max_pool2d(anyclip.to(dtype), 3, stride=1, padding=1) > 0
    k = HIGHLIGHT_BORDER
    border = (F.max_pool2d(anyclip.to(dtype), 2 * k + 1, stride=1, padding=k) > 0) & ~near
    total = means.sum(1, keepdim=True)
    share = means / torch.where(total > 0, total, 1.0)
    # A border block's hue is read over its 3 × 3 blocks (none clipped), so that one
    # astride an edge (a colour's sites on either side) gives no false hue.
    around = F.avg_pool2d(means, 3, stride=1, padding=1, count_include_pad=False)
    around_total = around.sum(1, keepdim=True)
    lit = around_total > 0
    bright = (around / g.reshape(1, 3, 1, 1)).amax(1, keepdim=True).clamp(0.0, 1.0)
    weight = torch.where(border & lit, bright**HIGHLIGHT_BORDER_POWER, 0.0)
    hue_of = around / torch.where(lit, around_total, 1.0)
    fields = torch.cat([weight * hue_of, weight, weight * hue_of**2], 1).double()
    hue_sum = 0.0
    for k, s in enumerate(HIGHLIGHT_SCALES):
        box = _box(fields, s) / float((2 * s + 1) ** 2)
        hue_sum = hue_sum + box * HIGHLIGHT_SCALE_WEIGHT**k
    has = hue_sum[:, 3:4] > 0
    hue = torch.where(has, hue_sum[:, :3] / torch.where(has, hue_sum[:, 3:4], 1.0), 1.0 / 3.0)
    # the border's spread of hue: the root of its shares' summed variances
    second = torch.where(has, hue_sum[:, 4:] / torch.where(has, hue_sum[:, 3:4], 1.0), 0.0)
    spread = (second - torch.where(has, hue, 0.0) ** 2).clamp_min(0.0).sum(1, keepdim=True)
    agree = (1 - spread.sqrt() / HIGHLIGHT_HUE_SPREAD).clamp(0.0, 1.0).to(dtype)
    count = clipped.sum(1, keepdim=True)  # colours clipped in each block
    hue = hue.to(dtype)
    # Two clipped: the border's hue wins over white light by how surely the third colour
    # refutes white, at any depth (beside the border too: a white highlight in coloured
    # surroundings stays white), unless the hue is refuted too (then neither is kept:
    # neutral); a hue with the least green, averaged from a border that disagrees (brown
    # and blue: purple), is no border block's: kept by how well the border agrees.
    kappa = _white_refuted(means, clipped, g) * (1 - _hue_refuted(means, clipped, hue))
    least_green = hue[:, 1:2] <= hue.amin(1, keepdim=True)
    kappa = torch.where(least_green, kappa * agree, kappa)
    # One clipped: the other two's ratio tests the hue against white light, and the hue
    # is kept only as far as it reaches (:func:`_hue_reach`).
    trust = _hue_or_white(means, share, hue, clipped) * _hue_reach(means, clipped, hue)
    share = torch.where(
        count == 3,
        1.0 / 3.0,  # nothing measured the light: white
        torch.where(
            count == 2,
            kappa * hue + (1 - kappa) / 3,
            torch.where(count == 1, _at_least_white(trust * hue + (1 - trust) / 3, clipped), hue),
        ),
    )
    share = share.clamp_min(HIGHLIGHT_RATIO_FLOOR)
    floor = torch.where(clipped, means / share, 0.0).amax(1, keepdim=True)
    return share, floor


def _at_least_white(share, clipped):
    """Where one colour clipped: ``share`` with the clipped colour's at least a third
    (the others scaled to keep the sum): rebuilt, it is at least the other two's
    mean, as bright as white light would make it. A clipped value is a lower bound,
    and a hue with less of it than white (a border of skin or brick around white light
    whose green alone clipped) would rebuild it short: magenta."""
    own = torch.where(clipped, share, 0.0).sum(1, keepdim=True)
    lifted = own.clamp_min(1.0 / 3.0)
    rest = (1 - lifted) / (1 - own).clamp_min(HIGHLIGHT_RATIO_FLOOR)
    return torch.where(clipped, lifted, share * rest)


def _white_refuted(means, clipped, g):
    """Where two colours clipped: how surely (0–1) the light is not white, from the
    third colour's mean, which white light would put at least at the clipped colours'
    clip levels (full at (1 − ``HIGHLIGHT_WHITE_MARGIN``) of the highest or below)."""
    level = (HIGHLIGHT_CLIPPED * g).reshape(1, 3, 1, 1)
    seen = torch.where(clipped, 0.0, means).amax(1, keepdim=True)
    need = torch.where(clipped, level, 0.0).amax(1, keepdim=True)
    return _refuted(seen / need.clamp_min(HIGHLIGHT_RATIO_FLOOR))


def _hue_reach(means, clipped, hue):
    """Where one colour clipped: how far (0–1) the border's ``hue`` is kept, by the value
    it gives the clipped colour over the least white light gives it (the other two's
    mean, at least the colour's clipped mean): whole up to ``HIGHLIGHT_HUE_REACH[0]``
    times, none from ``HIGHLIGHT_HUE_REACH[1]`` times. The light's hue was measured
    by the colours that did not clip; a hue that puts the one that did far beyond them
    comes from the border alone (a wall lit deep blue around a white lamp)."""
    top = torch.where(clipped, means, 0.0).sum(1, keepdim=True)
    rest = torch.where(clipped, 0.0, means).sum(1, keepdim=True)
    hue_top = torch.where(clipped, hue, 0.0).sum(1, keepdim=True)
    hue_rest = torch.where(clipped, 0.0, hue).sum(1, keepdim=True)
    guess = hue_top * rest / hue_rest.clamp_min(HIGHLIGHT_RATIO_FLOOR)
    white = torch.maximum(top, rest / 2).clamp_min(HIGHLIGHT_RATIO_FLOOR)
    lo, hi = HIGHLIGHT_HUE_REACH
    return ((hi - guess / white) / (hi - lo)).clamp(0.0, 1.0)


def _hue_refuted(means, clipped, hue):
    """Where two colours clipped: how surely (0–1) ``hue`` is not the light's, from the
    third colour's mean, which that hue would put at least at the clipped colours' means
    (full where it puts one at (1 − ``HIGHLIGHT_WHITE_MARGIN``) of its mean or below):
    a brown border's hue cannot have made a block whose green and blue clipped while
    its red stayed low."""
    seen = torch.where(clipped, 0.0, means).amax(1, keepdim=True)
    hue_seen = torch.where(clipped, 0.0, hue).amax(1, keepdim=True)
    made = seen * hue / hue_seen.clamp_min(HIGHLIGHT_RATIO_FLOOR)
    rho = torch.where(clipped, made / means.clamp_min(HIGHLIGHT_RATIO_FLOOR), 1.0)
    return _refuted(rho.amin(1, keepdim=True))


def _refuted(rho):
    """How surely (0–1) a guess is refuted, from what it predicts over what was
    measured (``rho``, clamped to 0–1): full at (1 − ``HIGHLIGHT_WHITE_MARGIN``) or
    below."""
    return ((1 - rho.clamp(0.0, 1.0)) / HIGHLIGHT_WHITE_MARGIN).clamp(0.0, 1.0)


def _local_levels(x: torch.Tensor, cmap: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W): each colour's brightness-weighted mean, Σ v² / Σ v (values below 0
    taken as 0; 0 where all are), over each site's 3 × 3 neighbourhood of the mosaic
    ``x`` (B, 1, H, W) (sites inside the image; NaN where a colour has none). The
    brighter neighbours count most: a clipped site at an edge (a twig across a blown
    sky) is lit as its bright side is, not as the mean with the dark side."""
    onehot = (cmap == torch.arange(3, device=x.device).reshape(1, 3, 1, 1)).to(x.dtype)
    v = onehot * x.clamp_min(0.0)
    squares = F.avg_pool2d(v * v, 3, stride=1, padding=1)
    sums = F.avg_pool2d(v, 3, stride=1, padding=1)
    counts = F.avg_pool2d(onehot, 3, stride=1, padding=1).expand_as(sums)
    level = torch.where(sums > 0, squares / torch.where(sums > 0, sums, 1.0), 0.0)
    return torch.where(counts > 0, level, torch.nan)


def _level_estimates(seen, share, floor, free, g):
    """Each colour's rebuilt value (B, 3, …) where its hue is ``share`` (B, 3, …): the
    colours seen unclipped (``free``; ``seen`` their measured means, NaN where none
    was seen) over their shares give the level, raised to ``floor`` (the least level
    the clipped colours allow), at most ``HIGHLIGHT_HEADROOM`` × each clip level."""
    use = free & ~seen.isnan()
    num = torch.where(use, seen, 0.0).double().sum(1, keepdim=True)
    den = torch.where(use, share, 0.0).double().sum(1, keepdim=True)
    level = torch.where(den > 0, num / torch.where(den > 0, den, 1.0), 0.0)
    level = torch.maximum(level, floor.double())
    top = HIGHLIGHT_HEADROOM * g.double().reshape(1, 3, 1, 1)
    return torch.minimum(share.double() * level, top).to(share.dtype)


def _hue_or_white(means, seen, hue, clipped):
    """Where one colour clipped: the odds (0–1) of ``hue`` over white light, from how
    well each predicts the other two colours' ratio (``seen``: the block's shares)
    and raises the clipped colour to its clipped mean, the hue ahead by
    ``HIGHLIGHT_HUE_PRIOR`` in log odds."""
    floor = HIGHLIGHT_RATIO_FLOOR
    log = lambda t: t.clamp_min(floor).log()  # noqa: E731
    seen_ratio = guess_ratio = top = rest = hue_top = hue_rest = 0.0
    for c, (a, b) in enumerate(((1, 2), (0, 2), (0, 1))):  # the two colours left
        alone = clipped[:, c : c + 1]
        seen_ratio = seen_ratio + _pick(alone, log(seen[:, a : a + 1]) - log(seen[:, b : b + 1]))
        guess_ratio = guess_ratio + _pick(alone, log(hue[:, a : a + 1]) - log(hue[:, b : b + 1]))
        top = top + _pick(alone, means[:, c : c + 1])
        rest = rest + _pick(alone, means[:, a : a + 1] + means[:, b : b + 1])
        hue_top = hue_top + _pick(alone, hue[:, c : c + 1])
        hue_rest = hue_rest + _pick(alone, hue[:, a : a + 1] + hue[:, b : b + 1])

    def short(estimate):  # how far an estimate falls below the clipped mean
        return (log(top) - log(estimate)).clamp_min(0.0) ** 2

    miss_white = seen_ratio**2 + short(rest / 2)
    miss_hue = (seen_ratio - guess_ratio) ** 2 + short(
        hue_top.clamp_min(floor) * rest / hue_rest.clamp_min(floor)
    )
    return torch.sigmoid(
        (miss_white - miss_hue) / (2 * HIGHLIGHT_HUE_SIGMA**2) + HIGHLIGHT_HUE_PRIOR
    )


def _pick(where: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return torch.where(where, t, 0.0)


class Highlights(nn.Module):
    """Highlight stage; ``reverse`` is the identity (clipped values are lost).

    ``levels``: where each colour clips (R, G, B; default 1 each; ``reconstruct``
    needs them); ``unclip`` and ``reconstruct`` on a mosaic need its ``cfa``, and
    :attr:`radius` is then their reach in rows (strips carry that much context).
    """

    def __init__(self, mode: str = "clip", levels=None, cfa: CFA | None = None) -> None:
        super().__init__()
        self.mode = check_choice("highlight mode", mode, HIGHLIGHT_MODES)
        if mode == "reconstruct" and levels is None:
            raise ParameterError("highlight mode 'reconstruct' needs the colours' clip levels")
        self.levels = None if levels is None else tuple(float(v) for v in levels)
        self.cfa = cfa

    @property
    def radius(self) -> int:
        if self.mode not in ("reconstruct", "unclip"):
            return 0
        b = highlight_block(self.cfa.colors, self.cfa.period) if self.cfa else 1
        if self.mode == "unclip":
            return b  # a site reads its own block
        return (max(HIGHLIGHT_SCALES) + HIGHLIGHT_BORDER + 2) * b

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return handle_highlights(x, self.mode, self.levels, self.cfa)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x
