"""Filtering a CFA mosaic plane by plane, so that each site only sees its own colour.

The mosaic (B, 1, H, W) is packed into its R, Gr, Gb, B planes (B, 4, H/2, W/2),
filtered, and unpacked. This fixes the original design's defect of filtering
across the mosaic, which mixes colours.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

from rawsim.cfa import CFA


def per_plane(mosaic: torch.Tensor, cfa: CFA, fn: Callable[[torch.Tensor], torch.Tensor]):
    """Apply ``fn`` to the packed planes (B, 4, H/2, W/2) of ``mosaic`` and unpack."""
    return cfa.unpack(fn(cfa.pack(mosaic)))


def neighbourhood(x: torch.Tensor, size: int) -> torch.Tensor:
    """All ``size``×``size`` shifted copies, mirror-padded: (B, C, H, W) → (size², B, C, H, W)."""
    pad = size // 2
    h, w = x.shape[-2:]
    padded = F.pad(x, (pad, pad, pad, pad), mode="reflect")
    return torch.stack(
        [padded[..., i : i + h, j : j + w] for i in range(size) for j in range(size)]
    )


def filter2d(x: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Correlate every channel of (B, C, H, W) with a normalised 2-D kernel (mirror borders)."""
    k = kernel.to(x.dtype).to(x.device)
    c = x.shape[1]
    pad_h, pad_w = k.shape[0] // 2, k.shape[1] // 2
    padded = F.pad(x, (pad_w, pad_w, pad_h, pad_h), mode="reflect")
    return F.conv2d(padded, k.expand(c, 1, *k.shape), groups=c)


def gaussian_kernel(sigma: float, size: int | None = None) -> torch.Tensor:
    """A normalised 2-D Gaussian (size × size, default odd ≥ 6σ), float64."""
    size = size or max(3, 2 * int(3 * sigma + 0.5) + 1)
    t = torch.arange(size, dtype=torch.float64) - size // 2
    g = torch.exp(-(t**2) / (2 * sigma**2))
    k = g[:, None] * g[None, :]
    return k / k.sum()
