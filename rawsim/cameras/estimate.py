"""Sensor noise estimated from a camera's physics, for cameras nobody calibrated.

The model (units: DN of the raw, e⁻ photo-electrons, µm², ISO):

- **Gain.** ISO 12232's saturation-based speed puts the raw's full scale at a fixed
  exposure H = 78/S lux·s at ISO S. The electrons a pixel collects from it are
  proportional to its area A (µm²) and fall as 1/S, so the electrons at full scale are
  ``N(S) = η·A/S`` and the gain is ``K(S) = (white − black)/N(S) = (white − black)·S/(η·A)``
  DN/e⁻. η (e⁻ per µm² at ISO 1) folds in the quantum efficiency, the colour filter and
  each maker's headroom; it is fitted on the calibrated cameras (``fit``).
- **Read noise.** ``σ²(S) = (K(S)·r)² + (d·(white − black)/16383)²`` DN²: a sensor noise
  of r e⁻ amplified with the gain, plus a floor after the amplifier of d DN on a 14-bit
  scale (an ADC's noise scales with its step). r and d are fitted on the same cameras.

The pixel area comes from the sensor's size and resolution. When the resolution is
not known it is assumed: the median pixel area of cameras with the same sensor size
(see ``build.py``), and the profile says so.
"""

from __future__ import annotations

import math

#: ISOs at which an estimated profile tabulates its read noise, within its ISO range.
ISO_GRID = (50, 100, 200, 400, 800, 1600, 3200, 6400, 12800, 25600, 51200, 102400, 204800)
#: The ISO range assumed for a camera nothing is known of (``profiles from-raw`` of a
#: camera the database lacks): the grid's.
ISO_RANGE = (ISO_GRID[0], ISO_GRID[-1])


def pixel_area(size_mm: tuple[float, float], resolution: tuple[int, int]) -> float:
    """Area of one pixel in µm², from the sensor size (mm) and its pixel counts."""
    return size_mm[0] * size_mm[1] / (resolution[0] * resolution[1]) * 1e6


def gain(iso: float, span: float, area_um2: float, eta: float) -> float:
    """K in DN/e⁻ at ``iso`` for a full scale of ``span`` DN over pixels of ``area_um2``."""
    return span * iso / (eta * area_um2)


def read_sigma(k: float, span: float, r: float, d: float) -> float:
    """Read noise σ in DN at gain ``k`` (see the module's model)."""
    return math.hypot(k * r, d * span / 16383.0)


def noise_spec(
    span: float, area_um2: float, constants: dict, iso_range: tuple[float, float] = ISO_RANGE
) -> dict:
    """The profile keys ``noise.gain`` (linear in ISO) and ``noise.read_sigma`` (a table
    at the ends of ``iso_range`` and the :data:`ISO_GRID` ISOs between them)."""
    eta, r, d = constants["eta"], constants["read_e"], constants["floor_dn14"]
    slope = gain(1.0, span, area_um2, eta)
    lo, hi = iso_range
    isos = [lo, *(i for i in ISO_GRID if lo < i < hi), hi] if hi > lo else [lo]
    sigma = [read_sigma(slope * iso, span, r, d) for iso in isos]
    return {
        "gain": {"model": "linear", "slope": slope, "intercept": 0.0},
        "read_sigma": {"model": "table", "iso": isos, "sigma": sigma},
    }


def calibrated_camera(profile, isos) -> dict:
    """A calibrated :class:`~rawsim.cameras.profiles.SensorProfile` as :func:`fit` takes it: its
    name, span (white − black, DN), pixel area (µm²) and (ISO, K, read σ) at ``isos``."""
    points = []
    for iso in isos:
        k = profile.noise.gain(iso)
        points.append((iso, k, profile.noise.read_sigma(iso, k)))
    return {
        "name": profile.name,
        "span": profile.white_level - profile.black_level,
        "area": pixel_area(profile.size_mm, profile.resolution),
        "points": points,
    }


def fit(cameras: list[dict]) -> dict:
    """η, r and d from calibrated cameras.

    Each camera is ``{"span", "area", "points": [(iso, K, read σ DN), ...]}``. η is the
    geometric mean of ``span·S/(K·A)`` over the cameras (one weight per camera, not per
    point); r and d are fitted by least squares of ln σ over a log grid.
    """
    etas = []
    for c in cameras:
        per = [c["span"] * iso / (k * c["area"]) for iso, k, _ in c["points"]]
        etas.append(sum(math.log(v) for v in per) / len(per))
    eta = math.exp(sum(etas) / len(etas))
    best = None
    for r in (0.25 * 1.05**i for i in range(90)):
        for d in (0.1 * 1.05**j for j in range(110)):
            err = 0.0
            for c in cameras:
                for _, k, s in c["points"]:
                    err += (math.log(read_sigma(k, c["span"], r, d)) - math.log(s)) ** 2
            if best is None or err < best[0]:
                best = (err, r, d)
    return {"eta": eta, "read_e": best[1], "floor_dn14": best[2]}
