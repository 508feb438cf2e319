"""The colour filter array (CFA) pattern as a value, and mosaic/pack operations on it.

A :class:`CFA` describes one period of a colour filter array. A 2×2 Bayer tile
is named by its letters, ``"RGGB"``: the colours at (row 0, col 0), (0, 1),
(1, 0), (1, 1). Any other periodic R/G/B layout is written row by row with
``/`` between the rows, e.g. the Fujifilm X-Trans 6×6 layout, also named
``"XTRANS"`` (:data:`XTRANS`). Masks, colour maps and mosaic/unmosaic are
generated from the pattern, so they work for every layout.

The 4-plane packing (:meth:`CFA.pack`, R, Gr, Gb, B) and :func:`apply_tile` are
defined for the 2×2 Bayer patterns only and raise :class:`ParameterError` for
other layouts.

Tensors are (B, C, H, W); a mosaic has C = 1. Bayer images have even H and W;
other layouts take any size (the pattern is anchored at the top-left pixel and
cut off at the right and bottom edges).
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
#: The Fujifilm X-Trans layout as LibRaw reports it (``raw_pattern``, its ``xtrans``
#: array) for a frame that starts on a whole 6×6 period: rows of R/G/B from the
#: top-left pixel. Each 3×3 block holds 5 G and 2 each of R and B (the 2 of one
#: colour on its middle row, the other's on its middle column), every row and
#: column of the period holds both R and B, and green forms 2×2 blocks around
#: single-green block centres. Read from a DNG with CFARepeatPatternDim 6×6 it is
#: exactly the CFAPattern tag, row-major (LibRaw's ``parse_tiff_ifd``).
XTRANS = "GGRGGB/GGBGGR/BRGRBG/GGBGGR/GGRGGB/RBGBRG"
#: Names accepted by :class:`CFA` besides explicit ``/``-separated rows.
CFA_NAMES = (*BAYER_PATTERNS, "XTRANS")
#: Order of the planes returned by :meth:`CFA.pack`, whatever the pattern.
PACKED_PLANES = ("R", "Gr", "Gb", "B")


@dataclass(frozen=True)
class CFA:
    """A CFA pattern: ``CFA("RGGB")``, ``CFA("XTRANS")`` or ``CFA("GRG/BGB/GRG")``...

    ``pattern`` is normalised: a Bayer name for 2×2 Bayer layouts (``"RG/GB"``
    becomes ``"RGGB"``), else the rows joined by ``/`` (``"XTRANS"`` becomes
    :data:`XTRANS`), so equal layouts compare equal.
    """

    pattern: str

    def __post_init__(self) -> None:
        pattern = str(self.pattern).upper().replace(" ", "")
        if pattern == "XTRANS":
            pattern = XTRANS
        rows = pattern.split("/") if "/" in pattern else None
        if rows is not None and len(rows) == 2 and all(len(r) == 2 for r in rows):
            pattern = "".join(rows)  # a 2×2 layout written as rows: use its Bayer name
            rows = None
        if rows is None:
            if pattern not in BAYER_PATTERNS:
                raise ParameterError(self._unknown())
        elif (
            len({len(r) for r in rows}) != 1 or not rows[0] or set("".join(rows)) != {"R", "G", "B"}
        ):
            raise ParameterError(self._unknown())
        object.__setattr__(self, "pattern", pattern)

    def _unknown(self) -> str:
        return (
            f"unknown CFA pattern {self.pattern!r}; valid: {', '.join(CFA_NAMES)}, or "
            "rows of equal length holding each of R, G and B, separated by '/' "
            "(e.g. 'GRG/BGB/GRG')"
        )

    @property
    def is_bayer(self) -> bool:
        """Whether this is one of the 2×2 Bayer patterns (:data:`BAYER_PATTERNS`)."""
        return "/" not in self.pattern

    @property
    def rows(self) -> tuple[str, ...]:
        """The letters of each row of the period, e.g. ``("RG", "GB")``."""
        if self.is_bayer:
            return (self.pattern[:2], self.pattern[2:])
        return tuple(self.pattern.split("/"))

    @property
    def period(self) -> tuple[int, int]:
        """(rows, columns) of one period: (2, 2) for Bayer, (6, 6) for X-Trans."""
        rows = self.rows
        return len(rows), len(rows[0])

    @property
    def name(self) -> str:
        """``"XTRANS"`` for :data:`XTRANS`, else :attr:`pattern`."""
        return "XTRANS" if self.pattern == XTRANS else self.pattern

    def color_at(self, y: int, x: int) -> int:
        """Colour index (R=0, G=1, B=2) of image site (y, x)."""
        ph, pw = self.period
        return COLOR_INDEX[self.rows[y % ph][x % pw]]

    def _require_bayer(self, what: str) -> None:
        if not self.is_bayer:
            ph, pw = self.period
            raise ParameterError(
                f"{what} is defined for the 2×2 Bayer patterns only "
                f"({', '.join(BAYER_PATTERNS)}); {self.name} has a {ph}×{pw} period"
            )

    @classmethod
    def from_rawpy(cls, raw_pattern, color_desc: bytes | str) -> CFA:
        """Build from rawpy's ``raw_pattern`` (N×M indices: 2×2 for Bayer, 6×6 for
        X-Trans) and ``color_desc`` (e.g. b"RGBG": index 3 is the second green)."""
        desc = color_desc.decode() if isinstance(color_desc, bytes) else str(color_desc)
        if raw_pattern is None:
            raise ParameterError("the file has no CFA pattern (raw_pattern is None)")
        try:
            rows = ["".join(desc[int(i)] for i in row) for row in raw_pattern]
        except (IndexError, TypeError, ValueError) as err:
            raise ParameterError(f"cannot read CFA from {raw_pattern!r} / {desc!r}") from err
        if len(rows) == 2 and [len(r) for r in rows] == [2, 2]:
            letters = "".join(rows)
            if letters not in BAYER_PATTERNS:
                raise ParameterError(f"not a 2×2 Bayer pattern: {raw_pattern!r} / {desc!r}")
            return cls(letters)
        try:
            return cls("/".join(rows))
        except ParameterError as err:
            raise ParameterError(f"not an R/G/B CFA pattern: {raw_pattern!r} / {desc!r}") from err

    @property
    def colors(self) -> tuple[int, ...]:
        """Colour index (R=0, G=1, B=2) of the period's sites in row-major order
        (four for Bayer, 36 for X-Trans)."""
        return tuple(COLOR_INDEX[c] for row in self.rows for c in row)

    @property
    def dng_pattern(self) -> bytes:
        """The DNG/TIFF-EP ``CFAPattern`` tag value (row-major, R=0, G=1, B=2)."""
        return bytes(self.colors)

    @property
    def dng_repeat(self) -> tuple[int, int]:
        """The DNG ``CFARepeatPatternDim`` tag value: :attr:`period`."""
        return self.period

    def _period_tile(self, planes: int, device, dtype):
        """(planes, ph, pw) zeros, and the colour of each period site, row-major."""
        import torch

        ph, pw = self.period
        return torch.zeros(planes, ph, pw, device=device, dtype=dtype), self.colors

    def _cover(self, tile, height: int, width: int):
        """Repeat a (..., ph, pw) tile over the image and cut it to (..., H, W)."""
        ph, pw = self.period
        reps = (1,) * (tile.ndim - 2) + (-(-height // ph), -(-width // pw))
        return tile.repeat(*reps)[..., :height, :width]

    @cached_property
    def packed_sites(self) -> tuple[tuple[int, int], ...]:
        """(row, col) of the R, Gr, Gb and B sites inside the tile (Bayer only)."""
        self._require_bayer("the R, Gr, Gb, B packing")
        sites = {(r, c): self.pattern[2 * r + c] for r in range(2) for c in range(2)}
        red = next(s for s, col in sites.items() if col == "R")
        blue = next(s for s, col in sites.items() if col == "B")
        green_r = next(s for s, col in sites.items() if col == "G" and s[0] == red[0])
        green_b = next(s for s, col in sites.items() if col == "G" and s[0] == blue[0])
        return (red, green_r, green_b, blue)

    @cached_property
    def phase_sites(self) -> tuple[tuple[int, int], ...]:
        """(row, col) of every site of one period: phase plane i is ``m[r::ph, c::pw]``
        for the i-th (r, c). For Bayer the R, Gr, Gb, B sites (:attr:`packed_sites`,
        the order of :meth:`pack`); otherwise all ph·pw sites, row-major."""
        if self.is_bayer:
            return self.packed_sites
        ph, pw = self.period
        return tuple((r, c) for r in range(ph) for c in range(pw))

    @cached_property
    def phase_channels(self) -> tuple[str, ...]:
        """The colour channel of each of :attr:`phase_sites`: ``R``, ``Gr``, ``Gb``, ``B``
        for Bayer (:data:`PACKED_PLANES`), the site's letter (``R``, ``G``, ``B``)
        otherwise, so phase planes of one colour share a name (X-Trans: 8 R, 20 G, 8 B)."""
        if self.is_bayer:
            return PACKED_PLANES
        return tuple(self.rows[r][c] for r, c in self.phase_sites)

    def tile(self, values: torch.Tensor) -> torch.Tensor:
        """Lay per-colour ``values`` (..., 3) out on one period: returns (..., 1, ph, pw)."""
        import torch

        idx = torch.tensor(self.colors, device=values.device)
        return values[..., idx].reshape(*values.shape[:-1], 1, *self.period)

    def masks(self, height: int, width: int, device=None, dtype=None):
        """One-hot colour masks (3, H, W): mask[c, y, x] is 1 where site (y, x) is colour c."""
        import torch

        dtype = dtype or torch.float32
        if self.is_bayer:
            _check_even(height, width)
            tile = torch.zeros(3, 2, 2, device=device, dtype=dtype)
            for i, color in enumerate(self.colors):
                tile[color, i // 2, i % 2] = 1
            return tile.repeat(1, height // 2, width // 2)
        tile, colors = self._period_tile(3, device, dtype)
        pw = self.period[1]
        for i, color in enumerate(colors):
            tile[color, i // pw, i % pw] = 1
        return self._cover(tile, height, width)

    @functools.lru_cache(maxsize=8)  # noqa: B019 - CFA values are few and immutable
    def site_masks(self, height: int, width: int, device=None, dtype=None):
        """Masks (4, H, W) of the R, Gr, Gb and B sites (the order of :meth:`pack`).

        Cached per size (strips repeat it); treat the result as read-only. Bayer only.
        """
        import torch

        self._require_bayer("site_masks (the R, Gr, Gb, B sites)")
        dtype = dtype or torch.float32
        _check_even(height, width)
        tile = torch.zeros(4, 2, 2, device=device, dtype=dtype)
        for plane, (r, c) in enumerate(self.packed_sites):
            tile[plane, r, c] = 1
        return tile.repeat(1, height // 2, width // 2)

    def color_map(self, height: int, width: int, device=None) -> torch.Tensor:
        """Colour index of every site, (1, 1, H, W) int64."""
        import torch

        if not self.is_bayer:
            tile = torch.tensor(self.colors, device=device).reshape(1, 1, *self.period)
            return self._cover(tile, height, width)
        _check_even(height, width)
        tile = torch.tensor(self.colors, device=device).reshape(1, 1, 2, 2)
        return tile.repeat(1, 1, height // 2, width // 2)

    def mosaic(self, rgb: torch.Tensor) -> torch.Tensor:
        """Sample an RGB image on the pattern: (B, 3, H, W) → (B, 1, H, W). Values untouched."""
        check_image(rgb, "rgb", channels=3)
        if not self.is_bayer:
            b, _, h, w = rgb.shape
            index = self.color_map(h, w, device=rgb.device).expand(b, 1, h, w)
            return rgb.gather(1, index)
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

        The plane order is the same for every Bayer pattern: Gr is the green on the
        red rows, Gb the green on the blue rows. Other layouts (X-Trans) have no such
        packing and raise :class:`ParameterError`.
        """
        import torch

        self._require_bayer("pack (the R, Gr, Gb, B planes)")
        check_image(mosaic, "mosaic", channels=1)
        _check_even(*mosaic.shape[-2:])
        return torch.cat([mosaic[:, :, r::2, c::2] for r, c in self.packed_sites], dim=1)

    def pack_array(self, mosaic):
        """:meth:`pack` of one NumPy mosaic, without torch: (H, W) → (4, H/2, W/2) in R,
        Gr, Gb, B order, the mosaic's type. Bayer only."""
        import numpy as np

        self._require_bayer("pack (the R, Gr, Gb, B planes)")
        _check_even(*mosaic.shape)
        return np.stack([mosaic[r::2, c::2] for r, c in self.packed_sites])

    def unpack_array(self, planes):
        """Inverse of :meth:`pack_array`: (4, H/2, W/2) → (H, W). Bayer only."""
        import numpy as np

        self._require_bayer("unpack (the R, Gr, Gb, B planes)")
        _, h, w = planes.shape
        out = np.empty((2 * h, 2 * w), planes.dtype)
        for plane, (r, c) in enumerate(self.packed_sites):
            out[r::2, c::2] = planes[plane]
        return out

    def unpack(self, planes: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`pack`: (B, 4, H/2, W/2) → (B, 1, H, W). Bayer only."""
        self._require_bayer("unpack (the R, Gr, Gb, B planes)")
        check_image(planes, "planes", channels=4)
        b, _, h, w = planes.shape
        out = planes.new_empty(b, 1, 2 * h, 2 * w)
        for plane, (r, c) in enumerate(self.packed_sites):
            out[:, 0, r::2, c::2] = planes[:, plane]
        return out


def apply_tile(x: torch.Tensor, tile: torch.Tensor, op) -> torch.Tensor:
    """``op(x, tile)`` with a (…, ph, pw) per-site tile (one CFA period) laid over
    ``x`` from its top-left pixel.

    ``x`` is (B, C, H, W). A 2×2 (Bayer) tile needs even H, W and broadcasts through
    a reshaped view, so no full-size map is built; a larger period (X-Trans, 6×6)
    is repeated over the image and cut at its right and bottom edges.
    """
    ph, pw = tile.shape[-2:]
    b, c, h, w = x.shape
    if (ph, pw) == (2, 2):
        _check_even(h, w)
        blocks = x.reshape(b, c, h // 2, 2, w // 2, 2)
        t = tile.to(x).reshape(*tile.shape[:-2], 1, 2, 1, 2)
        return op(blocks, t).reshape(b, c, h, w)
    reps = (1,) * (tile.ndim - 2) + (-(-h // ph), -(-w // pw))
    return op(x, tile.to(x).repeat(*reps)[..., :h, :w])


def phase_reflect_index(n: int, pad: int, period: int):
    """Source index (int64 numpy array, length n + 2·pad) of each position −pad … n + pad − 1
    of a line of ``n`` CFA sites extended by ``pad`` on both sides.

    Inside, the identity. Outside, the mirror image about the edge site, moved
    outwards by less than one period to the nearest index of the same CFA phase
    (≡ the virtual index mod ``period``), so the extended mosaic keeps the
    pattern; for ``period`` 2 this is plain reflection (torch's ``reflect``
    padding). Needs n ≥ pad + period.
    """
    import numpy as np

    if n < pad + period:
        raise ParameterError(f"cannot extend {n} sites by {pad} keeping a period of {period}")
    v = np.arange(-pad, n + pad)
    low = -v + np.mod(2 * v, period)
    high = 2 * (n - 1) - v - np.mod(2 * (n - 1) - 2 * v, period)
    return np.where(v < 0, low, np.where(v >= n, high, v)).astype(np.int64)


def _check_even(height: int, width: int) -> None:
    if height % 2 or width % 2:
        raise ParameterError(f"a Bayer image needs even height and width, got {height}×{width}")
