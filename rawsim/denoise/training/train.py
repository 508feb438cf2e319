"""Train :class:`rawsim.denoise.learned.RefineNet` on pairs rawsim makes, and write its weights.

One set of weights per kind of mosaic (``--kind bayer|xtrans``, :data:`PROFILES`):

1. **Pairs.** ``rawsim unprocess --clean --format npz`` turns each photo of
   ``--images`` (default: the photos vendored in tests/data: srgb, srgb16 and exr,
   none from the Kodak set) into a noisy capture and its noise-free twin, for every
   profile of the kind's mix, variant (:func:`variants`: the randomised ISP, and the
   profile's own colour with its physics noise where it has one) and seed of
   ``--seeds``, at an ISO drawn log-uniformly from the profile's range cut to
   :data:`ISO_RANGE`.
2. **Estimates.** The compiled profiled denoiser (:func:`rawsim.engine.denoise.
   denoise_mosaic`) denoises each noisy capture with the noise model its DNG
   NoiseProfile would carry (the sidecar's).
3. **Training.** Random 64×64 crops of packed planes (:func:`rawsim.denoise.
   layout.pack`), batches of 16, Adam
   (learning rate 1e-3, cosine decay to 1e-5), mean squared error in units of
   the model's σ at 10 % of white. Torch's generator is seeded with
   :data:`TRAIN_SEED`; a checkpoint (``checkpoint.pt`` in ``--work``) is written
   every 200 steps and picked up again by a later run with the same ``--work``.

The weights are written as safetensors to ``--out``.

    python -m rawsim.denoise.training.train --work /tmp/train --steps 14000 --seeds 11 \\
        --images DIRS --out rawsim/denoise/weights/refine_bayer.safetensors

(the README here: the photos, the commands and their times).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from rawsim.cameras.profiles import load_profile
from rawsim.cfa import CFA
from rawsim.denoise.layout import pack
from rawsim.denoise.learned import (
    INPUTS,
    RefineNet,
    network_input,
    noise_scale,
    site_inputs,
)
from rawsim.engine.denoise import denoise_mosaic

ROOT = Path(__file__).resolve().parents[3]
#: The profiles of each kind's mix. Bayer: every bundled Bayer profile with more than one
#: ISO (the D800E has one), and four database cameras of other sensor sizes and bit
#: depths (full frame, Micro Four Thirds, 1 inch). X-Trans: the bundled X-T3 and six
#: database X-Trans cameras, 12- and 14-bit, the pattern at three phases (X-T3's,
#: X-Pro2's, XQ2's).
PROFILES = {
    "bayer": (
        "canon_eos_5d_mark_iv",
        "canon_eos_700d",
        "canon_eos_70d",
        "nikon_d850",
        "oppo_reno10x",
        "sony_a7s2",
        "sony_imx686",
        "nikon_z_6",
        "om_digital_solutions_om_1",
        "panasonic_dc_gh5",
        "sony_dsc_rx100",
    ),
    "xtrans": (
        "fujifilm_xt3",
        "fujifilm_x_pro1",
        "fujifilm_x_pro2",
        "fujifilm_x_pro3",
        "fujifilm_x100v",
        "fujifilm_xq2",
        "fujifilm_x_s20",
    ),
}
SEEDS = (11, 12, 13, 14)
ISO_RANGE = (200.0, 51200.0)
TRAIN_SEED = 7
CROP, BATCH = 64, 16
#: The npz members of a pair.
KEYS = ("mosaic", "clean")


def default_images() -> list[Path]:
    return [ROOT / "tests" / "data" / d for d in ("srgb", "srgb16", "exr")]


def variants(profile: str) -> tuple[tuple[str, bool], ...]:
    """The (noise model, randomised colour) of a profile's pairs: Poisson-Gaussian noise
    with the randomised ISP, and the profile's own colour (its matrix and daylight white
    balance: a phone's gains near 1 leave red and blue as bright as green, which the
    randomised ISP never does) with the physics noise model (Tukey-lambda read noise,
    row noise, channel bias) where the profile has its terms, else Poisson-Gaussian."""
    physics = load_profile(profile).noise.has_physics
    return (("poisson-gaussian", True), ("physics" if physics else "poisson-gaussian", False))


def make_pairs(images: list[Path], work: Path, profiles, seeds=SEEDS) -> None:
    """Unprocess every photo for every profile, variant (:func:`variants`) and seed
    into ``work/pairs``."""
    for profile in profiles:
        lo, hi = load_profile(profile).iso_range
        iso = (max(lo, ISO_RANGE[0]), min(hi, ISO_RANGE[1]))
        for noise, randomize in variants(profile):
            for seed in seeds:
                colour = "random" if randomize else "own"
                out = work / "pairs" / f"{profile}_{noise}_{colour}_{seed}"
                if out.is_dir():
                    continue
                cmd = ["rawsim", "unprocess", *map(str, images), "-o", str(out)]
                cmd += ["--profile", profile, "--noise", noise]
                cmd += ["--iso-range", f"{iso[0]:g}", f"{iso[1]:g}", "--clean"]
                cmd += ["--randomize"] if randomize else []
                cmd += ["--format", "npz", "--seed", str(seed), "-q"]
                subprocess.run(cmd, check=True)


def load_pairs(work: Path) -> list[dict]:
    """Every pair as packed planes (4, h, w), white = 1 (:func:`rawsim.denoise.layout.
    pack`): noisy and profiled estimate float16 (their rounding, ≤ 0.03 σ at ISO 200,
    halves the memory of a wide mix), clean float32, with the CFA, the noise model per
    colour and the scale of the network's inputs (:func:`~rawsim.denoise.learned.
    noise_scale`)."""
    pairs = []
    for npz in sorted((work / "pairs").rglob("*.npz")):
        meta = json.loads(npz.with_suffix(".json").read_text())
        z = np.load(npz)
        cfa = CFA(meta["cfa_pattern"])
        black, white = float(np.mean(meta["black_level"])), float(meta["white_level"])
        gain, offset = ([v] * 3 for v in meta["noise"]["noise_profile"])  # per colour
        # npz layout auto: Bayer captures are stored packed (4, h, w), others as the
        # mosaic (1, H, W)
        noisy, clean = (cfa.unpack_array(z[k]) if cfa.is_bayer else z[k][0] for k in KEYS)
        estimate = denoise_mosaic(noisy, cfa, black, white, gain, offset)
        pair = {
            k: torch.from_numpy((pack(a, cfa).astype(np.float32) - black) / (white - black)).to(
                dtype
            )
            for k, a, dtype in (
                ("noisy", noisy, torch.float16),
                ("estimate", estimate, torch.float16),
                ("clean", clean, torch.float32),
            )
        }
        pairs.append(
            {
                **pair,
                "cfa": cfa,
                "gain": gain,
                "offset": offset,
                "scale": noise_scale(cfa, gain, offset),
            }
        )
    return pairs


def batch(pairs: list[dict], g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """(input (B, 12 or 24, 64, 64), target residual (B, 4, 64, 64)) in noise units."""
    areas = torch.tensor(
        [p["noisy"].shape[1] * p["noisy"].shape[2] for p in pairs], dtype=torch.float
    )
    picks = torch.multinomial(areas, BATCH, replacement=True, generator=g)
    xs, ys = [], []
    for i in picks.tolist():
        p = pairs[i]
        h, w = p["noisy"].shape[1:]
        y0 = int(torch.randint(0, h - CROP + 1, (1,), generator=g)) // 2 * 2
        x0 = int(torch.randint(0, w - CROP + 1, (1,), generator=g)) // 2 * 2
        rows, cols = slice(y0, y0 + CROP), slice(x0, x0 + CROP)
        cut = (slice(None), rows, cols)
        scale = p["scale"]
        gain, offset, colours = site_inputs(p["cfa"], p["gain"], p["offset"], rows, cols)
        colours = None if colours is None else torch.from_numpy(colours)[None]
        noisy, estimate = (p[k][cut][None].float() for k in ("noisy", "estimate"))
        xs.append(network_input(noisy, estimate, gain, offset, scale, colours))
        ys.append((p["clean"][cut][None] - estimate) / scale)
    return torch.cat(xs), torch.cat(ys)


def train(pairs: list[dict], work: Path, steps: int, minutes: float, inputs: int) -> RefineNet:
    torch.manual_seed(TRAIN_SEED)
    g = torch.Generator().manual_seed(TRAIN_SEED)
    net = RefineNet(inputs=inputs)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=1e-5)
    start, ckpt = 0, work / "checkpoint.pt"
    if ckpt.exists():
        state = torch.load(ckpt, weights_only=False)
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        g.set_state(state["generator"])
        start = state["step"]
        print(f"resumed at step {start}", flush=True)
    began, running = time.monotonic(), None
    for step in range(start, steps):
        x, y = batch(pairs, g)
        loss = torch.nn.functional.mse_loss(net(x), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        value = float(loss.detach())
        running = value if running is None else 0.98 * running + 0.02 * value
        if (step + 1) % 200 == 0 or step + 1 == steps:
            torch.save(
                {
                    "net": net.state_dict(),
                    "opt": opt.state_dict(),
                    "sched": sched.state_dict(),
                    "generator": g.get_state(),
                    "step": step + 1,
                },
                ckpt,
            )
            elapsed = (time.monotonic() - began) / 60
            print(f"step {step + 1}/{steps}: loss {running:.4f} ({elapsed:.1f} min)", flush=True)
            if minutes and elapsed > minutes:
                print(f"stopping after {elapsed:.1f} min: run again to resume", flush=True)
                break
    return net


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--images", type=Path, nargs="*", help="photo folders (default: tests/data's)")
    ap.add_argument("--work", type=Path, required=True, help="pairs and the checkpoint")
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--minutes", type=float, default=0, help="stop (resumably) after this long")
    ap.add_argument("--out", type=Path, help="write the weights here (safetensors)")
    ap.add_argument("--kind", choices=sorted(PROFILES), default="bayer", help="the mosaics served")
    ap.add_argument("--profiles", help="the profile mix (default: the kind's, PROFILES)")
    ap.add_argument("--seeds", default=",".join(map(str, SEEDS)), help="unprocess seeds")
    args = ap.parse_args(argv)
    began = time.monotonic()
    seeds = [int(v) for v in args.seeds.split(",")]
    profiles = args.profiles.split(",") if args.profiles else PROFILES[args.kind]
    images = args.images or default_images()
    make_pairs(images, args.work, profiles, seeds)
    pairs = load_pairs(args.work)
    print(f"{len(pairs)} pairs in {time.monotonic() - began:.0f} s", flush=True)
    net = train(pairs, args.work, args.steps, args.minutes, INPUTS[args.kind])
    if args.out:
        from safetensors.torch import save_file

        save_file({k: v.contiguous() for k, v in net.state_dict().items()}, str(args.out))
        print(f"wrote {args.out}", flush=True)
    print(f"total {(time.monotonic() - began) / 60:.1f} min", flush=True)


if __name__ == "__main__":
    sys.exit(main())
