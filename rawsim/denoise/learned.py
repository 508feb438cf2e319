"""Learned raw denoising: a small network that refines the profiled estimate.

The network (:class:`RefineNet`, a three-scale U-Net of 0.61 M parameters) works
on a mosaic's packed planes (half size): a Bayer mosaic's R, G, G and B, an
X-Trans mosaic's four sites of each 2 × 2 block (:func:`packing`). Its input: the
noisy planes, the profiled method's estimate of them
(:mod:`rawsim.denoise.profiled`), and the noise model's σ at that estimate, site
by site (the noise-level map, so that one set of weights serves every camera and
ISO), 12 channels; for X-Trans also the colour of each plane's site at each
packed pixel (12 channels of 0 and 1), since a block's colours change across the
6 × 6 period. The first three are divided by the model's σ at 10 % of white
(:func:`noise_scale`), so the network sees noise of about the same size at every
ISO. Its output, less its own mean
over :data:`MEAN_BOX` × :data:`MEAN_BOX` packed pixels, is added to the
estimate: the network restores detail and removes what noise is left, and local
levels stay the profiled estimate's, whose transform is unbiased (without this,
flat patches of the real chart in the tests moved by up to 1.2 times the bound
the test allows, where the profiled estimate moves by 0.3 times it).

Each set of weights was trained only on pairs rawsim made (``rawsim unprocess
--randomize --clean``) from photos outside the Kodak set, across profiles of its
kind of mosaic and their ISO ranges: :mod:`rawsim.denoise.training` holds the
script, the image list with sources and licences, the seeds and the time it took.
The weights ship in the package (``weights/refine_bayer.safetensors`` and
``refine_xtrans.safetensors``, safetensors, 2.4 MB each) and are loaded on first
use.

Inference runs in tiles of :data:`TILE` packed pixels with :data:`OVERLAP` of
context on each side (more than the network's reach, :data:`REACH`), so the
result equals the whole image's and memory stays flat at any size; on CUDA when
the input is there. Other CFAs have no weights (:func:`weights_kind`): the stage
falls back to ``profiled`` and warns.
"""

from __future__ import annotations

import functools
from importlib import resources

import numpy as np
import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.denoise.layout import packing, weights_kind
from rawsim.denoise.profiled import profiled_denoise

#: The weights in the package, by the kind of mosaic they serve (:func:`weights_kind`).
WEIGHTS = {"bayer": "refine_bayer.safetensors", "xtrans": "refine_xtrans.safetensors"}
#: The network's input channels by kind: noisy, estimate and σ planes, and for X-Trans
#: the colour of each plane's site (R, G, B one-hot per plane).
INPUTS = {"bayer": 12, "xtrans": 24}
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
    """Three-scale convolutional network (a small U-Net): (B, ``inputs``, h, w) → (B, 4,
    h, w), h and w multiples of 4. Full, half and quarter resolution, ``width``, 2× and
    4× that many channels; each coarser scale is upsampled and joined to the finer."""

    def __init__(self, width: int = 32, inputs: int = 12) -> None:
        super().__init__()
        w, w2, w4 = width, 2 * width, 4 * width

        def convs(n_in, n_out, n, stride=1):  # n 3 × 3 convolutions, each with a ReLU
            layers = [nn.Conv2d(n_in, n_out, 3, stride=stride, padding=1), nn.ReLU(inplace=True)]
            for _ in range(n - 1):
                layers += [nn.Conv2d(n_out, n_out, 3, padding=1), nn.ReLU(inplace=True)]
            return nn.Sequential(*layers)

        self.head = convs(inputs, w, 2)
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


def period_values(cfa: CFA, values) -> list[float]:
    """Per-colour ``values`` (R, G, B) at each site of one period, in the order of
    :attr:`CFA.phase_sites` (for Bayer, the packed planes')."""
    return [values[cfa.color_at(*site)] for site in cfa.phase_sites]


def noise_scale(cfa: CFA, gain, offset) -> float:
    """The σ of the noise model at :data:`REFERENCE_LEVEL` of white, averaged over one
    period's sites (normalised units): what the network's inputs are divided by.
    ``gain``/``offset``: per colour (R, G, B)."""
    g = torch.tensor(period_values(cfa, gain), dtype=torch.float32)
    o = torch.tensor(period_values(cfa, offset), dtype=torch.float32)
    return float((g.mean() * REFERENCE_LEVEL + o.mean()).sqrt())


