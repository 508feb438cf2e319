"""Profiled denoising of a raw mosaic (torch reference): the noise model drives a
variance-stabilising transform, then collaborative shrinkage in the DCT domain.

The method, on a mosaic normalised so that black is 0 and white 1:

1. **Planes.** A Bayer mosaic is read as its four colour planes (R, G, G, B: half
   size each, :attr:`~rawsim.cfa.CFA.packed_sites`); any other pattern (X-Trans …)
   as one plane, the mosaic itself.
2. **Variance stabilisation.** Each site's value x, of variance ``gain·x + offset``
   for its colour (the noise model, :mod:`rawsim.denoise.noise_model`), goes
   through the generalised Anscombe transform
   2·√(x/gain + 3/8 + offset/gain²), after which the noise is close to Gaussian
   of σ 1 at every level.
3. **Colour decorrelation.** Bayer planes are mixed by an orthonormal 4×4
   transform (:data:`~rawsim.denoise.layout.BAYER_MIX`: their mean, the two
   chroma differences, the green split), which keeps the noise white with σ 1
   and puts most of the signal in one channel; then each channel is filtered on
   its own. A one-plane mosaic (X-Trans) has its colour pattern taken out
   (:func:`colour_modulation`: each site's colour's mean over the period around
   it, less the mean of all its colours), which the patches would otherwise keep
   as detail, with the noise in it; it is put back before step 5.
4. **Two passes of sliding 8×8 DCT shrinkage** (Yu & Sapiro, "DCT image
   denoising: a simple and effective image denoising algorithm", IPOL 2011; the
   second, Wiener pass as in BM3D's, without block matching): patches start every
   ``STEP`` plane pixels (on the grid −7 + 2k) over the planes mirrored at
   their edges. Pass one keeps the coefficients above ``threshold``·σ and averages
   the patches back, each weighted by 1 / its kept coefficients. Pass two shrinks
   the noisy coefficients by the Wiener factor P² / (P² + σ²) of the first
   estimate's P, weighted by 1 / Σ factor². Both keep the DC coefficient whole:
   shrinking it would pull a patch's weak colour towards grey. σ is 1 × ``strength``.
5. **Back:** the inverse mix, then the exact unbiased inverse of the transform
   (:mod:`rawsim.denoise.vst`; Mäkitalo & Foi, "Optimal inversion of the
   generalized Anscombe transformation for Poisson-Gaussian noise", IEEE TIP
   22(1), 2013), which returns the mean, not the median, of the signal. Sites at or above white
   (clipped: no noise to remove) and sites outside the planes (an odd last row or
   column of a Bayer mosaic) keep their values.

The planes are worked through in chunks of rows (``CHUNK``), each reading the
rows it needs around it; a chunk's result does not depend on the chunking, so
memory stays flat and the compiled engine (:mod:`rawsim.engine.denoise`, which
computes the same in float32) can split the work as it likes. Domain: any real
values (values below black stay below black when they are the mean); range: the
denoised values, not clipped except at 0 in the transform's domain. Gradients
flow through every step but the threshold's choice of coefficients.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from rawsim.cfa import CFA
from rawsim.denoise.layout import (
    CHUNK,
    PATCH,
    REACH,
    STEP,
    THRESHOLD,
    large_enough,
    modulation_pads,
    plane_layout,
    plane_shape,
)
from rawsim.denoise.vst import tables


def forward_vst(x: torch.Tensor, gain, offset) -> torch.Tensor:
    """The generalised Anscombe transform of ``x`` (variance ``gain·x + offset``)."""
    return 2 * (x / gain + 0.375 + offset / (gain * gain)).clamp_min(0).sqrt()


def inverse_vst(d: torch.Tensor, gain: float, offset: float) -> torch.Tensor:
    """The exact unbiased inverse of :func:`forward_vst` (:mod:`rawsim.denoise.vst`):
    the mean x whose transform's expectation is ``d``; ≥ 0. One colour's model."""
    td, tx = (torch.as_tensor(t, dtype=d.dtype, device=d.device) for t in tables([gain], [offset]))
    td, tx = td[0], tx[0]
    i = torch.searchsorted(td, d.detach().contiguous()).clamp(1, td.numel() - 1)
    lo, hi = td[i - 1], td[i]
    w = ((d - lo) / (hi - lo)).clamp(0, 1)
    table = tx[i - 1] + w * (tx[i] - tx[i - 1])
    c = d.clamp_min(1.0)
    r = math.sqrt(1.5)
    closed = 0.25 * c * c + 0.25 * r / c - 1.375 / (c * c) + 0.625 * r / c**3 - 0.125
    closed = (closed - offset / gain**2).clamp_min(0) * gain
    return torch.where(d > td[-1], closed, table)


def _basis(device, dtype) -> torch.Tensor:
    k = torch.arange(PATCH, dtype=torch.float64)[:, None]
    j = torch.arange(PATCH, dtype=torch.float64)[None]
    b = torch.cos(math.pi * (2 * j + 1) * k / (2 * PATCH)) * math.sqrt(2 / PATCH)
    b[0] /= math.sqrt(2)
    return b.to(device, dtype)


def _reflect(i: torch.Tensor, n: int) -> torch.Tensor:
    """Indices mirrored into [0, n) without repeating the edge."""
    i = i.abs()
    return torch.where(i >= n, 2 * (n - 1) - i, i)


def _patches(buf: torch.Tensor) -> torch.Tensor:
    """(C, rows, cols) → every STEP-th 8×8 patch: (C, nr, nc, 8, 8)."""
    return buf.unfold(1, PATCH, STEP).unfold(2, PATCH, STEP)


def _unpatch(p: torch.Tensor, rows: int, cols: int) -> torch.Tensor:
    """The sum of patches (C, nr, nc, 8, 8) laid back where :func:`_patches` took them."""
    c, nr, nc = p.shape[:3]
    cols_ = p.permute(0, 3, 4, 1, 2).reshape(c, PATCH * PATCH, nr * nc)
    return F.fold(cols_, (rows, cols), PATCH, stride=STEP)[:, 0]


def _pass(noisy, n0, pilot, a, lo, hi, hp, sigma, threshold, basis):
    """One pass over the patches touching plane rows [lo, hi): (num, den) (C, hi − lo, wp).
    Arguments as :func:`rawsim.engine.denoise._pass`'s; ``pilot`` None for the first."""
    wp = noisy.shape[2] - 2 * REACH
    first = lo - REACH + lo % STEP
    last = first + (hi - 1 - first) // STEP * STEP
    rows = last - first + PATCH
    t = basis @ _patches(noisy[:, first - n0 : first - n0 + rows]) @ basis.T
    if pilot is None:
        keep = t.abs() > threshold * sigma
        keep[..., 0, 0] = True
        t = t * keep
        weight = 1 / keep.sum((-2, -1)).to(t.dtype)
    else:
        prow = _reflect(torch.arange(first, first + rows), hp) - a
        pcol = _reflect(torch.arange(-REACH, wp + REACH), wp)
        q = basis @ _patches(pilot[:, prow][:, :, pcol]) @ basis.T
        f = q * q / (q * q + sigma * sigma)
        f[..., 0, 0] = 1  # the DC kept whole
        t = t * f
        weight = 1 / (f * f).sum((-2, -1))
    back = basis.T @ t @ basis * weight[..., None, None]
    ones = weight[..., None, None].expand_as(back)
    cut = (slice(None), slice(lo - first, hi - first), slice(REACH, REACH + wp))
    size = (rows, wp + 2 * REACH)
    return _unpatch(back, *size)[cut], _unpatch(ones, *size)[cut]


