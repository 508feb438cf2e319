"""Learned raw denoising: a small network that refines the profiled estimate.

The network (:class:`RefineNet`, a three-scale U-Net of 0.61 M parameters) works
on a Bayer mosaic's packed planes (R, G, G, B; half size). Its input, 12
channels: the noisy planes, the profiled method's estimate of them
(:mod:`rawsim.denoise.profiled`), and the noise model's σ at that estimate, site
by site (the noise-level map, so that one set of weights serves every camera and
ISO). Everything is divided by the model's σ at 10 % of white, so the network
sees noise of about the same size at every ISO. Its output, less its own mean
over :data:`MEAN_BOX` × :data:`MEAN_BOX` packed pixels, is added to the
estimate: the network restores detail and removes what noise is left, and local
levels stay the profiled estimate's, whose transform is unbiased (without this,
flat patches of the real chart in the tests moved by up to 1.2 times the bound
the test allows, where the profiled estimate moves by 0.3 times it).

It was trained only on pairs rawsim made (``rawsim unprocess --randomize
--clean``) from photos outside the Kodak set, across the bundled Bayer profiles
and their ISO ranges: :mod:`rawsim.denoise.training` holds the script, the image
list with sources and licences, the seeds and the time it took. The weights ship
in the package (``weights/refine_bayer.safetensors``, safetensors, 2.4 MB) and
are loaded on first use.

Inference runs in tiles of :data:`TILE` packed pixels with :data:`OVERLAP` of
context on each side (more than the network's reach, :data:`REACH`), so the
result equals the whole image's and memory stays flat at any size; on CUDA when
the input is there. Other CFAs (X-Trans) have no weights: the stage falls back
to ``profiled`` and warns.
"""

from __future__ import annotations

import functools
from importlib import resources

import numpy as np
import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.denoise.profiled import profiled_denoise

#: The weights, in the package.
WEIGHTS = "refine_bayer.safetensors"
#: Packed pixels per tile side, and the context read around each tile.
TILE = 256
OVERLAP = 32
#: The side (packed pixels) of the box over which the network's correction has its
#: mean removed.
MEAN_BOX = 9
#: Rows (packed pixels) an output pixel depends on, each side, at most: the network's
#: 24 (measured: its 3 × 3 convolutions at full, half and quarter resolution, and the
#: grid's phase), then the box.
REACH = 24 + MEAN_BOX // 2
#: The level (white = 1) whose noise σ scales the network's inputs.
REFERENCE_LEVEL = 0.1


