"""Convert darktable's noise profiles (``data/noiseprofiles.json``) to rawsim's K and read σ.

Run from the repository root::

    python tools/cameras/darktable_noise.py NOISEPROFILES_JSON [--factor F]

``NOISEPROFILES_JSON`` is darktable's ``data/noiseprofiles.json`` (or any file of the same
form: ``noiseprofiles`` → makers → ``models`` → ``profiles`` with ``iso``, ``a[3]``,
``b[3]``). The script prints, for every bundled ELD-calibrated profile whose camera the
file lists, the converted K and read σ beside rawsim's, and their ratios.

What darktable's ``a`` and ``b`` are (read in darktable-org/darktable; the index reported
these commits for the files read):

1. ``tools/noise/darktable-gen-noiseprofile`` @ 07b4fbf92a1ea0dc2701a90d8367f3a3ca0fe8d6,
   ``profile_image`` (≈ lines 125-160): each raw is exported by ``darktable-cli`` with
   ``profiling-shot.xmp`` to a full-size float PFM (``--core --conf
   plugins/lighttable/export/iccprofile=image``), measured by ``darktable-noiseprofile``,
   and gnuplot fits ``std² = a·x + b`` per channel (green over x ∈ [0, 0.8], points
   weighted by their pixel count); the JSON stores those a, b (``txt2json``).
2. ``tools/noise/profiling-shot.xmp`` @ 0ccb79fce816d7dd718a9632b8760bf4d813793f: the
   history applied before measuring. ``temperature`` params ``0000803f``×3 = WB
   multipliers 1, 1, 1 (no white balance); ``colorin`` and ``colorout`` type 3 = linear
   Rec.709 in and out (an identity: camera RGB passes through, no matrix, no gamma);
   sharpen, basecurve, highlights switched off. Still on, as darktable's defaults:
   rawprepare (x = (raw − black)/(white − black), i.e. [0, 1]) and demosaic (full size).
   No exposure module.
3. ``tools/noise/noiseprofile.c`` @ 03a8259dc26bef4c08a86090461b4430e2be00b5, ``main``:
   pixels are clamped at 0 on reading (``read_pfm``, ≈ line 63); a one-level decimated
   Haar transform is applied (≈ lines 225-250): ``LL = (x00+x01+x10+x11)/4`` gives the
   brightness bin (300 bins), ``HH = (x00 − x01 − x10 + x11)/4``; the "std" of a bin is
   ``median(|HH|)/0.6745`` (≈ line 280) and is written without rescaling. For white
   noise of per-pixel variance σ², Var(HH) = σ²/4; demosaicing correlates neighbouring
   pixels and lowers Var(HH) further. So ``a·x + b`` is the HH-band variance of the
   demosaiced channel, not the per-pixel variance.
4. ``src/iop/denoiseprofile.c`` (``compute_wb_factors``, ``process_wavelets``: "only use
   green channel + wb for now"): the module uses ``a[1]``, ``b[1]`` (green) only and
   multiplies them by the image's white-balance coefficients (green is 1), which is
   consistent with profiles measured without white balance (step 2). Its variance model
   is in its own stabilising transform's units, so the Haar factor never needs undoing
   inside darktable.

Hence, for green (WB coefficient 1), in DN of the raw file (range R = white − black)::

    Var_HH(DN) = a_G·R · (signal DN) + b_G·R²
    K          = F · a_G · R                  [DN/e⁻]
    σ_read     = sqrt(F · b_G) · R            [DN]   (undefined when b_G ≤ 0)

with F = Var(pixel)/Var(HH) = 4 × (demosaic's HH attenuation of green). Only the 4 follows
from the source exactly; the demosaic part depends on the algorithm the contributor's
darktable used, which the JSON does not record. Simulated with darktable's measurement
(flat ramps, Poisson–Gaussian noise, the estimator and fit above): F ≈ 4.0 with no
demosaic, 10.3 with a Hamilton–Adams green, 14.3 with PPG, 21.5 with bilinear. The
default F = 14.3 (PPG) is that estimate, not an exact inverse; scene texture, the clamp
at 0 and the fit window change the b term most.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

#: darktable's file version these notes were checked against.
UPSTREAM = (
    "darktable-org/darktable data/noiseprofiles.json @ 0001d6291804c66d63078fa3bc248fa827c48e9e"
)
#: Var(pixel)/Var(Haar HH): exact part (Haar normalisation) and the PPG-demosaic estimate.
HAAR_FACTOR = 4.0
PPG_FACTOR = 14.3
#: Bundled ELD profiles and darktable's (maker, model) for the same camera.
CAMERAS = {
    "canon_eos_700d": ("Canon", "EOS 700D"),
    "canon_eos_70d": ("Canon", "EOS 70D"),
    "canon_eos_5d_mark_iv": ("Canon", "EOS 5D Mark IV"),
    "nikon_d850": ("Nikon", "D850"),
    "sony_a7s2": ("Sony", "ILCE-7SM2"),
}
#: ISO range of the acceptance criterion (ratio within ±25 %).
CHECK_ISO = (400, 6400)
TOLERANCE = 0.25


def find_entry(doc: dict, maker: str, model: str) -> dict | None:
    """darktable's model entry for ``maker``/``model`` (case-insensitive), or None."""
    for m in doc.get("noiseprofiles", []):
        if m.get("maker", "").lower() != maker.lower():
            continue
        for entry in m.get("models", []):
            if entry.get("model", "").lower() == model.lower():
                return entry
    return None


