"""The learned correction after ``wcd`` (torch reference; the engine's form is
:func:`rawsim.engine.process._correct`): (B, 3, H, W) → (B, 3, H, W).

At each site of a Bayer mosaic, each colour the site did not measure gets a
linear filter of the ``wcd`` values of all three colours in the 5 × 5 window
around it: 75 taps, one set for each site class (R, Gr, Gb, B) and colour
(:mod:`rawsim.learned_demosaic.filters`). The site's own colour is never changed
(its filter is zero); each filter's taps on each input colour sum to zero, so a
flat colour passes unchanged; and each filter is symmetric in rows and in
columns, as every class's neighbourhood is. The correction is linear, so it
commutes with scaling the image (exposure). Borders
are mirror-padded, as the demosaics' are (a 2-site reflection keeps the CFA
phase). No clipping; differentiable.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from rawsim.cfa import CFA
from rawsim.learned_demosaic.filters import REACH, SIZE, load_filters


def correct(rgb: torch.Tensor, cfa: CFA, filters: torch.Tensor | None = None) -> torch.Tensor:
    """``rgb`` (B, 3, H, W), a ``wcd`` demosaic of a ``cfa`` mosaic (any values: the
    demosaic's domain), plus the correction of ``filters`` (a (4, 3, 3, SIZE, SIZE)
    tensor; default the shipped ones, :func:`~rawsim.learned_demosaic.filters.load_filters`)."""
    filters = torch.tensor(load_filters()) if filters is None else filters
    h, w = rgb.shape[-2:]
    weight = filters.to(rgb).reshape(12, 3, SIZE, SIZE)
    padded = F.pad(rgb, (REACH,) * 4, mode="reflect")
    by_class = F.conv2d(padded, weight).unflatten(1, (4, 3))  # (B, 4, 3, H, W)
    sites = cfa.site_masks(h, w, device=rgb.device, dtype=rgb.dtype)[:, None]  # (4, 1, H, W)
    return rgb + (by_class * sites).sum(1)
