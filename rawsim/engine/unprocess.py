"""The fused unprocess kernel: display or linear RGB → noisy (and clean) mosaic codes.

One pass per row, parallel over rows (two passes through a lens, which moves
pixels: :func:`lens_camera`): decode (lookup table of the display
transform, or linear floats) → exposure and brightness → seed matrix bias →
sRGB → camera matrix → inverse white balance (exact or Brooks's safe one) →
mosaic (only the site's channel is kept) → vignetting → levels → noise →
rounding and saturation → uint16. The torch reference of each stage is in
:mod:`rawsim.sensors` and :mod:`rawsim.isp`; the noise is
:func:`rawsim.noise.models.noise_field`, drawn here by :func:`noise_row` from the same
counter-based generator, bit for bit. Arithmetic is float64 (the reference runs
in float32), so the clean codes agree with the reference within one code.

Any periodic CFA (2×2 Bayer, 6×6 X-Trans, …): the colour and the channel bias of
each site come from one period's tiles, laid along the rows once per image
(:func:`site_rows`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rawsim.engine import configure
from rawsim.noise.kernels import (
    ROW,
    normal,
    normal_row,
    poisson_sites,
    poisson_words,
    tukey_lambda_row,
    tukey_table,
)
from rawsim.noise.poisson_table import EXACT_POISSON_BELOW

configure()

#: Compiled once, cached; the numpy error model (no zero-division checks, whose early
#: exits would keep LLVM from vectorising the row loops).
_JIT = {"cache": True, "error_model": "numpy"}
#: Noise model codes of the kernels.
MODEL_CODES = {"none": 0, "gaussian": 1, "poisson-gaussian": 2, "physics": 3}
#: Layout of the float64 noise-parameter vector (see :func:`noise_vector`).
N_BLACK, N_GAIN, N_READ, N_ALPHA, N_BETA, N_ISO_GAIN, N_ROW = range(7)
#: The physics model's dark terms: ISO, the dark-shading crop's first row and column,
#: the black-level offset (DN).
N_DARK_ISO, N_DARK_TOP, N_DARK_LEFT, N_DARK_OFFSET = range(7, 11)


def noise_vector(levels, black: float, dark=None) -> np.ndarray:
    """The kernel's noise parameters from :class:`~rawsim.noise.models.NoiseLevels` and
    the file's :class:`~rawsim.noise.models.DarkDraw` (None: no dark terms)."""
    return np.array(
        [
            black,
            levels.gain or 0.0,
            levels.read_sigma,
            levels.shot_alpha,
            levels.shot_beta,
            levels.iso_gain,
            levels.row_sigma,
            levels.iso,
            0 if dark is None else dark.top,
            0 if dark is None else dark.left,
            0.0 if dark is None else dark.offset,
        ],
        dtype=np.float64,
    )


def dark_maps(levels, dark) -> tuple[np.ndarray, np.ndarray]:
    """The whole dark-shading maps (k, b) float32 of the levels' gain range, as
    :func:`noise_row` takes them: empty (0, 0) where ``dark`` (the file's
    :class:`~rawsim.noise.models.DarkDraw`) is None or has no map."""
    if dark is None or levels.dark_shading is None:
        empty = np.zeros((0, 0), np.float32)
        return empty, empty
    return levels.dark_shading.maps(levels.iso)


def noise_tables(levels) -> tuple[np.ndarray, np.ndarray]:
    """The noise model's tables, as :func:`noise_row` takes them: ``tukey``, the
    physics model's Tukey-lambda quantile table (:func:`tukey_table` of the levels'
    λ), and ``poisson``, the exact Poisson draws' alias tables
    (:func:`poisson_words`); empty arrays where the model draws neither."""
    tukey = tukey_table(levels.tukey_lambda) if levels.model == "physics" else np.zeros((0, 4))
    shot = levels.model in ("poisson-gaussian", "physics")
    return tukey, poisson_words() if shot else np.zeros(0, np.uint64)


@njit(**_JIT)
def site_rows(tile, width):
    """A (ph, pw) per-site tile (one CFA period) laid along rows ``width`` wide:
    (ph, width), entry [i, x] = tile[i, x % pw]; row y of an image reads entry
    ``y % ph``. Built once per image, so the row loops read one value per site
    (no division) for any period."""
    ph, pw = tile.shape
    out = np.empty((ph, width), tile.dtype)
    for i in range(ph):
        for x in range(width):
            out[i, x] = tile[i, x % pw]
    return out


