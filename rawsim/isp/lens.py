"""Lens correction (torch reference): lensfun's distortion, TCA and vignetting, both ways.

:func:`remap_lens` applies a :class:`~rawsim.io.lensfun.LensField` (the radial
tables of :mod:`rawsim.io.lensfun`) to linear RGB: each output pixel's channel k
samples the input at its own source position (Lanczos-3, :mod:`rawsim.resample`:
the 6 × 6 pixels around it, kept within the range of the 2 × 2 nearest, so no
edge rings) and is multiplied by its gain. :func:`correct_lens` takes the lens out
of a photo (what ``rawsim process --lens-correction auto`` does after the demosaic);
:func:`add_lens` puts it into a clean image (the unprocessing direction).
:func:`correct_mosaic_tca` takes the lateral CA out of a Bayer mosaic before the
demosaic (:class:`MosaicTca`), so that the demosaic sees red and blue where green
is; the lens stage then corrects the rest (:func:`~rawsim.io.lensfun.without_tca`). The
compiled engine's twin is :mod:`rawsim.engine.lens`; both evaluate the same float32
arithmetic.

Differentiable in the image (the field is fixed). Values are linear, any range,
never clipped. Positions outside the input take ``padding``: ``zeros`` (black:
there is no image there), ``border`` (the nearest edge pixel) or ``reflect``
(mirrored about the edge pixel, which is not repeated).
"""

from __future__ import annotations

import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.errors import ParameterError, check_choice, check_image
from rawsim.io.lensfun import LensField, LensParams, lens_field, mosaic_tca_fields
from rawsim.resample import FIRST, PHASES, TAPS, lanczos_table

PADDINGS = ("zeros", "border", "reflect")
#: Output pixels per chunk: the per-pixel temporaries stay a few tens of MB.
CHUNK_PIXELS = 1 << 18


