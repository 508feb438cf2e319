"""The counter-based generator's constants and key schedule, torch-free: shared by
the torch reference (:mod:`rawsim.noise.reference`) and the compiled backend
(:mod:`rawsim.noise.kernels`), so a process that only runs compiled kernels
does not import torch."""

from __future__ import annotations

MASK32 = 0xFFFFFFFF
PHILOX_M0, PHILOX_M1 = 0xD2511F53, 0xCD9E8D57
PHILOX_W0, PHILOX_W1 = 0x9E3779B9, 0xBB67AE85
#: Counter word 2 of each kind of draw. Row noise indexes rows, the others sites; the
#: per-file draws of the physics model's dark terms use index 0: ``black_level`` the
#: black-level offset (a normal), ``dark_crop`` the crop of the dark-shading map
#: (two uniforms). New streams take new numbers, so earlier draws keep their bits.
STREAMS = {
    "normal": 0,
    "tukey": 1,
    "poisson": 2,
    "row": 3,
    "threshold": 4,
    "shot": 5,
    "black_level": 6,
    "dark_crop": 7,
}


def split_key(seed: int) -> tuple[int, int]:
    """A 64-bit seed → the two 32-bit Philox key words (low, high)."""
    seed = int(seed) & 0xFFFFFFFFFFFFFFFF
    return seed & MASK32, seed >> 32