class RefineNet(nn.Module):
    """Three-scale convolutional network (a small U-Net): (B, 12, h, w) → (B, 4, h, w),
    h and w multiples of 4. Full, half and quarter resolution, ``width``, 2× and 4×
    that many channels; each coarser scale is upsampled and joined to the finer."""

    def __init__(self, width: int = 32) -> None:
        super().__init__()
        w, w2, w4 = width, 2 * width, 4 * width

        def convs(n_in, n_out, n, stride=1):  # n 3 × 3 convolutions, each with a ReLU
            layers = [nn.Conv2d(n_in, n_out, 3, stride=stride, padding=1), nn.ReLU(inplace=True)]
            for _ in range(n - 1):
                layers += [nn.Conv2d(n_out, n_out, 3, padding=1), nn.ReLU(inplace=True)]
            return nn.Sequential(*layers)

        self.head = convs(12, w, 2)
        self.down = convs(w, w2, 3, stride=2)
        self.down2 = convs(w2, w4, 3, stride=2)
        self.up2 = nn.ConvTranspose2d(w4, w2, 2, stride=2)
        self.join2 = convs(2 * w2, w2, 1)
        self.up = nn.ConvTranspose2d(w2, w, 2, stride=2)
        self.tail = nn.Sequential(*convs(2 * w, w, 1), nn.Conv2d(w, 4, 3, padding=1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        full = self.head(x)
        half = self.down(full)
        half = self.join2(torch.cat([half, self.up2(self.down2(half))], 1))
        return self.tail(torch.cat([full, self.up(half)], 1))


def network_input(noisy, estimate, gain, offset) -> tuple[torch.Tensor, float]:
    """The network's input (B, 12, h, w) from packed planes (B, 4, h, w) normalised to
    white = 1 and the model's per-plane ``gain``/``offset`` (4 numbers each), and the
    scale it was divided by."""
    g = torch.as_tensor(gain, dtype=noisy.dtype, device=noisy.device).reshape(1, 4, 1, 1)
    o = torch.as_tensor(offset, dtype=noisy.dtype, device=noisy.device).reshape(1, 4, 1, 1)
    scale = float((g.mean() * REFERENCE_LEVEL + o.mean()).sqrt())
    sigma = (g * estimate.clamp_min(0) + o).sqrt()
    return torch.cat([noisy, estimate, sigma], 1) / scale, scale


@functools.lru_cache(maxsize=2)
def load_network(device: str = "cpu") -> RefineNet:
    """The shipped weights in a :class:`RefineNet` on ``device``, in eval mode."""
    from safetensors.torch import load_file

    path = resources.files("rawsim.denoise") / "weights" / WEIGHTS
    with resources.as_file(path) as file:
        state = load_file(str(file), device=device)
    net = RefineNet()
    net.load_state_dict(state)
    return net.to(device).eval()


def tiles(h: int, w: int):
    """The tiles of (h, w) packed planes: (rows, cols) a tile reads, with its context,
    and (rows, cols) of it that it writes, relative to what it reads."""
    for y0 in range(0, h, TILE):
        for x0 in range(0, w, TILE):
            y1, x1 = min(h, y0 + TILE), min(w, x0 + TILE)
            ya, xa = max(0, y0 - OVERLAP), max(0, x0 - OVERLAP)
            yb, xb = min(h, y1 + OVERLAP), min(w, x1 + OVERLAP)
            yield (slice(ya, yb), slice(xa, xb)), (slice(y0 - ya, y1 - ya), slice(x0 - xa, x1 - xa))


def _delta(net: RefineNet, noisy, estimate, gain, offset) -> torch.Tensor:
    """The network's correction of one tile's estimate (B, 4, h, w), in its units."""
    x, scale = network_input(noisy, estimate, gain, offset)
    h, w = x.shape[-2:]
    x = nn.functional.pad(x, (0, -w % 4, 0, -h % 4), mode="replicate")  # sides of 4k
    delta = net(x)[..., :h, :w]
    box = nn.functional.avg_pool2d(
        delta, MEAN_BOX, stride=1, padding=MEAN_BOX // 2, count_include_pad=False
    )
    return (delta - box) * scale


def refine(noisy, estimate, gain, offset, net: RefineNet | None = None) -> torch.Tensor:
    """The network's denoised planes (B, 4, h, w) from noisy and profiled packed planes,
    tile by tile (see the module doc). ``gain``/``offset``: per plane (4 each)."""
    net = net or load_network(str(noisy.device))
    out = torch.empty_like(estimate)
    for (rows, cols), (keep_r, keep_c) in tiles(*noisy.shape[-2:]):
        part = (..., rows, cols)
        delta = _delta(net, noisy[part], estimate[part], gain, offset)
        out[..., rows, cols][..., keep_r, keep_c] = (estimate[part] + delta)[..., keep_r, keep_c]
    return out


def _per_plane(cfa: CFA, values) -> list[float]:
    """Per-colour ``values`` (R, G, B) for each packed plane of a Bayer ``cfa``."""
    return [values[cfa.color_at(*site)] for site in cfa.packed_sites]


def refine_mosaic(noisy, estimate, cfa: CFA, black, white: float, gain, offset):
    """The engine's form of :func:`learned_denoise`: the (H, W) uint16 mosaics ``noisy``
    and ``estimate`` (the profiled one, :func:`rawsim.engine.denoise.denoise_mosaic`)
    → the refined uint16 mosaic (DN, rounded), tile by tile, so memory stays flat.
    ``black``: per site of a period or one number; ``gain``/``offset`` per colour."""
    net = load_network("cpu")
    ph, pw = cfa.period
    black = np.broadcast_to(np.asarray(black, np.float32), (ph, pw))
    sites = cfa.packed_sites
    plane_black = np.array([black[r, c] for r, c in sites], np.float32).reshape(4, 1, 1)
    span = np.float32(white) - plane_black
    plane_gain, plane_offset = _per_plane(cfa, gain), _per_plane(cfa, offset)
    h, w = noisy.shape[0] // 2, noisy.shape[1] // 2
    out = estimate.copy()
    with torch.inference_mode():
        for (rows, cols), (keep_r, keep_c) in tiles(h, w):

            def packed(m, rows=rows, cols=cols):
                planes = np.stack([m[r::2, c::2][:h, :w][rows, cols] for r, c in sites])
                return planes.astype(np.float32)

            n, e = packed(noisy), packed(estimate)
            to = lambda a: torch.from_numpy((a - plane_black) / span)[None]  # noqa: E731
            delta = _delta(net, to(n), to(e), plane_gain, plane_offset)[0].numpy()
            dn = np.clip(np.rint(e + delta * span), 0, 65535)[:, keep_r, keep_c]
            kept = (n >= plane_black + span)[:, keep_r, keep_c]  # clipped: as they were
            dn = np.where(kept, n[:, keep_r, keep_c], dn).astype(np.uint16)
            y0, x0 = rows.start + keep_r.start, cols.start + keep_c.start
            for k, (r, c) in enumerate(sites):
                ys = slice(r + 2 * y0, r + 2 * (y0 + dn.shape[1]), 2)
                xs = slice(c + 2 * x0, c + 2 * (x0 + dn.shape[2]), 2)
                out[ys, xs] = dn[k]
    return out


def learned_denoise(x: torch.Tensor, cfa: CFA, gain, offset, strength: float = 1.0) -> torch.Tensor:
    """Denoise a Bayer mosaic ``x`` (B, 1, H, W), normalised (white = 1), noise model
    per colour (R, G, B) as :func:`~rawsim.denoise.profiled.profiled_denoise` takes
    it. ``strength`` scales the profiled estimate's σ, as there. Sites at or above
    white keep their values; an odd last row or column is the profiled estimate's."""
    estimate = profiled_denoise(x, cfa, gain, offset, strength)
    h, w = x.shape[-2] // 2 * 2, x.shape[-1] // 2 * 2
    sites = cfa.packed_sites
    plane_gain, plane_offset = _per_plane(cfa, gain), _per_plane(cfa, offset)
    packed = [torch.stack([t[:, 0, r:h:2, c:w:2] for r, c in sites], 1) for t in (x, estimate)]
    with torch.inference_mode(not torch.is_grad_enabled()):
        planes = refine(*packed, plane_gain, plane_offset)
    out = estimate.clone()
    for k, (r, c) in enumerate(sites):
        old = x[:, 0, r:h:2, c:w:2]
        out[:, 0, r:h:2, c:w:2] = torch.where(old >= 1, old, planes[:, k])
    return out