def colour_modulation(y: torch.Tensor, cfa: CFA) -> torch.Tensor:
    """The CFA's colour pattern in the transformed mosaic ``y`` (H, W) of a one-plane
    layout (X-Trans …): at each site, the mean of ``y`` over the sites of its colour
    in the period-sized box around it, less the mean of every site in that box
    (:func:`~rawsim.denoise.layout.modulation_pads`; the mosaic mirrored at its
    edges without repeating them). Taken out before the patches, which would keep
    the pattern as detail and the noise with it, and put back after (its own noise,
    a mean of 8 or more sites, stays). The engine's form:
    :func:`rawsim.engine.denoise.colour_pattern`."""
    top, bottom, left, right = modulation_pads(cfa)
    ph, pw = cfa.period
    h, w = y.shape
    colors = torch.as_tensor(cfa.colors, device=y.device).reshape(ph, pw)
    colours = colors.repeat(-(-h // ph), -(-w // pw))[:h, :w]

    def box(a: torch.Tensor) -> torch.Tensor:
        a = F.pad(a[None, None], (left, right, top, bottom), mode="reflect")
        return F.avg_pool2d(a, (ph, pw), stride=1)[0, 0]

    out = -box(y)
    for c in colours.unique().tolist():
        mask = (colours == c).to(y.dtype)
        count = box(mask).clamp_min(0.5 / (ph * pw))  # never 0 where a site reads it
        out = out + torch.where(colours == c, box(y * mask) / count, 0.0)
    return out


def profiled_denoise(
    x: torch.Tensor,
    cfa: CFA,
    gain,
    offset,
    strength: float = 1.0,
    threshold: float = THRESHOLD,
    chunk: int = CHUNK,
) -> torch.Tensor:
    """Denoise a mosaic ``x`` (B, 1, H, W) of ``cfa``, normalised (white = 1), whose
    noise variance is ``gain[c]·x + offset[c]`` for colour c (R, G, B; 3 numbers
    each). Returns the same shape (see the module doc). Planes smaller than
    ``PATCH`` a side are returned as they are."""
    if not large_enough(tuple(x.shape[-2:]), cfa):
        return x
    offsets, step, mix = plane_layout(cfa)
    hp, wp = plane_shape(tuple(x.shape[-2:]), cfa)
    dev, dt = x.device, x.dtype
    colors = torch.as_tensor(cfa.colors, device=dev).reshape(cfa.period)
    gains = torch.as_tensor(gain, dtype=dt, device=dev)
    offs = torch.as_tensor(offset, dtype=dt, device=dev)
    mix_t, basis = torch.as_tensor(mix, device=dev, dtype=dt), _basis(dev, dt)
    ph, pw = cfa.period
    sites = []  # each plane's rows and columns in the mosaic
    for oy, ox in offsets:
        sites.append(
            (oy + step * torch.arange(hp, device=dev), ox + step * torch.arange(wp, device=dev))
        )
    col = torch.stack([colors[ys % ph][:, xs % pw] for ys, xs in sites])  # (C, hp, wp)
    g, o = gains[col], offs[col]
    out = x.clone()
    for n in range(x.shape[0]):
        planes = torch.stack([x[n, 0][ys][:, xs] for ys, xs in sites])
        y = torch.einsum("cd,dhw->chw", mix_t, forward_vst(planes, g, o))
        pattern = None if cfa.is_bayer else colour_modulation(y[0], cfa)
        if pattern is not None:
            y = y - pattern
        result = []
        for r0 in range(0, hp, chunk):
            r1 = min(hp, r0 + chunk)
            a, b = max(0, r0 - REACH), min(hp, r1 + REACH)
            rows = _reflect(torch.arange(a - REACH, b + REACH, device=dev), hp)
            cols = _reflect(torch.arange(-REACH, wp + REACH, device=dev), wp)
            noisy = y[:, rows][:, :, cols]
            num, den = _pass(noisy, a - REACH, None, a, a, b, hp, strength, threshold, basis)
            e1 = num / den
            num, den = _pass(noisy, a - REACH, e1, a, r0, r1, hp, strength, threshold, basis)
            result.append(num / den)
        est = torch.einsum("dc,dhw->chw", mix_t, torch.cat(result, 1))
        if pattern is not None:
            est = est + pattern
        denoised = torch.empty_like(est)
        for c in col.unique().tolist():  # each colour's sites, through its own inverse
            sel = col == c
            denoised[sel] = inverse_vst(est[sel], float(gain[c]), float(offset[c]))
        for k, (ys, xs) in enumerate(sites):
            old = planes[k]
            out[n, 0, ys[:, None], xs[None]] = torch.where(old >= 1, old, denoised[k])
    return out