@njit(**_JIT)
def noise_row(
    dn, y, width, model, p, tukey, poisson, k0, k1, bias_rows, dark_k, dark_b, white, out
):
    """Noise, rounding and saturation of row ``y`` of clean float64 DN ``dn`` (w,)
    into codes ``out`` (w,), with ``tukey``, ``poisson`` the model's
    :func:`noise_tables`, ``bias_rows`` the channel bias of each site
    (:func:`site_rows` of the (ph, pw) bias tile) and ``dark_k``, ``dark_b`` the
    whole dark-shading maps (:func:`dark_maps`; ``p`` places the crop): the compiled
    :meth:`~rawsim.sensors.ProfileSensor.simu_noise`, bit for bit (the reference's
    ``noise_field``: same operations, same order).

    Model 0 (``none``) gives the clean codes. The draws and the arithmetic run as
    whole-row loops without branches, which LLVM vectorises; only the table reads
    (Tukey-lambda's, and the exact Poisson draws' of dark sites) run site by site.
    """
    w = dn.shape[0]
    noise = np.zeros(w) if model == 0 else np.empty(w)  # the models write every site
    if model != 0:
        first = np.uint64(y) * np.uint64(width)
        z = np.empty(w)
        normal_row(first, k0, k1, z)
        black, read = p[N_BLACK], p[N_READ]
        if model == 1:
            alpha, beta, iso_gain = p[N_ALPHA], p[N_BETA], p[N_ISO_GAIN]
            for x in range(w):
                shot = alpha * math.sqrt(max(dn[x] - black, 0.0)) + beta
                noise[x] = math.sqrt(iso_gain * (shot * shot) + read * read) * z[x]
        else:
            _shot_noise(dn, first, model == 3, p, poisson, k0, k1, z, noise)
        if model == 3:
            bias = bias_rows[y % bias_rows.shape[0]]
            _physics_read_noise(y, first, p, tukey, k0, k1, bias, noise)
            _dark_terms(y, p, dark_k, dark_b, noise)
    for x in range(w):
        out[x] = min(max(np.rint(dn[x] + noise[x]), 0.0), white)


@njit(**_JIT)
def _shot_noise(dn, first, physics, p, poisson, k0, k1, z, noise):
    """Shot noise (joined with Gaussian read noise unless ``physics``) into ``noise``:
    a normal of variance K·s + σ² everywhere, then exact Poisson where s is above 0
    and below :data:`EXACT_POISSON_BELOW` electrons (at s = 0 both are 0: the
    normal's term is σ·z, as the Poisson's would be)."""
    black, k, read = p[N_BLACK], p[N_GAIN], p[N_READ]
    read_var = 0.0 if physics else read * read
    for x in range(dn.shape[0]):
        noise[x] = math.sqrt(k * max(dn[x] - black, 0.0) + read_var) * z[x]
    limit = EXACT_POISSON_BELOW * k
    marks = _marks(dn.shape[0])
    n = 0
    for x in range(dn.shape[0]):
        marks[x] = (dn[x] - black < limit) & (dn[x] - black > 0.0)
        n += marks[x]
    if n == 0:
        return
    at = np.empty(n + 1, np.intp)
    _marked(marks, at)
    lam, sites, counts = np.empty(n), np.empty(n, np.uint64), np.empty(n)
    for i in range(n):
        lam[i] = max(dn[at[i]] - black, 0.0) / k
        sites[i] = first + np.uint64(at[i])
    poisson_sites(lam, sites, k0, k1, poisson, counts)
    for i in range(n):
        x = at[i]
        positive = max(dn[x] - black, 0.0)
        shot = k * counts[i] - positive
        noise[x] = shot if physics else shot + read * z[x]


