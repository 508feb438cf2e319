"""The configurable forward ISP (torch reference): a config → an :class:`Isp` module.

The config itself (typed stages, validation, TOML) and its resolution for one
raw are :mod:`rawsim.isp.config`; :func:`build_isp` turns a config and a
:class:`~rawsim.io.raw.RawImage` into an :class:`Isp` module, one torch module
per stage type (:data:`MODULES`).

Data flow: DN mosaic (B, 1, H, W) — or (B, 3, H, W) for raws without a CFA —
through black level (→ white = 1), raw denoising, optional mosaic filters, white balance,
highlights, demosaic (→ RGB), denoise, lens correction, colour matrix, exposure,
tone curve, transfer, YCbCr and orientation. Where the lens stage corrects a Bayer
raw's lateral CA (:attr:`~rawsim.isp.config.ResolvedIsp.tca_on_mosaic`), a module
named ``lens_tca`` takes it out of the mosaic just before the demosaic.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from rawsim.cfa import CFA
from rawsim.denoise.noise_model import stage_model
from rawsim.isp.color_matrix import ColorMatrix
from rawsim.isp.config import (
    HALF_SIZE,
    XTRANS_METHOD,
    AntiAliasingStage,
    BlackLevelStage,
    ColorMatrixStage,
    DeadPixelStage,
    DemosaicStage,
    DenoiseStage,
    ExposureStage,
    HighlightsStage,
    IspConfig,
    LensCorrectionStage,
    LensShadingStage,
    OrientationStage,
    RawDenoiseStage,
    ResolvedIsp,
    Stage,
    ToneStage,
    TransferStage,
    WhiteBalanceStage,
    YCbCrStage,
    resolve,
)
from rawsim.isp.dead_pixel import DeadPixelCorrection
from rawsim.isp.demosaic import Demosaic, RootDomain
from rawsim.isp.exposure import Exposure
from rawsim.isp.filters import AntiAliasing, Denoise
from rawsim.isp.half_size import HalfSize
from rawsim.isp.highlights import Highlights
from rawsim.isp.lens import LensCorrection, MosaicTca
from rawsim.isp.lens_shading import LensShading
from rawsim.isp.levels import Levels
from rawsim.isp.magenta_guard import MagentaGuard
from rawsim.isp.orientation import Orientation
from rawsim.isp.raw_denoise import RawDenoise
from rawsim.isp.tone import ToneCurve
from rawsim.isp.transfer import Transfer
from rawsim.isp.white_balance import WhiteBalance
from rawsim.isp.xtrans import XTransDemosaic
from rawsim.isp.ycbcr import ColorSpaceConversion


class Isp(nn.Module):
    """A built ISP: named stage modules run in order. ``info`` records resolved values.

    Without gradients, images taller than two strips run strip by strip
    (:data:`STRIP_ROWS` rows, the last one up to twice that, plus :attr:`halo`
    rows of context on each side): the result is the same, the memory a
    fraction. Every strip starts on a whole CFA period and is at least a strip
    tall, so stages that need a few periods of image (the X-Trans demosaics,
    the per-site filters of :mod:`rawsim.isp.planes`) get them. The stages that
    move pixels across the image (:data:`WHOLE_IMAGE`: lens correction, which
    works through the image in row chunks itself, and orientation) run once on
    the whole image, the stages between them strip by strip.
    """

    def __init__(self, stages: list[tuple[str, nn.Module]], info: dict, period: int = 2) -> None:
        super().__init__()
        self.names = [n for n, _ in stages]
        self.stages = nn.ModuleList([m for _, m in stages])
        self.info = info
        self.period = period

    @property
    def halo(self) -> int:
        """Rows of context a strip needs on each side: the sum of the stages' ``radius``
        (rows each output row depends on, on each side), rounded up to whole CFA
        periods so strips keep the CFA phase."""
        return self._halo(self.stages)

    def _halo(self, modules) -> int:
        total = sum(getattr(m, "radius", 0) for m in modules)
        return -(-total // self.period) * self.period

    @property
    def strip_rows(self) -> int:
        """:data:`STRIP_ROWS`, cut to whole CFA periods."""
        return STRIP_ROWS - STRIP_ROWS % self.period

    def _run(self, x: torch.Tensor, region: tuple[int, int], modules) -> torch.Tensor:
        for m in modules:
            x = m(x, region) if getattr(m, "positional", False) else m(x)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        run: list[nn.Module] = []
        for m in self.stages:
            if isinstance(m, WHOLE_IMAGE):
                x = m(self._strips(x, run)) if run else m(x)
                run = []
            else:
                run.append(m)
        return self._strips(x, run) if run else x

    def _strips(self, x: torch.Tensor, modules: list[nn.Module]) -> torch.Tensor:
        """``modules`` (none of :data:`WHOLE_IMAGE`) on ``x``, strip by strip where that helps."""
        h = x.shape[-2]
        strip = self.strip_rows
        whole = any(isinstance(m, HalfSize) for m in modules)  # strips keep the size
        if torch.is_grad_enabled() or h <= 2 * strip or whole:
            return self._run(x, (0, h), modules)
        out = None
        halo = self._halo(modules)
        count = h // strip  # the last strip takes the rest: none is shorter than a strip
        for k in range(count):
            top = k * strip
            size = strip if k < count - 1 else h - top
            lo, hi = max(0, top - halo), min(h, top + size + halo)
            part = self._run(x[..., lo:hi, :], (lo, h), modules)
            rows = part[..., top - lo : top - lo + size, :]
            if out is None:
                out = rows.new_empty(*rows.shape[:-2], h, rows.shape[-1])
            out[..., top : top + size, :] = rows
        return out


STRIP_ROWS = 256
#: Stages that run once on the whole image (they move pixels across strips, or, as
#: raw denoising, work through the image in chunks of their own).
WHOLE_IMAGE = (RawDenoise, MosaicTca, LensCorrection, Orientation)


def build_isp(config: IspConfig | list[dict], raw) -> Isp:
    """Build the ISP for ``raw`` (a :class:`~rawsim.io.raw.RawImage`) from a config
    (typed, or its TOML tables)."""
    return isp_for(resolve(config, raw))


def isp_for(resolved: ResolvedIsp) -> Isp:
    """The :class:`Isp` of a config resolved for one raw (its stages, its values)."""
    modules = []
    guard = resolved.magenta_guard
    for s in resolved.stages:
        if isinstance(s, DemosaicStage) and resolved.tca_on_mosaic:
            modules.append(("lens_tca", MosaicTca(resolved.raw.cfa, resolved.info["lens"])))
        module = MODULES[type(s)](s, resolved)
        if isinstance(s, DemosaicStage) and guard is not None:
            module = MagentaGuard(module, resolved.raw.cfa, resolved.clip_levels[1], guard)
        modules.append((s.name, module))
    cfa = resolved.raw.cfa
    return Isp(modules, resolved.info, int(np.lcm(*cfa.period)) if cfa else 2)


#: Stage type → its torch module, from the stage and the config resolved for a raw.
MODULES: dict[type[Stage], Callable[..., nn.Module]] = {
    BlackLevelStage: lambda s, r: Levels(
        _black_map(r.raw), r.white_level, r.raw.cfa.period if r.raw.cfa else (2, 2)
    ),
    RawDenoiseStage: lambda s, r: RawDenoise(
        r.raw.cfa, r.info["raw_denoise"], *stage_model(r), s.strength
    ),
    DeadPixelStage: lambda s, r: DeadPixelCorrection(
        r.raw.cfa, s.threshold, s.kernel, s.temperature
    ),
    LensShadingStage: lambda s, r: LensShading(s.k, s.strength),
    AntiAliasingStage: lambda s, r: AntiAliasing(r.raw.cfa, s.method, s.sigma),
    WhiteBalanceStage: lambda s, r: WhiteBalance(r.white_balance, r.raw.cfa),
    HighlightsStage: lambda s, r: Highlights(s.mode, r.clip_levels, r.raw.cfa),
    DemosaicStage: lambda s, r: _demosaic(r.raw.cfa, s.method, s.domain),
    DenoiseStage: lambda s, r: Denoise(
        r.raw.cfa if r.config.before_demosaic(s) else None,
        s.method,
        s.kernel,
        s.sigma,
        s.sigma_color,
    ),
    LensCorrectionStage: lambda s, r: LensCorrection(r.rgb_lens),
    ColorMatrixStage: lambda s, r: ColorMatrix(
        torch.as_tensor(r.color_matrix, dtype=torch.float32)
    ),
    ExposureStage: lambda s, r: Exposure(r.exposure_stops),
    ToneStage: lambda s, r: ToneCurve(s.curve, s.exposure, s.white_point),
    TransferStage: lambda s, r: Transfer(r.info["transfer"]),  # "auto" resolved
    YCbCrStage: lambda s, r: ColorSpaceConversion(),
    OrientationStage: lambda s, r: Orientation(r.raw.orientation),
}


def _demosaic(cfa: CFA, method: str, domain: str = "sqrt") -> nn.Module:
    """The demosaic stage of ``cfa``: a Bayer method as configured, or for other
    patterns (X-Trans) the X-Trans method it maps to (:data:`XTRANS_METHOD`), on
    square roots where ``domain`` is ``sqrt`` (:class:`RootDomain`); for ``half``,
    half-size binning."""
    if method == HALF_SIZE:
        return HalfSize(cfa)
    inner = Demosaic(cfa, method) if cfa.is_bayer else XTransDemosaic(cfa, XTRANS_METHOD[method])
    return RootDomain(inner) if domain == "sqrt" else inner


def _black_map(raw):
    """The black level as a number, or a tensor broadcastable to the data (B, C, H, W)."""
    black = np.asarray(raw.black_level, dtype=np.float64)
    if np.allclose(black, black.flat[0]):
        return float(black.flat[0])
    if raw.cfa is None:
        return torch.as_tensor(black, dtype=torch.float32).reshape(1, 3, 1, 1)
    return torch.as_tensor(black, dtype=torch.float32).reshape(1, 1, *raw.cfa.period)  # a tile