def plane_maps(cfa: CFA, table, rows: slice, cols: slice) -> np.ndarray:
    """A per-site ``table`` (ph, pw) of one period laid out as packed planes over packed
    rows × cols: (4, h, w); (4, 1, 1) for Bayer, whose planes each hold one site."""
    table = np.asarray(table)
    sites = packing(cfa)
    if cfa.is_bayer:
        return np.stack([table[r, c] for r, c in sites]).reshape(4, 1, 1)
    ph, pw = cfa.period
    ys, xs = np.arange(rows.start, rows.stop), np.arange(cols.start, cols.stop)
    return np.stack([table[np.ix_((2 * ys + r) % ph, (2 * xs + c) % pw)] for r, c in sites])


def site_inputs(cfa: CFA, gain, offset, rows: slice, cols: slice):
    """Over packed rows × cols: the model's gain and offset at each plane's site ((4,
    h, w), or (4, 1, 1) for Bayer), and for X-Trans the colours one-hot (12, h, w)
    (None for Bayer)."""
    colours = np.array(cfa.colors).reshape(cfa.period)
    g = plane_maps(cfa, np.asarray(gain, np.float32)[colours], rows, cols)
    o = plane_maps(cfa, np.asarray(offset, np.float32)[colours], rows, cols)
    if cfa.is_bayer:
        return g, o, None
    onehot = plane_maps(cfa, colours, rows, cols)[:, None] == np.arange(3)[None, :, None, None]
    return g, o, onehot.reshape(12, *onehot.shape[-2:]).astype(np.float32)


def network_input(noisy, estimate, gain, offset, scale: float, colours=None) -> torch.Tensor:
    """The network's input (B, 12 or 24, h, w) from packed planes (B, 4, h, w)
    normalised to white = 1, the model's ``gain``/``offset`` at each plane's site (any
    shape that broadcasts to the planes), the ``scale`` (:func:`noise_scale`) the first
    12 channels are divided by, and for X-Trans the ``colours`` (B, 12, h, w)."""
    g = torch.as_tensor(gain, dtype=noisy.dtype, device=noisy.device)
    o = torch.as_tensor(offset, dtype=noisy.dtype, device=noisy.device)
    sigma = (g * estimate.clamp_min(0) + o).sqrt()
    x = torch.cat([noisy, estimate, sigma], 1) / scale
    if colours is None:
        return x
    return torch.cat([x, torch.as_tensor(colours, dtype=x.dtype, device=x.device)], 1)


@functools.lru_cache(maxsize=4)
def load_network(kind: str = "bayer", device: str = "cpu") -> RefineNet:
    """The shipped weights of ``kind`` (a key of :data:`WEIGHTS`) in a :class:`RefineNet`
    on ``device``, in eval mode."""
    from safetensors.torch import load_file

    path = resources.files("rawsim.denoise") / "weights" / WEIGHTS[kind]
    with resources.as_file(path) as file:
        state = load_file(str(file), device=device)
    net = RefineNet(inputs=INPUTS[kind])
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


def _delta(net: RefineNet, x: torch.Tensor, scale: float) -> torch.Tensor:
    """The network's correction (B, 4, h, w) of one tile's estimate from its input ``x``
    (:func:`network_input`), in normalised units."""
    h, w = x.shape[-2:]
    x = nn.functional.pad(x, (0, -w % 4, 0, -h % 4), mode="replicate")  # sides of 4k
    delta = net(x)[..., :h, :w]
    box = nn.functional.avg_pool2d(
        delta, MEAN_BOX, stride=1, padding=MEAN_BOX // 2, count_include_pad=False
    )
    return (delta - box) * scale


