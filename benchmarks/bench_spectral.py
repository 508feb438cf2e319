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
an entry) for every camera with curves under D65 and A, and the time of each.

``--round-trip``: the ColorChecker as a spectral scene (24 patches of 40 × 40 pixels,
81 bands) through ``rawsim unprocess`` (under D65, noise off, the clean DNG) and
``rawsim process`` (to CIE XYZ in EXR, no tone, ``--saturation white``: the raw is
noise-free, so its white patch is 800 equal sites that the default finder, like
LibRaw's adjust_maximum, takes for a clip at 89 % of white), for every camera: the
patches' mean and worst ΔE00 against the scene's own colours (the CIE 1931
observer's, D65).

``--metamerism PNG``: the ColorChecker for two cameras under D65 and A, rendered as a
raw converter renders each camera (white-balanced, its own D65 matrix): where the
cameras disagree, and where a matrix-only simulation (camera RGB from the observer's
XYZ through the D65 matrix, rawsim's RGB path) differs from the spectral one; the
figures in ΔE00, and a picture of the patches. Needs colour-science (the test
extra)::

    python benchmarks/bench_spectral.py [--round-trip] [--metamerism PNG] [--rawtoaces]

``--rawtoaces``: rawtoaces (built from its source: docs/guide/spectral.md) on DNGs that
``rawsim unprocess`` writes for the ten cameras rawtoaces 1.0 has curves for, against
``rawsim process --output-space aces2065-1`` of the same DNGs.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import colour  # noqa: E402
from machine import describe  # noqa: E402

from rawsim.cameras import spectra  # noqa: E402
from rawsim.cameras.profiles import load_profile  # noqa: E402
from rawsim.color import (  # noqa: E402
    SRGB_TO_XYZ,
    XYZ_D65,
    chromatic_adaptation,
    delta_e_2000,
    xyz_to_lab,
)
from rawsim.spectral import fit, tables  # noqa: E402


def colorchecker() -> np.ndarray:
    """(81, 24) the ColorChecker's reflectances on rawsim's grid."""
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values()
    return np.array([[sd[w] for w in tables.WAVELENGTHS] for sd in sds]).T


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
            xyz_to_lab(*fit.converter_xyz(curves, d65, fitted, refl)),
            xyz_to_lab(*fit.converter_xyz(curves, d65, adobe, refl)),
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
    print("\nACES IDT: rawsim vs colour.matrix_idt, every camera with curves, D65 and A")
    worst, ours_t, theirs_t, n = 0.0, 0.0, 0.0, 0
    for name in spectra.names():
        curves = spectra.of_camera(name)
        sens = colour.characterisation.RGB_CameraSensitivities(
            dict(zip(tables.WAVELENGTHS, curves.rgb, strict=True)), labels=list("RGB")
        )
        for light in ("D65", "A"):
            spd = tables.illuminant(light)
            t0 = time.perf_counter()
            ours, _ = fit.aces_idt(curves.rgb, spd)
            t1 = time.perf_counter()
            sd = colour.SpectralDistribution(dict(zip(tables.WAVELENGTHS, spd, strict=True)))
            theirs, _ = colour.matrix_idt(sens, sd)
            t2 = time.perf_counter()
            worst = max(worst, float(np.abs(ours - theirs).max()))
            ours_t, theirs_t, n = ours_t + t1 - t0, theirs_t + t2 - t1, n + 1
    print(
        f"  {n} fits: largest |ΔB| {worst:.1e} (target 1e-3); mean time rawsim "
        f"{ours_t / n * 1e3:.1f} ms, colour-science {theirs_t / n * 1e3:.1f} ms"
    )


def chart_scene(path: Path, size: int = 40) -> np.ndarray:
    """Write the ColorChecker as a spectral .npz (6 × 4 patches of ``size`` pixels,
    81 bands, reflectance); return its (81, 24) reflectances."""
    refl = colorchecker()
    patches = refl.T.reshape(4, 6, 81).astype(np.float32)
    cube = np.repeat(np.repeat(patches, size, axis=0), size, axis=1)
    np.savez(path, spectra=cube, wavelengths=tables.WAVELENGTHS, kind="reflectance")
    return refl


def patch_means(image: np.ndarray, size: int = 40) -> np.ndarray:
    """(24, 3) the mean of each patch's central half."""
    q = size // 4
    return np.array(
        [
            image[r * size + q : (r + 1) * size - q, c * size + q : (c + 1) * size - q]
            .reshape(-1, 3)
            .mean(axis=0)
            for r in range(4)
            for c in range(6)
        ]
    )


def round_trip(work: Path) -> None:
    import OpenImageIO as oiio
    from click.testing import CliRunner

    from rawsim_cli.main import cli

    scene = work / "colorchecker.npz"
    refl = chart_scene(scene)
    d65 = tables.illuminant("D65")
    xyz, white = fit.observer_xyz(d65, refl)
    truth = xyz_to_lab(xyz, white)
    print("\nColorChecker round trip: unprocess (D65, no noise) → process (XYZ, EXR)")
    print(f"{'camera':26} {'ΔE00 mean':>9} {'worst':>6}")
    rows = []
    for name in spectra.names():
        out = work / name
        iso = max(100.0, load_profile(name).iso_range[0])  # the X-T3's starts at 160
        args = ["unprocess", str(scene), "-o", str(out), "-p", name, "--iso", f"{iso:g}"]
        args += ["--noise", "none", "--clean", "--illuminant", "D65", "--seed", "1"]
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 0, r.output
        r = CliRunner().invoke(
            cli,
            ["process", str(out / "colorchecker.clean.dng"), "-o", str(out), "--output-space",
             "xyz", "--format", "exr", "--bits", "32", "--tone", "none",
             "--saturation", "white"],
        )  # fmt: skip
        assert r.exit_code == 0, r.output
        image = oiio.ImageBuf(str(out / "colorchecker.clean.exr")).get_pixels(oiio.FLOAT)
        de = delta_e_2000(xyz_to_lab(patch_means(image[..., :3]), white), truth)
        rows.append((spectra.of_camera(name).label, de.mean(), de.max()))
        print(f"{rows[-1][0]:26} {de.mean():9.2f} {de.max():6.2f}")
    best = min(rows, key=lambda r: r[1])
    means = np.array([r[1] for r in rows])
    print(
        f"best: {best[0]} {best[1]:.2f} (target ≤ 1.0); all {len(rows)}: mean "
        f"{means.mean():.2f}, worst camera {means.max():.2f}"
    )


#: The two cameras of the metamerism example: a Canon and a Fujifilm, whose curves
#: differ more than most (bench_spectral's table: X-T3 the furthest from the observer).
METAMERISM_CAMERAS = ("Canon EOS R6", "Fujifilm X-T3")


def metamerism(png: Path) -> None:
    """Two cameras, two lights: the spectral renders against the matrix-only one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    refl = colorchecker()
    cams = [load_profile(n) for n in METAMERISM_CAMERAS]
    print(
        "\nMetamerism: the ColorChecker through each camera's curves, rendered with its D65 matrix"
    )
    panels = []
    for light_name in ("D65", "A"):
        light = tables.illuminant(light_name)
        xyz, white = fit.observer_xyz(light, refl)
        observer = xyz @ chromatic_adaptation(white, XYZ_D65).T  # matrix-only: exactly this
        labs = [xyz_to_lab(observer, XYZ_D65)]
        row = [("matrix-only (either camera)", observer)]
        for p in cams:
            seen, seen_white = fit.converter_xyz(p.curves.rgb, light, p.xyz_to_camera, refl)
            seen = seen @ chromatic_adaptation(seen_white, XYZ_D65).T  # as the converter adapts
            labs.append(xyz_to_lab(seen, XYZ_D65))
            row.append((p.curves.label, seen))
        apart = delta_e_2000(labs[1], labs[2])
        print(
            f"  {light_name:4} cameras apart: ΔE00 mean {apart.mean():.2f}, worst "
            f"{apart.max():.2f} (patch {apart.argmax() + 1}); matrix-only: 0 by construction"
        )
        for p, lab in zip(cams, labs[1:], strict=True):
            off = delta_e_2000(lab, labs[0])
            print(
                f"  {light_name:4} {p.curves.label:16} vs matrix-only: ΔE00 mean "
                f"{off.mean():.2f}, worst {off.max():.2f} (patch {off.argmax() + 1})"
            )
        panels.append((light_name, row, apart))
    fig, axes = plt.subplots(2, 3, figsize=(10.5, 5.4))
    to_srgb = np.linalg.inv(SRGB_TO_XYZ)
    for (light_name, row, apart), line in zip(panels, axes, strict=True):
        for (title, xyz), ax in zip(row, line, strict=True):
            rgb = np.clip(xyz @ to_srgb.T / 0.9, 0, 1)  # the white patch (0.9) at 1
            rgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * rgb ** (1 / 2.4) - 0.055)
            ax.imshow(rgb.reshape(4, 6, 3), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{title}, {light_name}", fontsize=9)
        for k, de in enumerate(apart):
            line[2].text(k % 6, k // 6, f"{de:.1f}", ha="center", va="center", fontsize=7)
    fig.suptitle(
        "The ColorChecker through measured curves, each camera rendered with its D65 matrix; "
        "numbers: ΔE00 between the two cameras",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    print(f"  wrote {png}")


#: rawsim profiles of the cameras rawtoaces 1.0's own data has curves for.
RAWTOACES_CAMERAS = (
    "sony_a7s2", "Sony ILCE-7RM2", "Nikon D7000", "Nikon D5100", "Nikon D700",
    "Nikon D200", "Nikon D70", "Canon EOS 5D Mark II", "Canon EOS 400D",
    "Canon PowerShot S90",
)  # fmt: skip


def rawtoaces_agreement(work: Path) -> None:
    """rawtoaces' ACES2065-1 EXR of rawsim DNGs against rawsim's own (--output-space
    aces2065-1): PSNR over the frame (8 pixels of border left out) and over 16 × 16
    block means, after one gain (rawtoaces' headroom, 6 by default)."""
    import shutil
    import subprocess

    import OpenImageIO as oiio
    from click.testing import CliRunner

    from rawsim_cli.main import cli

    exe = shutil.which("rawtoaces")
    if exe is None:
        print("\nrawtoaces: not on PATH (docs/guide/spectral.md says how to build it)")
        return
    photo = Path(__file__).resolve().parents[1] / "tests/data/kodak/kodim02_crop.png"
    print(f"\nrawtoaces ({exe}) vs rawsim process, ACES2065-1 of {photo.name} unprocessed")
    print(f"{'profile':22} {'gain':>6} {'PSNR':>6} {'16×16':>6}  rawsim's IDT")

    def blocks(x: np.ndarray, n: int = 16) -> np.ndarray:
        h, w = x.shape[0] // n * n, x.shape[1] // n * n
        return x[:h, :w].reshape(h // n, n, w // n, n, 3).mean(axis=(1, 3))

    def psnr(x: np.ndarray, y: np.ndarray) -> float:
        return float(10 * np.log10(x.max() ** 2 / np.mean((x - y) ** 2)))

    for name in RAWTOACES_CAMERAS:
        out = work / name.replace(" ", "_")
        args = ["unprocess", str(photo), "-o", str(out), "-p", name, "--iso", "200"]
        r = CliRunner().invoke(cli, [*args, "--noise", "none"])
        assert r.exit_code == 0, r.output
        dng = out / f"{photo.stem}.dng"
        done = subprocess.run([exe, str(dng)], capture_output=True, text=True, cwd=out)
        if done.returncode != 0:  # e.g. the EOS 400D, which its data names "XTi" only
            said = (done.stdout + done.stderr).strip().splitlines()[-1]
            print(f"{name:22} rawtoaces refused it: {said}")
            continue
        r = CliRunner().invoke(
            cli, ["process", str(dng), "-o", str(out / "rawsim"), "--output-space", "aces2065-1"]
        )
        assert r.exit_code == 0, r.output
        theirs = oiio.ImageBuf(str(out / f"{photo.stem}_aces.exr")).get_pixels(oiio.FLOAT)
        ours = oiio.ImageBuf(str(out / "rawsim" / f"{photo.stem}.exr")).get_pixels(oiio.FLOAT)
        a, b = theirs[8:-8, 8:-8, :3], ours[8:-8, 8:-8, :3]
        gain = float((a * b).sum() / (b * b).sum())
        side = json.loads((out / "rawsim" / f"{photo.stem}.process.json").read_text())
        kind = side["aces"]["idt"]["kind"]
        full, coarse = psnr(a, gain * b), psnr(blocks(a), gain * blocks(b))
        print(f"{name:22} {gain:6.3f} {full:6.1f} {coarse:6.1f}  {kind}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--round-trip", action="store_true", help="the ColorChecker round trip")
    ap.add_argument("--metamerism", type=Path, metavar="PNG", help="write the picture")
    ap.add_argument("--rawtoaces", action="store_true", help="compare with rawtoaces' EXRs")
    a = ap.parse_args()
    for line in describe():
        print(line)
    matrices()
    idt()
    if a.round_trip:
        with tempfile.TemporaryDirectory() as work:
            round_trip(Path(work))
    if a.metamerism:
        metamerism(a.metamerism)
    if a.rawtoaces:
        with tempfile.TemporaryDirectory() as work:
            rawtoaces_agreement(Path(work))


if __name__ == "__main__":
    main()
