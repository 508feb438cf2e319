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
    h, w = x.shape[-2:]
    padded = F.pad(x, (kw // 2, kw // 2, kh // 2, kh // 2), mode="reflect")
    out = None
    for (i, j), weight in zip(k.nonzero().tolist(), k[k != 0].tolist(), strict=True):
        view = padded[..., i : i + h, j : j + w]
        if out is None:
            out = view * weight
        else:
            out.add_(view, alpha=weight)
    return out if out is not None else torch.zeros_like(x)


def gaussian_kernel(sigma: float, size: int | None = None) -> torch.Tensor:
    """A normalised 2-D Gaussian (size × size, default odd ≥ 6σ), float64."""
    size = size or max(3, 2 * int(3 * sigma + 0.5) + 1)
    t = torch.arange(size, dtype=torch.float64) - size // 2
    g = torch.exp(-(t**2) / (2 * sigma**2))
    k = g[:, None] * g[None, :]
    return k / k.sum()
