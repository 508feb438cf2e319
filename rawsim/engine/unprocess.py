"""The fused unprocess kernel: display or linear RGB → noisy (and clean) mosaic codes.

One pass per row, parallel over rows: decode (lookup table of the display
transform, or linear floats) → exposure and brightness → seed matrix bias →
sRGB → camera matrix → inverse white balance (exact or Brooks's safe one) →
mosaic (only the site's channel is kept) → vignetting → levels → noise →
rounding and saturation → uint16. The torch reference of each stage is in
:mod:`rawsim.sensors` and :mod:`rawsim.isp`; the noise is
:func:`rawsim.noise.noise_field`, drawn here by :func:`site_noise` from the same
counter-based generator, bit for bit. Arithmetic is float64 (the reference runs
in float32), so the clean codes agree with the reference within one code.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rawsim.engine import configure
from rawsim.engine.counter_rng import NORMAL, ROW, normal, poisson, tukey_lambda
from rawsim.noise import EXACT_POISSON_BELOW

configure()

#: Noise model codes of the kernels.
MODEL_CODES = {"none": 0, "gaussian": 1, "poisson-gaussian": 2, "physics": 3}
#: Layout of the float64 noise-parameter vector (see :func:`noise_vector`).
N_BLACK, N_GAIN, N_READ, N_ALPHA, N_BETA, N_ISO_GAIN, N_LAMBDA, N_ROW = range(8)


def noise_vector(levels, black: float) -> np.ndarray:
    """The kernel's noise parameters from :class:`~rawsim.noise.NoiseLevels`."""
    return np.array(
        [
            black,
            levels.gain or 0.0,
            levels.read_sigma,
            levels.shot_alpha,
            levels.shot_beta,
            levels.iso_gain,
            levels.tukey_lambda,
            levels.row_sigma,
        ],
        dtype=np.float64,
    )


@njit(cache=True)
def site_noise(dn, site, model, p, k0, k1, row_noise, bias):
    """The noise added to clean ``dn`` at ``site`` (the reference's ``noise_field``).

    ``row_noise`` is the row's σ_row·N draw and ``bias`` the site's channel bias
    (physics only). Operations and their order follow the reference exactly.
    """
    positive = max(dn - p[N_BLACK], 0.0)
    z = normal(site, NORMAL, k0, k1)
    if model == 1:
        shot = p[N_ALPHA] * math.sqrt(positive) + p[N_BETA]
        return math.sqrt(p[N_ISO_GAIN] * (shot * shot) + p[N_READ] * p[N_READ]) * z
    k = p[N_GAIN]
    physics = model == 3
    read_var = 0.0 if physics else p[N_READ] * p[N_READ]
    if positive < EXACT_POISSON_BELOW * k:
        shot = k * poisson(positive / k, site, k0, k1) - positive
        noise = shot if physics else shot + p[N_READ] * z
    else:
        noise = math.sqrt(k * positive + read_var) * z
    if not physics:
        return noise
    t = tukey_lambda(site, k0, k1, p[N_LAMBDA])
    noise = noise + p[N_READ] * t
    noise = noise + row_noise
    return noise + bias


@njit(cache=True)
def noise_row(dn, y, width, model, p, k0, k1, bias_tile, white, out):
    """Noise, rounding and saturation of row ``y`` of clean float64 DN ``dn`` (w,)
    into codes ``out`` (w,): the compiled :meth:`~rawsim.sensors.ProfileSensor.simu_noise`.
    Model 0 (``none``) gives the clean codes."""
    row = np.uint64(y)
    row_noise = p[N_ROW] * normal(row, ROW, k0, k1) if model == 3 else 0.0
    for x in range(dn.shape[0]):
        v = dn[x]
        if model != 0:
            site = row * np.uint64(width) + np.uint64(x)
            v = v + site_noise(v, site, model, p, k0, k1, row_noise, bias_tile[y % 2, x % 2])
        out[x] = min(max(np.rint(v), 0.0), white)


@njit(cache=True)
def add_noise_rows(dn, top, width, model, p, k0, k1, bias_tile, white, out):
    """:func:`noise_row` over clean rows ``dn`` (h, w) float32, rows ``top`` on of an
    image ``width`` wide, into ``out`` (h, w); for the equality tests."""
    for y in range(dn.shape[0]):
        noise_row(
            dn[y].astype(np.float64), top + y, width, model, p, k0, k1, bias_tile, white, out[y]
        )


@njit(parallel=True, cache=True)
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
    k0,
    k1,
    bias_tile,
    noisy,
    clean,
):
    """The whole unprocess chain for an (H, W, 3) image, into uint16 ``noisy`` (H, W).

    Args:
        pixels: (H, W, 3) integer codes (with ``lut``) or float32 linear values
            (``lut`` empty).
        lut: float32 linear value of each code (the reference's table).
        scale: 2^EV / brightness. ``ccm_bias``: (3,) subtracted first.
        matrix: (3, 3) sRGB → camera. ``wb``: (3,) white-balance gains.
        safe: Brooks's highlight-preserving inverse, blending above ``threshold``.
        mono: grey sensor (mean of RGB; no matrix or white balance).
        colors: (2, 2) colour index of each site of the CFA tile.
        vignetting: (strength, k1, k2, k3); no shading when strength is 0.
        levels: (black, white) DN.
        model, p, k0, k1, bias_tile: the noise (see :func:`site_noise`).
        noisy, clean: (H, W) uint16 outputs; ``clean`` is written if it has rows.
    """
    h, w = noisy.shape
    black, white = levels[0], levels[1]
    span = white - black
    with_lut = lut.shape[0] > 0
    want_clean = clean.shape[0] > 0
    strength = vignetting[0]
    cy, cx = (h - 1) / 2.0, (w - 1) / 2.0
    norm = cy * cy + cx * cx
    inv = np.empty(3)
    for c in range(3):
        inv[c] = 1.0 / wb[c]
    for y in prange(h):
        rgb = np.empty(3)
        cam = np.empty(3)
        dn = np.empty(w)
        for x in range(w):
            for c in range(3):
                # One body for codes and floats: the table branch types for both.
                px = pixels[y, x, c]
                v = np.float64(lut[np.intp(px)]) if with_lut else np.float64(px)
                rgb[c] = v * scale - ccm_bias[c]
            if mono:
                v = (rgb[0] + rgb[1] + rgb[2]) / 3.0
            else:
                for c in range(3):
                    cam[c] = matrix[c, 0] * rgb[0] + matrix[c, 1] * rgb[1] + matrix[c, 2] * rgb[2]
                c = colors[y % 2, x % 2]
                if safe:
                    gray = (cam[0] + cam[1] + cam[2]) / 3.0
                    m = max(gray - threshold, 0.0) / (1.0 - threshold)
                    v = cam[c] * (inv[c] + m * m * max(1.0 - inv[c], 0.0))
                else:
                    v = cam[c] / wb[c]
            if strength > 0.0:
                r2 = ((y - cy) ** 2 + (x - cx) ** 2) / norm
                gain = 1.0 + vignetting[1] * r2 + vignetting[2] * r2**2 + vignetting[3] * r2**3
                v = v / (1.0 + strength * (gain - 1.0))
            dn[x] = black + v * span
        if want_clean:
            noise_row(dn, y, w, 0, p, k0, k1, bias_tile, white, clean[y])
        noise_row(dn, y, w, model, p, k0, k1, bias_tile, white, noisy[y])
