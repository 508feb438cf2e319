"""Train a tiny raw denoiser for a few steps on CPU: the rawsim training loop end to end.

    python examples/train_denoiser.py --data ../shared/data/srgb --steps 50

Each step draws a batch of random crops from the image folder, unprocesses them
on the fly into noisy/clean packed Bayer planes (R, Gr, Gb, B) at random ISOs
with rawsim's noise model, and fits a small residual CNN that gets the noise
level map (√(K·x + σ²), as in noise-conditioned denoisers) as a fifth input.
"""

from __future__ import annotations

import argparse

import torch
from torch import nn
from torch.utils.data import DataLoader

from rawsim import RGBSensor, UnprocessDataset


class TinyDenoiser(nn.Module):
    """(B, 4, h, w) noisy planes + (B, 4, h, w) noise σ → (B, 4, h, w) clean estimate."""

    def __init__(self, width: int = 32) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(8, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, 4, 3, padding=1),
        )

    def forward(self, noisy: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        return noisy - self.net(torch.cat([noisy, sigma], dim=1))


def noise_sigma(noisy: torch.Tensor, batch: dict, span: float) -> torch.Tensor:
    """Per-pixel noise σ on the normalised scale, from each sample's K and read σ."""
    k = batch["gain"].view(-1, 1, 1, 1)
    read = batch["read_sigma"].view(-1, 1, 1, 1)
    var_dn = k * noisy.clamp(min=0) * span + read**2
    return var_dn.sqrt() / span


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1 / torch.mean((a.clamp(0, 1) - b) ** 2)))


def main(argv: list[str] | None = None) -> list[float]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="folder of sRGB/EXR images")
    ap.add_argument("--profile", default="canon_eos_70d")
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--batch-size", type=int, default=4)
    ap.add_argument("--crop", type=int, default=128)
    ap.add_argument("--workers", type=int, default=0)
    ap.add_argument("--iso-range", type=float, nargs=2, default=(800.0, 6400.0))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

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
    span = sensor.white_level - sensor.black_level
    model = TinyDenoiser()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    losses, step, epoch = [], 0, 0
    while step < args.steps:
        data.set_epoch(epoch)
        loader = DataLoader(
            data, batch_size=args.batch_size, shuffle=True, num_workers=args.workers
        )
        for batch in loader:
            noisy, clean = batch["noisy"], batch["clean"]
            out = model(noisy, noise_sigma(noisy, batch, span))
            loss = nn.functional.l1_loss(out, clean)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
            before, after = psnr(noisy, clean), psnr(out.detach(), clean)
            print(
                f"step {step + 1:4d}  loss {losses[-1]:.5f}  "
                f"PSNR noisy {before:5.2f} dB → denoised {after:5.2f} dB"
            )
            step += 1
            if step == args.steps:
                break
        epoch += 1
    return losses


if __name__ == "__main__":
    main()
