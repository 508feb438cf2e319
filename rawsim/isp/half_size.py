"""Half-size rendering: one RGB pixel per 2×2 block of the mosaic, no demosaic
(LibRaw's ``half_size``), for previews: the torch reference.

Each output pixel (i, j) takes, for each colour, the mean of that colour's sites
in its block (rows 2i, 2i + 1, columns 2j, 2j + 1): on a Bayer mosaic R, the mean
of the two greens, and B, as LibRaw. A colour missing from the block (on
X-Trans, where a 2×2 block may lack red or blue) takes the mean of its sites in
the 4×4 window around the block (one more site on each side, cut at the image's
edges), which always holds every colour on X-Trans (every 3×3 does); LibRaw
fills such pixels from their horizontal neighbours. An odd last row or column
makes a block of its own. Linear values in and out; nothing is clipped.

The compiled twin is :func:`rawsim.engine.process.half_kernel`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import check_image


def _block_sums(x: torch.Tensor, size: int) -> torch.Tensor:
    """Sums over ``size``×``size`` windows at stride 2: (B, C, H, W) → (B, C, H/2, W/2),
    the windows centred on the 2×2 blocks (``size`` 2 or 4; H, W even)."""
    pad = (size - 2) // 2
    if pad:
        x = F.pad(x, (pad, pad, pad, pad))
    return F.avg_pool2d(x, size, stride=2) * (size * size)


def half_size(mosaic: torch.Tensor, cfa: CFA) -> torch.Tensor:
    """(B, 1, H, W) mosaic on ``cfa`` → (B, 3, ⌈H/2⌉, ⌈W/2⌉) RGB (see the module doc)."""
    check_image(mosaic, "mosaic", channels=1)
    h, w = mosaic.shape[-2:]
    masks = cfa.masks(h, w, device=mosaic.device, dtype=mosaic.dtype)[None]
    if h % 2 or w % 2:  # an odd edge: a block of one row or column, zero-weighted beyond
        masks = F.pad(masks, (0, w % 2, 0, h % 2))
        mosaic = F.pad(mosaic, (0, w % 2, 0, h % 2))
    samples = mosaic * masks  # (B, 3, H, W): each colour's sites, zero elsewhere
    total, count = _block_sums(samples, 2), _block_sums(masks, 2)
    wide_total, wide_count = _block_sums(samples, 4), _block_sums(masks, 4)
    own = total / count.clamp(min=1)
    wide = wide_total / wide_count.clamp(min=1)
    return torch.where(count > 0, own, wide)


class HalfSize(nn.Module):
    """Half-size stage (in place of a demosaic): ``forward`` mosaic → half-size RGB,
    ``reverse`` RGB → a full-size mosaic (each pixel repeated over its block, then
    sampled on the CFA); on a Bayer mosaic ``forward(reverse(x))`` is ``x``."""

    def __init__(self, cfa: CFA) -> None:
        super().__init__()
        self.cfa = cfa

    def forward(self, mosaic: torch.Tensor) -> torch.Tensor:
        return half_size(mosaic, self.cfa)

    def reverse(self, rgb: torch.Tensor) -> torch.Tensor:
        full = rgb.repeat_interleave(2, dim=-2).repeat_interleave(2, dim=-1)
        return self.cfa.mosaic(full)
