"""The configurable forward ISP (torch reference): a config → an :class:`Isp` module.

The config itself (stages, parameters, validation, TOML) is
:mod:`rawsim.isp.config`, re-exported here; :func:`build_isp` turns a config and
a :class:`~rawsim.io.raw.RawImage` into an :class:`Isp` module.

Data flow: DN mosaic (B, 1, H, W) — or (B, 3, H, W) for raws without a CFA —
through black level (→ white = 1), optional mosaic filters, white balance,
highlights, demosaic (→ RGB), denoise, colour matrix, exposure, tone curve,
transfer, YCbCr and orientation.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from rawsim.errors import ParameterError
from rawsim.isp.color_matrix import ColorMatrix
from rawsim.isp.config import (  # noqa: F401 - the config API, also reachable from here
    COLOUR_ONLY,
    MOSAIC_ONLY,
    OUTPUT_SPACES,
    STAGES,
    WB_MODES,
    auto_white_balance,
    camera_to_output,
    config_to_toml,
    default_config,
    exposure_stops,
    load_config,
    load_config_text,
    override,
    parse_gains,
    tone_params,
    validate_config,
    white_balance,
    white_level,
)
from rawsim.isp.dead_pixel import DeadPixelCorrection
from rawsim.isp.demosaic import Demosaic
from rawsim.isp.exposure import Exposure
from rawsim.isp.filters import AntiAliasing, Denoise
from rawsim.isp.highlights import Highlights
from rawsim.isp.lens_shading import LensShading
from rawsim.isp.levels import Levels
from rawsim.isp.orientation import Orientation
from rawsim.isp.tone import ToneCurve
from rawsim.isp.transfer import Transfer
from rawsim.isp.white_balance import WhiteBalance
from rawsim.isp.ycbcr import ColorSpaceConversion


class Isp(nn.Module):
    """A built ISP: named stage modules run in order. ``info`` records resolved values.

    Without gradients, images taller than two strips run strip by strip
    (:data:`STRIP_ROWS` rows plus enough rows of context for every stage): the
    result is the same, the memory a fraction. Orientation, a global reindexing,
    runs once at the end.
    """

    def __init__(self, stages: list[tuple[str, nn.Module]], info: dict) -> None:
        super().__init__()
        self.names = [n for n, _ in stages]
        self.stages = nn.ModuleList([m for _, m in stages])
        self.info = info

    @property
    def halo(self) -> int:
        """Rows of context a strip needs on each side (even, so strips keep the CFA phase)."""
        total = sum(getattr(m, "radius", 0) for m in self.stages)
        return total + total % 2

    def _run(self, x: torch.Tensor, region: tuple[int, int]) -> torch.Tensor:
        for m in self.stages:
            if isinstance(m, Orientation):
                continue
            x = m(x, region) if getattr(m, "positional", False) else m(x)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x.shape[-2]
        if torch.is_grad_enabled() or h <= 2 * STRIP_ROWS:
            out = self._run(x, (0, h))
        else:
            out = None
            halo = self.halo
            for top in range(0, h, STRIP_ROWS):
                lo, hi = max(0, top - halo), min(h, top + STRIP_ROWS + halo)
                part = self._run(x[..., lo:hi, :], (lo, h))
                rows = part[..., top - lo : top - lo + min(STRIP_ROWS, h - top), :]
                if out is None:
                    out = rows.new_empty(*rows.shape[:-2], h, rows.shape[-1])
                out[..., top : top + rows.shape[-2], :] = rows
        for m in self.stages:
            if isinstance(m, Orientation):
                out = m(out)
        return out


STRIP_ROWS = 256


def build_isp(config: list[dict], raw) -> Isp:
    """Build the ISP for ``raw`` (a :class:`~rawsim.io.raw.RawImage`) from a validated config."""
    warnings: list[str] = list(raw.warnings)
    info: dict = {"warnings": warnings}
    stages: list[tuple[str, nn.Module]] = []
    cfa = raw.cfa
    mono = cfa is None and raw.data.shape[-1] == 1
    info["monochrome"] = mono  # grey data: no colour stages
    for s in config:
        name = s["name"]
        if not s["enabled"]:
            continue
        if cfa is None and name in MOSAIC_ONLY:
            continue  # 3-channel or grey data: nothing to demosaic or filter per plane
        if mono and name in COLOUR_ONLY:
            continue
        if name == "black_level":
            module = Levels(_black_map(raw), white_level(s, raw, info))
        elif name == "dead_pixel":
            module = DeadPixelCorrection(cfa, s["threshold"], s["kernel"], s["temperature"])
        elif name == "lens_shading":
            module = LensShading(tuple(s["k"]), s["strength"])
        elif name == "anti_aliasing":
            module = AntiAliasing(cfa, s["method"], s["sigma"])
        elif name == "white_balance":
            module = WhiteBalance(white_balance(s, config, raw, warnings, info), cfa)
        elif name == "highlights":
            module = Highlights(s["mode"])
        elif name == "demosaic":
            module = Demosaic(cfa, s["method"])
        elif name == "denoise":
            module = Denoise(
                cfa if _before(config, "denoise", "demosaic") else None,
                s["method"],
                s["kernel"],
                s["sigma"],
                s["sigma_color"],
            )
        elif name == "color_matrix":
            matrix = camera_to_output(raw, s["output_space"])
            info["color_matrix"] = matrix.tolist()
            module = ColorMatrix(torch.as_tensor(matrix, dtype=torch.float32))
        elif name == "exposure":
            module = Exposure(exposure_stops(s, raw, info))
        elif name == "tone":
            module = ToneCurve(*tone_params(s))
        elif name == "transfer":
            module = Transfer(s["function"])
        elif name == "ycbcr":
            module = ColorSpaceConversion()
        elif name == "orientation":
            module = Orientation(raw.orientation)
        else:  # pragma: no cover - STAGES and this chain list the same names
            raise ParameterError(f"unknown stage {name!r}; valid: {', '.join(STAGES)}")
        stages.append((name, module))
    return Isp(stages, info)


def _black_map(raw):
    """The black level as a number, or a tensor broadcastable to the data (B, C, H, W)."""
    black = np.asarray(raw.black_level, dtype=np.float64)
    if np.allclose(black, black.flat[0]):
        return float(black.flat[0])
    if raw.cfa is None:
        return torch.as_tensor(black, dtype=torch.float32).reshape(1, 3, 1, 1)
    return torch.as_tensor(black, dtype=torch.float32).reshape(1, 1, 2, 2)  # a CFA tile


def _before(config: list[dict], a: str, b: str) -> bool:
    names = [s["name"] for s in config]
    return b in names and names.index(a) < names.index(b)
