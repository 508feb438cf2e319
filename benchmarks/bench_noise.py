"""Noise sampling speed: each model on a 24 MP mosaic, in the same run.

    python benchmarks/bench_noise.py

Draws noise for a 6000×4000 mosaic (signal spread over the whole range, Sony A7S2
profile, ISO 1600) the way ``rawsim unprocess`` does: 128-row strips, one
generator, 2 threads. Best of 3 runs per model.
Goal (issue 4): physics ≤ 2× the time of the plain Gaussian model.
"""

from __future__ import annotations

import time

import torch

from rawsim.noise import add_noise
from rawsim.pipelines.unprocess import STRIP_ROWS
from rawsim.profiles import load_profile


def main() -> None:
    profile = load_profile("sony_a7s2")
    g = torch.Generator().manual_seed(0)
    span = profile.white_level - profile.black_level
    dn = profile.black_level + torch.rand(1, 1, 4000, 6000, generator=g) * span
    times = {}
    for model in ("gaussian", "poisson-gaussian", "physics"):
        levels = profile.noise.levels(model, 1600)
        best = float("inf")
        for _ in range(3):
            gen = torch.Generator().manual_seed(1)
            start = time.perf_counter()
            for top in range(0, dn.shape[-2], STRIP_ROWS):
                add_noise(dn[..., top : top + STRIP_ROWS, :], profile.black_level, levels, gen)
            best = min(best, time.perf_counter() - start)
        times[model] = best
    print(f"24 MP mosaic, {torch.get_num_threads()} threads, ISO 1600 (sony_a7s2)")
    for model, seconds in times.items():
        print(f"  {model:<18} {seconds:6.3f} s   {seconds / times['gaussian']:4.2f}× gaussian")
    print("  goal: physics ≤ 2.00× gaussian")


if __name__ == "__main__":
    main()