def convert(
    entry: dict, white: float, black: float, factor: float = PPG_FACTOR
) -> list[tuple[float, float, float]]:
    """(iso, K in DN/e⁻, read σ in DN) for each profile of a darktable model entry.

    Uses the green coefficients (index 1), whose WB multiplier is 1: K = factor·a_G·(white −
    black) and σ = sqrt(factor·b_G)·(white − black), NaN when b_G ≤ 0. ``factor`` is
    Var(pixel)/Var(Haar HH) (see the module docstring). Profiles marked ``"skip"`` are
    left out; repeated ISOs are averaged (a and b separately).
    """
    span = white - black
    by_iso: dict[float, list[tuple[float, float]]] = {}
    for p in entry.get("profiles", []):
        if p.get("skip"):
            continue
        by_iso.setdefault(float(p["iso"]), []).append((float(p["a"][1]), float(p["b"][1])))
    out = []
    for iso in sorted(by_iso):
        pairs = by_iso[iso]
        a = sum(v[0] for v in pairs) / len(pairs)
        b = sum(v[1] for v in pairs) / len(pairs)
        k = factor * a * span
        sigma = math.sqrt(factor * b) * span if b > 0 else math.nan
        out.append((iso, k, sigma))
    return out


def _ratio_range(rows: list[tuple[float, float, float]]) -> tuple[float, float] | None:
    inside = [r[1] for r in rows if CHECK_ISO[0] <= r[0] <= CHECK_ISO[1]]
    return (min(inside), max(inside)) if inside else None


def compare(doc: dict, factor: float) -> list[str]:
    """Comparison table lines (and a summary per camera) against the bundled profiles."""
    from rawsim.cameras.profiles import load_profile

    lines: list[str] = []
    verdicts: list[bool] = []
    for name, (maker, model) in CAMERAS.items():
        entry = find_entry(doc, maker, model)
        if entry is None:
            lines.append(f"\n{name}: darktable lists no {maker} {model} in this file")
            continue
        prof = load_profile(name)
        black, white = prof.black_level, prof.white_level
        lines.append(
            f"\n{name} ({maker} {model}; black {black:g}, white {white:g}; "
            f"ELD range ISO {prof.iso_range[0]:g}-{prof.iso_range[1]:g})"
        )
        lines.append("    ISO     K_dt    K_ELD  K ratio   σ_dt   σ_ELD  σ ratio")
        ratios = []
        for iso, k, sigma in convert(entry, white, black, factor):
            k_eld = prof.noise.gain(iso)
            s_eld = prof.noise.read_sigma(iso, k_eld)
            kr, sr = k / k_eld, sigma / s_eld
            ratios.append((iso, kr, sr))
            flag = "" if prof.iso_range[0] <= iso <= prof.iso_range[1] else "  (outside ELD range)"
            lines.append(
                f"  {iso:6g} {k:8.3f} {k_eld:8.3f} {kr:7.3f}"
                f"  {sigma:7.2f} {s_eld:7.2f} {sr:7.3f}{flag}"
            )
        rng = _ratio_range(ratios)
        if rng:
            ok = 1 - TOLERANCE <= rng[0] and rng[1] <= 1 + TOLERANCE
            verdicts.append(ok)
            lines.append(
                f"  K ratio over ISO {CHECK_ISO[0]}-{CHECK_ISO[1]}: {rng[0]:.3f} … {rng[1]:.3f}"
                f" -> {'within' if ok else 'OUTSIDE'} ±{TOLERANCE:.0%}"
            )
    found = len(verdicts)
    lines.append(
        f"\nfactor F = {factor:g}; cameras compared: {found}; within ±{TOLERANCE:.0%} over ISO "
        f"{CHECK_ISO[0]}-{CHECK_ISO[1]}: {sum(verdicts)} of {found}"
    )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("noiseprofiles", type=Path, help="darktable's data/noiseprofiles.json")
    ap.add_argument(
        "--factor",
        type=float,
        default=PPG_FACTOR,
        help=f"Var(pixel)/Var(HH): {HAAR_FACTOR:g} = Haar only, {PPG_FACTOR:g} = PPG (default)",
    )
    args = ap.parse_args(argv)
    doc = json.loads(args.noiseprofiles.read_text())
    print(f"darktable noise profiles: {args.noiseprofiles}")
    print(f"upstream: {doc.get('_transcribed_from', UPSTREAM)}")
    print(
        "K = F·a_G·(white − black); σ_read = sqrt(F·b_G)·(white − black); ratios are darktable/ELD"
    )
    print("\n".join(compare(doc, args.factor)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