def refine(noisy, estimate, cfa: CFA, gain, offset, net: RefineNet | None = None) -> torch.Tensor:
    """The network's denoised planes (B, 4, h, w) from noisy and profiled packed planes
    (:func:`packing`) of a mosaic of ``cfa``, tile by tile (see the module doc).
    ``gain``/``offset``: the noise model per colour (R, G, B)."""
    net = net or load_network(weights_kind(cfa), str(noisy.device))
    scale = noise_scale(cfa, gain, offset)
    out = torch.empty_like(estimate)
    for (rows, cols), (keep_r, keep_c) in tiles(*noisy.shape[-2:]):
        part = (..., rows, cols)
        g, o, colours = site_inputs(cfa, gain, offset, rows, cols)
        colours = None if colours is None else torch.from_numpy(colours)[None]
        x = network_input(noisy[part], estimate[part], g, o, scale, colours)
        delta = _delta(net, x, scale)
        out[..., rows, cols][..., keep_r, keep_c] = (estimate[part] + delta)[..., keep_r, keep_c]
    return out


def refine_mosaic(noisy, estimate, cfa: CFA, black, white: float, gain, offset):
    """The engine's form of :func:`learned_denoise`: the (H, W) uint16 mosaics ``noisy``
    and ``estimate`` (the profiled one, :func:`rawsim.engine.denoise.denoise_mosaic`)
    → the refined uint16 mosaic (DN, rounded), tile by tile, so memory stays flat.
    ``black``: per site of a period or one number; ``gain``/``offset`` per colour. An
    odd last row or column keeps the estimate."""
    net = load_network(weights_kind(cfa), "cpu")
    scale = noise_scale(cfa, gain, offset)
    black = np.broadcast_to(np.asarray(black, np.float32), cfa.period)
    sites = packing(cfa)
    h, w = noisy.shape[0] // 2, noisy.shape[1] // 2
    out = estimate.copy()
    with torch.inference_mode():
        for (rows, cols), (keep_r, keep_c) in tiles(h, w):

            def packed(m, rows=rows, cols=cols):
                planes = np.stack([m[r::2, c::2][:h, :w][rows, cols] for r, c in sites])
                return planes.astype(np.float32)

            plane_black = plane_maps(cfa, black, rows, cols)
            span = np.float32(white) - plane_black
            n, e = packed(noisy), packed(estimate)
            to = lambda a, b=plane_black, s=span: torch.from_numpy((a - b) / s)[None]  # noqa: E731
            g, o, colours = site_inputs(cfa, gain, offset, rows, cols)
            colours = None if colours is None else torch.from_numpy(colours)[None]
            delta = _delta(net, network_input(to(n), to(e), g, o, scale, colours), scale)
            dn = np.clip(np.rint(e + delta[0].numpy() * span), 0, 65535)[:, keep_r, keep_c]
            kept = (n >= plane_black + span)[:, keep_r, keep_c]  # clipped: as they were
            dn = np.where(kept, n[:, keep_r, keep_c], dn).astype(np.uint16)
            y0, x0 = rows.start + keep_r.start, cols.start + keep_c.start
            for k, (r, c) in enumerate(sites):
                ys = slice(r + 2 * y0, r + 2 * (y0 + dn.shape[1]), 2)
                xs = slice(c + 2 * x0, c + 2 * (x0 + dn.shape[2]), 2)
                out[ys, xs] = dn[k]
    return out


def learned_denoise(x: torch.Tensor, cfa: CFA, gain, offset, strength: float = 1.0) -> torch.Tensor:
    """Denoise a Bayer or X-Trans mosaic ``x`` (B, 1, H, W), normalised (white = 1),
    noise model per colour (R, G, B) as :func:`~rawsim.denoise.profiled.profiled_denoise`
    takes it. ``strength`` scales the profiled estimate's σ, as there. Sites at or above
    white keep their values; an odd last row or column is the profiled estimate's."""
    estimate = profiled_denoise(x, cfa, gain, offset, strength)
    h, w = x.shape[-2] // 2 * 2, x.shape[-1] // 2 * 2
    sites = packing(cfa)
    packed = [torch.stack([t[:, 0, r:h:2, c:w:2] for r, c in sites], 1) for t in (x, estimate)]
    with torch.inference_mode(not torch.is_grad_enabled()):
        planes = refine(*packed, cfa, gain, offset)
    out = estimate.clone()
    for k, (r, c) in enumerate(sites):
        old = x[:, 0, r:h:2, c:w:2]
        out[:, 0, r:h:2, c:w:2] = torch.where(old >= 1, old, planes[:, k])
    return out
