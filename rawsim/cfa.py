"""The colour filter array (CFA) pattern as a value, and mosaic/pack operations on it.

A :class:`CFA` describes a 2×2 Bayer tile such as ``"RGGB"``: the letters are
the colours at (row 0, col 0), (0, 1), (1, 0), (1, 1). Masks and plane indices
are generated from it, so every operation works for RGGB, BGGR, GRBG and GBRG.

Tensors are (B, C, H, W) with H and W even; a mosaic has C = 1.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

from rawsim.errors import ParameterError, check_image

if TYPE_CHECKING:  # torch is imported where it is used: reading raws needs none
    import torch

#: Colour index of each CFA letter; DNG's CFAPattern uses the same codes (R=0, G=1, B=2).
COLOR_INDEX = {"R": 0, "G": 1, "B": 2}
BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
#: Order of the planes returned by :meth:`CFA.pack`, whatever the pattern.
PACKED_PLANES = ("R", "Gr", "Gb", "B")


@dataclass(frozen=True)
class CFA:
    """A 2×2 Bayer pattern, e.g. ``CFA("RGGB")``."""

    pattern: str

    def __post_init__(self) -> None:
        pattern = str(self.pattern).upper()
        if pattern not in BAYER_PATTERNS:
            raise ParameterError(
                f"unknown CFA pattern {self.pattern!r}; valid: {', '.join(BAYER_PATTERNS)}"
            )
        object.__setattr__(self, "pattern", pattern)

    @classmethod
    def from_rawpy(cls, raw_pattern, color_desc: bytes | str) -> CFA:
        """Build from rawpy's ``raw_pattern`` (2×2 indices) and ``color_desc`` (e.g. b"RGBG")."""
        desc = color_desc.decode() if isinstance(color_desc, bytes) else str(color_desc)
        if raw_pattern is None:
            raise ParameterError("the file has no CFA pattern (raw_pattern is None)")
        try:
            letters = "".join(desc[int(i)] for row in raw_pattern for i in row)
        except (IndexError, TypeError, ValueError) as err:
            raise ParameterError(f"cannot read CFA from {raw_pattern!r} / {desc!r}") from err
        if len(letters) != 4:
            raise ParameterError(f"not a 2×2 Bayer pattern: {raw_pattern!r} / {desc!r}")
        return cls(letters)

    @property
    def colors(self) -> tuple[int, int, int, int]:
        """Colour index (R=0, G=1, B=2) of the four tile sites in row-major order."""
        return tuple(COLOR_INDEX[c] for c in self.pattern)  # type: ignore[return-value]

    @property
    def dng_pattern(self) -> bytes:
        """The DNG/TIFF-EP ``CFAPattern`` tag value."""
        return bytes(self.colors)

    @cached_property
    def packed_sites(self) -> tuple[tuple[int, int], ...]:
        """(row, col) of the R, Gr, Gb and B sites inside the tile."""
        sites = {(r, c): self.pattern[2 * r + c] for r in range(2) for c in range(2)}
        red = next(s for s, col in sites.items() if col == "R")
        blue = next(s for s, col in sites.items() if col == "B")
        green_r = next(s for s, col in sites.items() if col == "G" and s[0] == red[0])
        green_b = next(s for s, col in sites.items() if col == "G" and s[0] == blue[0])
        return (red, green_r, green_b, blue)

    def tile(self, values: torch.Tensor) -> torch.Tensor:
        """Lay per-colour ``values`` (..., 3) out on the 2×2 tile: returns (..., 1, 2, 2)."""
        import torch

        idx = torch.tensor(self.colors, device=values.device)
        return values[..., idx].reshape(*values.shape[:-1], 1, 2, 2)

    def masks(self, height: int, width: int, device=None, dtype=None):
        """One-hot colour masks (3, H, W): mask[c, y, x] is 1 where site (y, x) is colour c."""
        import torch

        dtype = dtype or torch.float32
        _check_even(height, width)
        tile = torch.zeros(3, 2, 2, device=device, dtype=dtype)
        for i, color in enumerate(self.colors):
            tile[color, i // 2, i % 2] = 1
        return tile.repeat(1, height // 2, width // 2)

    @functools.lru_cache(maxsize=8)  # noqa: B019 - CFA values are few and immutable
    def site_masks(self, height: int, width: int, device=None, dtype=None):
        """Masks (4, H, W) of the R, Gr, Gb and B sites (the order of :meth:`pack`).

        Cached per size (strips repeat it); treat the result as read-only.
        """
        import torch

        dtype = dtype or torch.float32
        _check_even(height, width)
        tile = torch.zeros(4, 2, 2, device=device, dtype=dtype)
        for plane, (r, c) in enumerate(self.packed_sites):
            tile[plane, r, c] = 1
        return tile.repeat(1, height // 2, width // 2)

    def color_map(self, height: int, width: int, device=None) -> torch.Tensor:
        """Colour index of every site, (1, 1, H, W) int64."""
        import torch

        _check_even(height, width)
        tile = torch.tensor(self.colors, device=device).reshape(1, 1, 2, 2)
        return tile.repeat(1, 1, height // 2, width // 2)

    def mosaic(self, rgb: torch.Tensor) -> torch.Tensor:
        """Sample an RGB image on the pattern: (B, 3, H, W) → (B, 1, H, W). Values untouched."""
        check_image(rgb, "rgb", channels=3)
        _check_even(*rgb.shape[-2:])
        out = rgb.new_empty(rgb.shape[0], 1, *rgb.shape[-2:])
        for i, color in enumerate(self.colors):
            r, c = divmod(i, 2)
            out[:, 0, r::2, c::2] = rgb[:, color, r::2, c::2]
        return out

    def unmosaic(self, mosaic: torch.Tensor) -> torch.Tensor:
        """Spread a mosaic into sparse RGB: (B, 1, H, W) → (B, 3, H, W), zero off-site.

        ``mosaic(unmosaic(m)) == m`` exactly; ``unmosaic(mosaic(x))`` equals ``x`` at
        the CFA sites of each channel.
        """
        check_image(mosaic, "mosaic", channels=1)
        masks = self.masks(*mosaic.shape[-2:], device=mosaic.device, dtype=mosaic.dtype)
        return mosaic * masks

    def pack(self, mosaic: torch.Tensor) -> torch.Tensor:
        """Pack a mosaic into half-resolution planes (B, 4, H/2, W/2) in R, Gr, Gb, B order.

        The plane order is the same for every pattern: Gr is the green on the red
        rows, Gb the green on the blue rows.
        """
        import torch

        check_image(mosaic, "mosaic", channels=1)
        _check_even(*mosaic.shape[-2:])
        return torch.cat([mosaic[:, :, r::2, c::2] for r, c in self.packed_sites], dim=1)

    def unpack(self, planes: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`pack`: (B, 4, H/2, W/2) → (B, 1, H, W)."""
        check_image(planes, "planes", channels=4)
        b, _, h, w = planes.shape
        out = planes.new_empty(b, 1, 2 * h, 2 * w)
        for plane, (r, c) in enumerate(self.packed_sites):
            out[:, 0, r::2, c::2] = planes[:, plane]
        return out


def apply_tile(x: torch.Tensor, tile: torch.Tensor, op) -> torch.Tensor:
    """``op(x, tile)`` with a (…, 2, 2) per-site tile laid over every 2×2 block of ``x``.

    ``x`` is (B, C, H, W) with even H, W; the tile broadcasts through a reshaped
    view, so no full-size map is built.
    """
    b, c, h, w = x.shape
    _check_even(h, w)
    blocks = x.reshape(b, c, h // 2, 2, w // 2, 2)
    t = tile.to(x).reshape(*tile.shape[:-2], 1, 2, 1, 2)
    return op(blocks, t).reshape(b, c, h, w)


def _check_even(height: int, width: int) -> None:
    if height % 2 or width % 2:
        raise ParameterError(f"a Bayer image needs even height and width, got {height}×{width}")
