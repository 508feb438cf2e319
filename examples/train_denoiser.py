"""Train a small raw denoiser on CPU: the rawsim training loop end to end.

    python examples/train_denoiser.py    # examples/photos: +3.6 dB in about 2.5 minutes

Each step draws a batch of random crops from the training photos, unprocesses
them on the fly into noisy/clean packed Bayer planes (R, Gr, Gb, B) at random
ISOs with rawsim's noise model, and fits a small residual CNN that gets the
noise level map (√(K·x + σ²), as in noise-conditioned denoisers) as extra
inputs. The PSNR it reports is measured on crops of a held-out photo (never
trained on) at one ISO, before and after denoising.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from torch import nn
from torch.utils.data import DataLoader

from rawsim import RGBSensor, UnprocessDataset

PHOTOS = Path(__file__).resolve().parent / "photos"


class TinyDenoiser(nn.Module):
    """(B, 4, h, w) noisy planes + (B, 4, h, w) noise σ → (B, 4, h, w) clean estimate.

    The network sees the planes and σ, and predicts the noise in units of σ (a
    well-scaled target whatever the ISO); the estimate is noisy − σ · that.
    """

    def __init__(self, width: int = 48, depth: int = 5) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.Conv2d(8, width, 3, padding=1), nn.ReLU()]
        for _ in range(depth - 2):
            layers += [nn.Conv2d(width, width, 3, padding=1), nn.ReLU()]
        layers.append(nn.Conv2d(width, 4, 3, padding=1))
        self.net = nn.Sequential(*layers)

    def forward(self, noisy: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        return noisy - sigma * self.net(torch.cat([noisy, sigma / 0.02], dim=1))


def noise_sigma(noisy: torch.Tensor, batch: dict, span: float) -> torch.Tensor:
    """Per-pixel noise σ on the normalised scale, from each sample's K and read σ."""
    k = batch["gain"].view(-1, 1, 1, 1)
    read = batch["read_sigma"].view(-1, 1, 1, 1)
    var_dn = k * noisy.clamp(min=0) * span + read**2
    return var_dn.sqrt() / span


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1 / torch.mean((a.clamp(0, 1) - b) ** 2)))


def split(data: UnprocessDataset, holdout: str) -> UnprocessDataset:
    """Move the files named ``holdout`` out of ``data`` into a dataset of their own."""
    held = [f for f in data.files if f[1] == holdout]
    if not held:
        raise SystemExit(f"no photo named {holdout!r} in {data.files[0][0].parent}")
    data.files = [f for f in data.files if f[1] != holdout]
    valid = UnprocessDataset.__new__(UnprocessDataset)
    valid.__dict__.update(data.__dict__, files=held)
    return valid


def validation_set(valid: UnprocessDataset, crops: int, iso: float) -> list[dict]:
    """``crops`` fixed crops of the held-out photo(s) at one ISO, drawn once."""
    valid.iso, valid.iso_range = iso, None
    batches = []
    for epoch in range(crops):
        valid.set_epoch(10_000 + epoch)
        batches.append(next(iter(DataLoader(valid, batch_size=len(valid)))))
    return batches


def evaluate(model: nn.Module, batches: list[dict], span: float) -> tuple[float, float]:
    """Mean PSNR of the noisy and the denoised planes against the clean ones."""
    noisy_db, out_db = [], []
    with torch.no_grad():
        for b in batches:
            out = model(b["noisy"], noise_sigma(b["noisy"], b, span))
            noisy_db.append(psnr(b["noisy"], b["clean"]))
            out_db.append(psnr(out, b["clean"]))
    return sum(noisy_db) / len(noisy_db), sum(out_db) / len(out_db)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(PHOTOS), help="folder of sRGB/EXR images")
    ap.add_argument("--holdout", default="astronaut.png", help="photo kept for validation")
    ap.add_argument("--profile", default="canon_eos_70d")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--crop", type=int, default=96)
    ap.add_argument("--workers", type=int, default=0)
    ap.add_argument("--iso-range", type=float, nargs=2, default=(800.0, 6400.0))
    ap.add_argument("--valid-iso", type=float, default=3200.0)
    ap.add_argument("--valid-crops", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    start = time.perf_counter()
    torch.manual_seed(args.seed)
    sensor = RGBSensor.from_profile(args.profile)
    data = UnprocessDataset(
        args.data,
        sensor,
        crop=args.crop,
        seed=args.seed,
        iso_range=tuple(args.iso_range),
        noise="physics" if sensor.profile.noise.has_physics else "poisson-gaussian",
    )
    valid = validation_set(split(data, args.holdout), args.valid_crops, args.valid_iso)
    span = sensor.white_level - sensor.black_level
    model = TinyDenoiser()
    opt = torch.optim.Adam(model.parameters(), lr=2e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, args.steps)
    losses, step, epoch = [], 0, 0
    while step < args.steps:
        data.set_epoch(epoch)
        loader = DataLoader(
            data, batch_size=args.batch_size, shuffle=True, num_workers=args.workers
        )
        for batch in loader:
            noisy, clean = batch["noisy"], batch["clean"]
            loss = nn.functional.l1_loss(model(noisy, noise_sigma(noisy, batch, span)), clean)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            losses.append(loss.item())
            step += 1
            if step % 100 == 0 or step == args.steps:
                before, after = evaluate(model, valid, span)
                print(
                    f"step {step:4d}  loss {losses[-1]:.5f}  held-out ISO {args.valid_iso:g}: "
                    f"PSNR noisy {before:5.2f} dB → denoised {after:5.2f} dB"
                )
            if step == args.steps:
                break
        epoch += 1
    before, after = evaluate(model, valid, span)
    seconds = time.perf_counter() - start
    print(
        f"done in {seconds:.0f} s: {args.holdout} at ISO {args.valid_iso:g}, {before:.2f} → "
        f"{after:.2f} dB ({after - before:+.2f} dB)"
    )
    return {"losses": losses, "noisy_psnr": before, "denoised_psnr": after, "seconds": seconds}


if __name__ == "__main__":
    main()
