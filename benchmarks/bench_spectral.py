"""Colour from spectra: each camera's fitted colour matrices against Adobe's, and
rawsim's ACES input transform against colour-science's ``matrix_idt``.

For every camera with measured curves (``rawsim.cameras.spectra``) it fits the D65
ColorMatrix (CIEDE2000 on rawtoaces' 190 training patches) and prints, on the 24
patches of the ColorChecker (colour-science's "ColorChecker N Ohta" reflectances; not
the training set: their chromatic patches differ from the nearest training patch by
1–9 % RMS reflectance), lit by D65 and seen through the curves:

- fit vs Adobe: ΔE00 between the renders with the fitted matrix and with the profile's
  own (Adobe's, from LibRaw's table), mean and worst;
- each against the observer: ΔE00 between what the matrix renders and what the CIE
  1931 observer sees (the curves are the truth here, so this favours the fit);
- under illuminant A likewise, the A fit against the D65 matrices the cameras'
  profiles have: what a single-matrix raw converter loses under tungsten.

Then the ACES IDT: rawsim's B against ``colour.matrix_idt``'s (largest difference of
an entry) and the time of each, under D55 and ISO 7589 tungsten, for the four bundled
cameras with curves. Needs colour-science (the test extra)::

    python benchmarks/bench_spectral.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import colour  # noqa: E402
from machine import describe  # noqa: E402

from rawsim.cameras import spectra  # noqa: E402
from rawsim.cameras.profiles import load_profile  # noqa: E402
from rawsim.color import delta_e_2000, xyz_to_lab  # noqa: E402
from rawsim.spectral import fit, tables  # noqa: E402


def colorchecker() -> np.ndarray:
    """(81, 24) the ColorChecker's reflectances on rawsim's grid."""
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values()
    return np.array([[sd[w] for w in tables.WAVELENGTHS] for sd in sds]).T


def rendered_lab(curves, light, xyz_to_camera, refl) -> np.ndarray:
    """CIELAB (relative to the camera white's XYZ) a DNG-style converter renders."""
    to_xyz = np.linalg.inv(xyz_to_camera)
    white = to_xyz @ (curves.T @ light)
    seen = fit.camera_responses(curves, light, refl) @ to_xyz.T / white[1]
    return xyz_to_lab(seen, white / white[1])


def matrices() -> None:
    refl = colorchecker()
    d65, a = tables.illuminant("D65"), tables.illuminant("A")
    print("\nColorChecker 24 under D65 (ΔE00 mean / worst); under A: the A fit vs the D65 matrix")
    heads = ("fit vs Adobe", "fit vs obs", "Adobe vs obs", "A: fit", "A: D65 mtx")
    print(f"{'camera':26} " + " ".join(f"{h:>11}" for h in heads))
    rows = []
    for name in spectra.names():
        p = load_profile(name)
        curves = p.curves.rgb
        fitted = fit.color_matrix(curves, d65).xyz_to_camera
        adobe = np.asarray(p.xyz_to_camera)
        vs = delta_e_2000(
            rendered_lab(curves, d65, fitted, refl), rendered_lab(curves, d65, adobe, refl)
        )
        fit_obs = fit.delta_e(curves, d65, fitted, refl)
        adobe_obs = fit.delta_e(curves, d65, adobe, refl)
        a_fit = fit.delta_e(curves, a, fit.color_matrix(curves, a).xyz_to_camera, refl)
        a_d65 = fit.delta_e(curves, a, adobe, refl)
        row = (vs, fit_obs, adobe_obs, a_fit, a_d65)
        rows.append(row)
        cells = " ".join(f"{x.mean():5.2f}/{x.max():5.2f}" for x in row)
        print(f"{p.curves.label:26} {cells}")
    means = np.array([[x.mean() for x in r] for r in rows]).mean(axis=0)
    worst = np.array([[x.max() for x in r] for r in rows]).max(axis=0)
    cells = " ".join(f"{m:5.2f}/{w:5.2f}" for m, w in zip(means, worst, strict=True))
    print(f"{f'all {len(rows)} (mean of means / worst)':26} {cells}")


def idt() -> None:
    print("\nACES IDT: rawsim vs colour.matrix_idt (largest |ΔB|, seconds each)")
    for name in ("sony_a7s2", "canon_eos_5d_mark_iv", "nikon_d850", "fujifilm_xt3"):
        curves = load_profile(name).curves
        sens = colour.characterisation.RGB_CameraSensitivities(
            dict(zip(tables.WAVELENGTHS, curves.rgb, strict=True)), labels=list("RGB")
        )
        for light in ("D55", "ISO7589"):
            spd = tables.illuminant(light)
            t0 = time.perf_counter()
            ours, _ = fit.aces_idt(curves.rgb, spd)
            t1 = time.perf_counter()
            sd = colour.SpectralDistribution(dict(zip(tables.WAVELENGTHS, spd, strict=True)))
            theirs, _ = colour.matrix_idt(sens, sd)
            t2 = time.perf_counter()
            print(
                f"  {curves.label:22} {light:8} |ΔB| {np.abs(ours - theirs).max():.1e}  "
                f"rawsim {t1 - t0:.3f} s, colour-science {t2 - t1:.3f} s"
            )


def main() -> None:
    for line in describe():
        print(line)
    matrices()
    idt()


if __name__ == "__main__":
    main()