@njit(inline="always")
def _marks(n):
    """Marks for ``n`` sites, uint8, to be set 0 or 1 by the caller: rounded up to
    whole words of eight, the padding 0, for :func:`_marked`."""
    marks = np.empty((n + 7) // 8 * 8, np.uint8)
    marks[n:] = 0
    return marks


@njit(**_JIT)
def _marked(marks, at):
    """The positions of the marked sites of ``marks`` (:func:`_marks`) into ``at``
    (at least their count + 1 long), in order; returns their count.

    Eight marks are read as one word, so a run of unmarked sites costs a test a
    word; the positions are gathered without branches only in words that have
    marks. A branch-free gather over every site took 0.54 ns a site (one core),
    a third of the shot noise's time on a photo."""
    words = marks.view(np.uint64)
    n = 0
    for k in range(words.size):
        if words[k] != 0:
            for x in range(8 * k, 8 * k + 8):
                at[n] = x
                n += marks[x]
    return n


@njit(**_JIT)
def _physics_read_noise(y, first, p, tukey, k0, k1, bias, noise):
    """The physics model's Tukey-lambda read noise, row noise and channel bias
    (``bias``: (w,), each site's of the row), added to ``noise``."""
    t = np.empty(noise.size)
    tukey_lambda_row(first, k0, k1, tukey, t)
    read = p[N_READ]
    row_noise = p[N_ROW] * normal(np.uint64(y), ROW, k0, k1)
    for x in range(noise.size):
        v = (noise[x] + read * t[x]) + row_noise
        noise[x] = v + bias[x]


@njit(**_JIT)
def _dark_terms(y, p, dark_k, dark_b, noise):
    """The physics model's dark terms of row ``y``, added to ``noise``: dark shading
    ``(k · ISO + b) + offset`` over the crop of the maps, or the black-level offset
    alone without maps (the reference's ``dark_field``)."""
    offset = p[N_DARK_OFFSET]
    if dark_k.shape[0] > 0:
        iso, row, left = p[N_DARK_ISO], int(p[N_DARK_TOP]) + y, int(p[N_DARK_LEFT])
        for x in range(noise.size):
            shade = np.float64(dark_k[row, left + x]) * iso + np.float64(dark_b[row, left + x])
            noise[x] = noise[x] + (shade + offset)
    elif offset != 0.0:
        for x in range(noise.size):
            noise[x] = noise[x] + offset


@njit(**_JIT)
def add_noise_rows(
    dn, top, width, model, p, tukey, poisson, k0, k1, bias_tile, dark_k, dark_b, white, out
):
    """:func:`noise_row` over clean rows ``dn`` (h, w) float32, rows ``top`` on of an
    image ``width`` wide, into ``out`` (h, w), with ``bias_tile`` the (ph, pw) channel
    bias of one CFA period; for the equality tests."""
    bias_rows = site_rows(bias_tile, width)
    noise = (model, p, tukey, poisson, k0, k1, bias_rows, dark_k, dark_b, white)
    for y in range(dn.shape[0]):
        noise_row(dn[y].astype(np.float64), top + y, width, *noise, out[y])


@njit(**_JIT)
def _code_tables(lut, scale, ccm_bias):
    """(3, codes) float64: the linear value of each code in each channel,
    ``lut[code] · scale − ccm_bias[channel]``, the arithmetic :func:`_linear_row`
    would do at every site (so the same bits); (3, 0) without ``lut``."""
    tables = np.empty((3, lut.shape[0]))
    for k in range(3):
        for code in range(lut.shape[0]):
            tables[k, code] = np.float64(lut[code]) * scale - ccm_bias[k]
    return tables


@njit(**_JIT)
def _linear_row(pixels, tables, scale, ccm_bias, r, g, b):
    """Linear RGB of one row of ``pixels`` (w, 3) into ``r``, ``g``, ``b`` (w,) float64:
    codes through ``tables`` (:func:`_code_tables`: one load a value), or floats
    times ``scale``, less ``ccm_bias``."""
    if tables.shape[1] > 0:
        for x in range(r.size):
            r[x] = tables[0, np.intp(pixels[x, 0])]
            g[x] = tables[1, np.intp(pixels[x, 1])]
            b[x] = tables[2, np.intp(pixels[x, 2])]
        return
    bias_r, bias_g, bias_b = ccm_bias[0], ccm_bias[1], ccm_bias[2]
    for x in range(r.size):
        vr, vg, vb = np.float64(pixels[x, 0]), np.float64(pixels[x, 1]), np.float64(pixels[x, 2])
        r[x], g[x], b[x] = vr * scale - bias_r, vg * scale - bias_g, vb * scale - bias_b


@njit(**_JIT)
def _camera_row(r, g, b, colors, matrix, wb, safe, threshold, out):
    """Each site's camera channel, white balance inverted, into ``out`` (w,): the
    channel of column x is ``colors[x]`` (the row of :func:`site_rows` of the CFA's
    colours). Brooks's safe inverse blends above ``threshold`` of the grey level.

    Below the threshold the safe inverse's blend term is exactly 0 and a site is
    ``v · (1 / gain)``, so the safe inverse runs without a division: that product
    at every site (a loop LLVM vectorises), marking the sites whose channel sum
    could reach the threshold; then the whole formula at those (:func:`_marked`; a
    photo's highlights are a few percent of its sites). The same bits as the
    formula everywhere; the three divisions a site were a third of the colour's
    time (0.66 → 0.41 ns a site on one core)."""
    m = matrix
    w = r.size
    if not safe:
        for x in range(w):
            c = colors[x]
            out[x] = _camera_channel(m, c, r[x], g[x], b[x])[0] / wb[c]
        return
    inv0, inv1, inv2 = 1.0 / wb[0], 1.0 / wb[1], 1.0 / wb[2]
    # total < bound (as reals, total < 3·threshold): grey = total / 3 ≤ threshold, rounded.
    bound = 3.0 * threshold - abs(threshold) * 2.0**-28
    marks = _marks(w)
    near = 0
    for x in range(w):
        c = colors[x]
        v, total = _camera_channel(m, c, r[x], g[x], b[x])
        out[x] = v * (inv0 if c == 0 else (inv1 if c == 1 else inv2))
        marks[x] = total >= bound
        near += marks[x]
    if near == 0:
        return
    at = np.empty(near + 1, np.intp)
    for i in range(_marked(marks, at)):
        x = at[i]
        c = colors[x]
        v, total = _camera_channel(m, c, r[x], g[x], b[x])
        inv = 1.0 / wb[c]
        t = max(total / 3.0 - threshold, 0.0) / (1.0 - threshold)
        out[x] = v * (inv + t * t * max(1.0 - inv, 0.0))


@njit(inline="always")
def _camera_channel(m, c, r, g, b):
    """(camera channel ``c`` of linear sRGB (r, g, b) through ``m``, the sum of the
    three camera channels): all three are computed, then the one selected."""
    cam0 = m[0, 0] * r + m[0, 1] * g + m[0, 2] * b
    cam1 = m[1, 0] * r + m[1, 1] * g + m[1, 2] * b
    cam2 = m[2, 0] * r + m[2, 1] * g + m[2, 2] * b
    return (cam0 if c == 0 else (cam1 if c == 1 else cam2)), cam0 + cam1 + cam2


@njit(parallel=True, **_JIT)
def camera_kernel(pixels, lut, scale, ccm_bias, matrix, mono, out):
    """The stages before the inverse white balance, for a lens's whole-image pass:
    ``pixels`` as :func:`unprocess_kernel` takes them (with ``lut``, ``scale``,
    ``ccm_bias``) → white-balanced camera RGB (sRGB → camera ``matrix``) into ``out``
    (H, W, 3) float32; for ``mono`` the grey (mean of linear R, G, B) in all three."""
    h, w = out.shape[0], out.shape[1]
    m = matrix
    tables = _code_tables(lut, scale, ccm_bias)
    for y in prange(h):
        r, g, b = np.empty(w), np.empty(w), np.empty(w)
        _linear_row(pixels[y], tables, scale, ccm_bias, r, g, b)
        for x in range(w):
            if mono:
                grey = (r[x] + g[x] + b[x]) / 3.0
                out[y, x, 0], out[y, x, 1], out[y, x, 2] = grey, grey, grey
            else:
                out[y, x, 0] = m[0, 0] * r[x] + m[0, 1] * g[x] + m[0, 2] * b[x]
                out[y, x, 1] = m[1, 0] * r[x] + m[1, 1] * g[x] + m[1, 2] * b[x]
                out[y, x, 2] = m[2, 0] * r[x] + m[2, 1] * g[x] + m[2, 2] * b[x]


def lens_camera(pixels, lut, scale, ccm_bias, matrix, mono, lens) -> np.ndarray:
    """A capture through ``lens`` (:class:`~rawsim.io.lensfun.LensParams`), first part:
    :func:`camera_kernel` on the whole image, then the lens added by
    :func:`rawsim.engine.lens.add_lens` (it samples anywhere in the frame, so this
    pass ends before the per-row kernel starts). Returns (H, W, 3) float32, which
    :func:`unprocess_kernel` takes as linear floats with scale 1, no bias and the
    identity matrix (each channel unchanged, exactly); for ``mono``, the green
    channel's remap in all three channels (their mean is it, exactly)."""
    from rawsim.engine.lens import add_lens

    h, w = pixels.shape[:2]
    camera = np.empty((h, w, 3), np.float32)
    camera_kernel(pixels, lut, scale, ccm_bias, matrix, mono, camera)
    out = add_lens(camera, lens)
    if mono:
        out[:] = out[:, :, 1:2]
    return out


@njit(**_JIT)
def _vignetting_row(y, cy, cx, norm, vignetting, v):
    """Lens shading of row ``y`` applied to ``v`` (w,): divided by the radial gain."""
    strength, k1, k2, k3 = vignetting[0], vignetting[1], vignetting[2], vignetting[3]
    for x in range(v.size):
        r2 = ((y - cy) ** 2 + (x - cx) ** 2) / norm
        gain = 1.0 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        v[x] = v[x] / (1.0 + strength * (gain - 1.0))


@njit(parallel=True, **_JIT)
def unprocess_kernel(
    pixels,
    lut,
    scale,
    ccm_bias,
    matrix,
    wb,
    safe,
    threshold,
    mono,
    colors,
    vignetting,
    levels,
    model,
    p,
    tukey,
    poisson,
    k0,
    k1,
    bias_tile,
    dark_k,
    dark_b,
    top,
    height,
    noisy,
    clean,
):
    """The whole unprocess chain for rows ``top`` to ``top + n`` of an (``height``, W, 3)
    image, into ``noisy`` (n, W): the whole image, or a band of it (the rows
    decoded so far), the same bits either way.

    Args:
        pixels: (n, W, 3), the band's rows, any strides (a channels-first tensor's
            view, a crop), integer codes (with ``lut``) or float32 linear values
            (``lut`` empty).
        lut: float32 linear value of each code (the reference's table).
        scale: 2^EV / brightness. ``ccm_bias``: (3,) subtracted first.
        matrix: (3, 3) sRGB → camera. ``wb``: (3,) white-balance gains.
        safe: Brooks's highlight-preserving inverse, blending above ``threshold``.
        mono: grey sensor (mean of RGB; no matrix or white balance).
        colors: (ph, pw) colour index (R=0, G=1, B=2) of each site of one CFA
            period, laid from the top-left pixel: 2×2 Bayer, 6×6 X-Trans, any period.
        vignetting: (strength, k1, k2, k3); no shading when strength is 0.
        levels: (black, white) DN.
        model, p, tukey, poisson, k0, k1: the noise (see :func:`noise_row`).
        bias_tile: (ph, pw) channel bias (DN) of each site of one period (physics model).
        dark_k, dark_b: the dark-shading maps (:func:`dark_maps`; physics model).
        top, height: the band's first row in the image, and the image's rows.
        noisy, clean: (n, W) uint16 or float32 outputs (the same whole codes);
            ``clean`` is written if it has rows.
    """
    n, w = noisy.shape
    black, white = levels[0], levels[1]
    span = white - black
    want_clean = clean.shape[0] > 0
    strength = vignetting[0]
    cy, cx = (height - 1) / 2.0, (w - 1) / 2.0
    norm = cy * cy + cx * cx
    site_colors, bias_rows = site_rows(colors, w), site_rows(bias_tile, w)
    period = site_colors.shape[0]
    tables = _code_tables(lut, scale, ccm_bias)
    for i in prange(n):
        y = top + i  # the row in the image: its CFA row, shading, noise counters
        r, g, b, dn = np.empty(w), np.empty(w), np.empty(w), np.empty(w)
        _linear_row(pixels[i], tables, scale, ccm_bias, r, g, b)
        if mono:
            for x in range(w):
                dn[x] = (r[x] + g[x] + b[x]) / 3.0
        else:
            _camera_row(r, g, b, site_colors[y % period], matrix, wb, safe, threshold, dn)
        if strength > 0.0:
            _vignetting_row(y, cy, cx, norm, vignetting, dn)
        for x in range(w):
            dn[x] = black + dn[x] * span
        noise = (p, tukey, poisson, k0, k1, bias_rows, dark_k, dark_b, white)
        if want_clean:
            noise_row(dn, y, w, 0, *noise, clean[i])
        noise_row(dn, y, w, model, *noise, noisy[i])