def remap_lens(image: torch.Tensor, field: LensField, padding: str = "zeros") -> torch.Tensor:
    """Apply ``field`` to ``image`` (B, 3, H, W), linear RGB with H × W the field's size:
    channel k of output pixel p is ``gain_k · lanczos3(image_k, source_k(p))``. A grey
    image (B, 1, H, W) takes the green channel's remap. Returns the image's shape and
    dtype, computed in chunks of rows."""
    _check(image)
    check_choice("padding", padding, PADDINGS)
    h, w = image.shape[-2:]
    if (h, w) != (field.height, field.width):
        raise ParameterError(
            f"lens field is for {field.height} × {field.width} pixels, the image is {h} × {w}"
        )
    table = torch.tensor(field.table, dtype=image.dtype, device=image.device)
    rows = max(1, CHUNK_PIXELS // w)
    parts = [
        _remap_rows(image, field, table, top, min(h, top + rows), padding)
        for top in range(0, h, rows)
    ]
    return torch.cat(parts, dim=-2)


def _remap_rows(image, field, table, top, bottom, padding):
    """Output rows [top, bottom): (B, 3, rows, W). The engine's arithmetic, in order."""
    b, _, h, w = image.shape
    dev, dt = image.device, image.dtype
    weights = torch.tensor(lanczos_table(), dtype=dt, device=dev)
    cy, cx = (torch.tensor(v, dtype=torch.float32).to(dt) for v in field.centre)
    xi = torch.arange(w, device=dev)
    yi = torch.arange(top, bottom, device=dev)
    dx = (xi.to(dt) - cx.to(dev))[None, :].expand(bottom - top, w)
    dy = (yi.to(dt) - cy.to(dev))[:, None].expand(bottom - top, w)
    # √ in float64: correctly rounded, as the engine's (torch's float32 √ may be off by an ulp)
    r = torch.sqrt((dx * dx + dy * dy).double()).to(dt)
    t = r * torch.tensor(field.scale, dtype=torch.float32).to(dt)
    i = t.long().clamp(max=table.shape[0] - 2)  # t ≥ 0: truncation is floor
    f = t - i.to(dt)
    out = []
    for c, k in enumerate(range(3) if image.shape[1] == 3 else (1,)):
        lo, hi = table[i, k], table[i + 1, k]  # (rows, W, 2): ratio, gain
        ratio = lo[..., 0] + f * (hi[..., 0] - lo[..., 0])
        gain = lo[..., 1] + f * (hi[..., 1] - lo[..., 1])
        m = ratio - 1
        ox, oy = dx * m, dy * m  # source − output, small: kept apart from the position
        fx, fy = torch.floor(ox), torch.floor(oy)
        half = torch.tensor(0.5, dtype=dt, device=dev)
        px = ((ox - fx) * PHASES + half).long()  # ≥ 0: truncation is the engine's int()
        py = ((oy - fy) * PHASES + half).long()
        wx, wy = weights[px], weights[py]  # (rows, W, TAPS)
        x0 = xi[None, :] + fx.long() + FIRST
        y0 = yi[:, None] + fy.long() + FIRST
        plane = image[:, c].reshape(b, h * w)
        acc = torch.zeros((), dtype=dt, device=dev)
        for row_tap in range(TAPS):  # the engine's order of sums
            row = torch.zeros((), dtype=dt, device=dev)
            for col_tap in range(TAPS):
                v = _tap(plane, y0 + row_tap, x0 + col_tap, h, w, padding)
                row = row + wx[..., col_tap] * v
            acc = acc + wy[..., row_tap] * row
        # no ringing: within the range of the 2 × 2 pixels around the sample
        near = [
            _tap(plane, y0 + dy - FIRST, x0 + dx - FIRST, h, w, padding)
            for dy in (0, 1)
            for dx in (0, 1)
        ]
        lo = torch.minimum(torch.minimum(near[0], near[1]), torch.minimum(near[2], near[3]))
        hi = torch.maximum(torch.maximum(near[0], near[1]), torch.maximum(near[2], near[3]))
        acc = torch.minimum(torch.maximum(acc, lo), hi)
        out.append(acc * gain)
    return torch.stack(out, dim=1)


def _check(image: torch.Tensor) -> None:
    check_image(image, "image")
    if image.shape[1] not in (1, 3):
        raise ParameterError(f"image must have 3 channels (or 1), got shape {tuple(image.shape)}")


def _tap(plane: torch.Tensor, y: torch.Tensor, x: torch.Tensor, h: int, w: int, padding: str):
    """``plane`` (B, H·W) at integer positions (y, x) (rows, W), outside per ``padding``."""
    if padding == "zeros":
        inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        v = plane[:, y.clamp(0, h - 1) * w + x.clamp(0, w - 1)]
        return torch.where(inside, v, torch.zeros((), dtype=plane.dtype, device=plane.device))
    if padding == "border":
        return plane[:, y.clamp(0, h - 1) * w + x.clamp(0, w - 1)]
    if padding == "reflect":
        return plane[:, _reflect(y, h) * w + _reflect(x, w)]
    raise ParameterError(f"unknown padding {padding!r}; valid: {', '.join(PADDINGS)}")


def _reflect(i: torch.Tensor, n: int) -> torch.Tensor:
    """Indices mirrored about the first and last (not repeated), then held in [0, n − 1]."""
    i = torch.where(i < 0, -i, i)
    i = torch.where(i > n - 1, 2 * (n - 1) - i, i)
    return i.clamp(0, n - 1)


def correct_lens(
    image: torch.Tensor, params: LensParams | dict, padding: str = "zeros"
) -> torch.Tensor:
    """Take the lens of ``params`` (a :class:`~rawsim.io.lensfun.LensParams` or its dict)
    out of ``image`` (B, 3, H, W), linear camera RGB of the whole frame (or grey, (B, 1,
    H, W)): distortion, TCA and vignetting, as lensfun corrects them. Where the lens
    saw nothing (pincushion corners): ``padding``, black by default."""
    _check(image)
    return remap_lens(image, lens_field(params, *image.shape[-2:]), padding)


def add_lens(
    image: torch.Tensor, params: LensParams | dict, padding: str = "reflect"
) -> torch.Tensor:
    """Give ``image`` (B, 3, H, W), clean linear RGB of the whole frame (or grey, (B, 1,
    H, W)), the distortion, TCA and vignetting of the lens of ``params``: what the lens
    would have made of the scene (:func:`correct_lens` undoes it, up to resampling).
    Where the lens would see beyond the image (barrel corners): ``padding``, mirrored
    by default."""
    _check(image)
    return remap_lens(image, lens_field(params, *image.shape[-2:], reverse=True), padding)


class LensCorrection(nn.Module):
    """Lens-correction stage: ``forward`` corrects the lens, ``reverse`` adds it.

    ``params``: the lens (:class:`~rawsim.io.lensfun.LensParams` or its dict), or None
    for a raw whose lens is unknown: then both directions return the image as it is.
    ``padding``: what the correction samples outside the image (black by default);
    ``reverse`` mirrors, as :func:`add_lens`. The field follows the input's size (a
    half-size render gets its own).
    """

    def __init__(self, params: LensParams | dict | None, padding: str = "zeros") -> None:
        super().__init__()
        self.params = None if params is None else LensParams.of(params)
        self.padding = check_choice("padding", padding, PADDINGS)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x if self.params is None else correct_lens(x, self.params, self.padding)

    def reverse(self, x: torch.Tensor) -> torch.Tensor:
        return x if self.params is None else add_lens(x, self.params)


def correct_mosaic_tca(mosaic: torch.Tensor, cfa: CFA, params: LensParams | dict) -> torch.Tensor:
    """Take the lateral CA of ``params``'s lens out of ``mosaic`` (B, 1, H, W), linear
    values of a Bayer ``cfa``: each red and blue site is resampled on its colour's own
    plane (a quarter of the sites; Lanczos-3, mirrored at the edges) where lensfun's
    TCA puts that colour relative to green (:func:`~rawsim.io.lensfun.mosaic_tca_fields`);
    green sites are kept. Returns a new tensor of the mosaic's shape and dtype;
    differentiable in the mosaic."""
    check_image(mosaic, "mosaic")
    if mosaic.shape[1] != 1 or not cfa.is_bayer:
        raise ParameterError(
            f"lateral CA on the mosaic takes a Bayer mosaic (B, 1, H, W), got shape "
            f"{tuple(mosaic.shape)} of a {cfa.pattern} pattern"
        )
    out = mosaic.clone()
    for oy, ox, field in mosaic_tca_fields(params, cfa.colors, *mosaic.shape[-2:]):
        out[..., oy::2, ox::2] = remap_lens(mosaic[..., oy::2, ox::2], field, "reflect")
    return out


class MosaicTca(nn.Module):
    """The lens stage's lateral CA, corrected on a Bayer mosaic just before the demosaic
    (:func:`correct_mosaic_tca`); ``params`` the lens's record (a dict)."""

    def __init__(self, cfa: CFA, params: LensParams | dict) -> None:
        super().__init__()
        self.cfa = cfa
        self.params = LensParams.of(params)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return correct_mosaic_tca(x, self.cfa, self.params)
