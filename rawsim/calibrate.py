"""Noise calibration: estimate a sensor's noise parameters from its own raw files.

Two methods, both on the CFA planes (R, Gr, Gb, B) cut into square tiles:

* ``flat`` (photon transfer, EMVA 1288 style): flat-field frames, ideally with
  an illumination gradient or at several exposures, and optional dark frames.
  Each tile gives its mean signal above black and its variance after removing
  a fitted plane (illumination gradient) and the row offsets. Per ISO and
  channel, variance = K · mean + σ_read² + 1/12 is fitted robustly (medians in
  signal bins, weighted least squares, outliers dropped). Dark frames give
  σ_read, the row-noise σ (variance of full-width row means) and the read-noise
  shape λ (Tukey-lambda, probability-plot correlation maximum, as ELD).
* ``patches`` (less accurate): ordinary photos. Only the smoothest tiles of each
  signal bin are used: a low quantile of their variances, corrected for the
  quantile's bias under pure noise, stands in for the noise variance.

All values are in DN of the raw file; K in DN/e⁻.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from rawsim.errors import ParameterError
from rawsim.io.raw import RawImage
from rawsim.noise import QUANTIZATION_VARIANCE, tukey_lambda_quantile, tukey_lambda_variance

METHODS = ("flat", "patches")
CHANNELS = ("R", "Gr", "Gb", "B")
#: Tile side in plane pixels (flat frames); 2×2-block details per tile side (photos).
TILE = 32
PATCH_BLOCKS = 8
MAD_TO_SIGMA = 1.482602218505602
#: Quantile of tile variances used by the patch method, and the bins of signal.
PATCH_QUANTILE = 0.1
BINS = 48
#: Tiles whose brightest pixel reaches this fraction of the range are dropped.
SATURATION = 0.95
#: Smallest K written to a profile (DN/e⁻): noise-free data gives K ≈ 0.
MIN_GAIN = 1e-6
LAMBDA_GRID = np.round(np.arange(-0.45, 0.61, 0.01), 2)


@dataclass
class TileStats:
    """Per-tile statistics of one frame: arrays of shape (4, N) (channel, tile), DN.

    ``mean`` is above black; ``var`` the pixel variance without rows' offsets;
    ``row_var`` the variance of the rows' offsets; ``valid`` excludes saturated tiles.
    """

    mean: np.ndarray
    var: np.ndarray
    row_var: np.ndarray
    valid: np.ndarray


@dataclass
class IsoFit:
    """The fit at one ISO. Per-channel values are in R, Gr, Gb, B order."""

    iso: float
    K: float
    read_sigma: float
    row_sigma: float | None
    lam: float | None
    channels: dict = field(default_factory=dict)
    frames: int = 0
    darks: int = 0
    points: dict = field(default_factory=dict)  # for the plot: channel → (means, vars)

    @property
    def tukey_sigma(self) -> float | None:
        """Scale of the Tukey-lambda law with shape λ and standard deviation ``read_sigma``."""
        if self.lam is None:
            return None
        return self.read_sigma / math.sqrt(tukey_lambda_variance(self.lam))

    def to_dict(self) -> dict:
        return {
            "iso": self.iso,
            "K": self.K,
            "read_sigma": self.read_sigma,
            "row_sigma": self.row_sigma,
            "lambda": self.lam,
            "tukey_sigma": self.tukey_sigma,
            "channels": self.channels,
            "frames": self.frames,
            "dark_frames": self.darks,
        }


def planes_of(raw: RawImage) -> torch.Tensor:
    """The raw's planes above black, float64: (4, H/2, W/2) R, Gr, Gb, B, or (3, H, W)."""
    data = torch.from_numpy(raw.data.astype(np.float64))
    black = torch.as_tensor(np.asarray(raw.black_level, dtype=np.float64))
    if raw.cfa is None:
        return (data - black).permute(2, 0, 1)
    return (raw.cfa.pack(data[None, None]) - raw.cfa.pack(black[None, None]))[0]


def _tiles(x: torch.Tensor, size: int) -> torch.Tensor:
    """Whole ``size``×``size`` tiles of (C, H, W), row-major: (C, N, size, size)."""
    c, h, w = x.shape
    ny, nx = h // size, w // size
    if ny == 0 or nx == 0:
        raise ParameterError(f"image too small for {size}×{size} tiles per channel")
    x = x[:, : ny * size, : nx * size].reshape(c, ny, size, nx, size).permute(0, 1, 3, 2, 4)
    return x.reshape(c, ny * nx, size, size)


def tile_stats(planes: torch.Tensor, span: float, tile: int = TILE) -> TileStats:
    """Statistics of ``tile``×``tile`` tiles of ``planes`` (C, H, W) above black.

    A least-squares plane is removed from each tile first (illumination
    gradients); then the row means of the residual split its variance into the
    rows' offsets (``row_var``) and the rest (``var``).
    """
    x = _tiles(planes, tile)
    mean = x.mean(dim=(-2, -1))
    t = torch.arange(tile, dtype=x.dtype) - (tile - 1) / 2
    norm = float((t**2).sum()) * tile
    slope_i = (x * t[:, None]).sum(dim=(-2, -1)) / norm
    slope_j = (x * t[None, :]).sum(dim=(-2, -1)) / norm
    r = x - mean[..., None, None] - slope_i[..., None, None] * t[:, None]
    r = r - slope_j[..., None, None] * t[None, :]
    total = (r**2).sum(dim=(-2, -1)) / (tile * tile - 3)
    rows = r.mean(dim=-1)
    rows_var = (rows**2).sum(dim=-1) / (tile - 2)
    row_var = (rows_var - total / tile) / (1 - 1 / tile)  # unbiased; may be < 0
    peak = x.amax(dim=(-2, -1))
    valid = peak < SATURATION * span
    return TileStats(mean.numpy(), (total - row_var).numpy(), row_var.numpy(), valid.numpy())


def _line(m: np.ndarray, v: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    a = np.stack([m, np.ones_like(m)], 1) * np.sqrt(weights)[:, None]
    sol, *_ = np.linalg.lstsq(a, v * np.sqrt(weights), rcond=None)
    return float(sol[0]), float(sol[1])


def fit_variance_line(
    mean: np.ndarray,
    var: np.ndarray,
    quantile: float | None = None,
    correction: float = 1.0,
    rel_err: float = math.sqrt(2 / (TILE * TILE - 3)),
) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Fit variance = slope · mean + offset over tiles: (slope, offset, bin means, bin vars).

    Tiles are grouped in signal bins; a bin's variance is its median (flat frames)
    or its ``quantile`` divided by ``correction``, that quantile's value under pure
    noise (patch method); ``rel_err`` is a tile variance's relative standard error.
    Weighted least squares (weight ∝ count / variance²), then bins off
    the line by more than 4 expected standard errors are dropped and the line refit.
    """
    order = np.argsort(mean)
    mean, var = mean[order], var[order]
    edges = np.linspace(mean[0], mean[-1] + 1e-9, BINS + 1)
    which = np.clip(np.searchsorted(edges, mean, side="right") - 1, 0, BINS - 1)
    bm, bv, bn = [], [], []
    for b in range(BINS):
        sel = which == b
        n = int(sel.sum())
        if n < 3:
            continue
        bm.append(float(np.median(mean[sel])))
        if quantile is None:
            bv.append(float(np.median(var[sel])))
        else:
            bv.append(float(np.quantile(var[sel], quantile)) / correction)
        bn.append(n)
    bm, bv, bn = np.array(bm), np.array(bv), np.array(bn, dtype=np.float64)
    if len(bm) < 2 or bm[-1] - bm[0] <= 0:
        raise ParameterError(
            "the frames do not span a range of signal levels (need flats at several "
            "brightnesses, an illumination gradient, or varied photos)"
        )
    keep = np.ones(len(bm), dtype=bool)
    for _ in range(3):
        w = bn[keep] / np.maximum(bv[keep], 1e-12) ** 2
        slope, offset = _line(bm[keep], bv[keep], w)
        model = np.maximum(slope * bm + offset, 1e-12)
        err = model * rel_err / np.sqrt(bn)
        new = np.abs(bv - model) <= 4 * err + 0.02 * model
        if new.sum() < 2 or (new == keep).all():
            break
        keep = new
    return slope, offset, bm[keep], bv[keep]


def fit_lambda(residual: torch.Tensor, max_samples: int = 400_000, seed: int = 0) -> float:
    """Tukey-lambda shape of a zero-mean sample: the λ of largest probability-plot correlation."""
    x = residual.reshape(-1).to(torch.float64)
    if x.numel() > max_samples:
        idx = torch.randperm(x.numel(), generator=torch.Generator().manual_seed(seed))
        x = x[idx[:max_samples]]
    x, _ = torch.sort(x)
    n = x.numel()
    p = (torch.arange(1, n + 1, dtype=torch.float64) - 0.3175) / (n + 0.365)
    xc = (x - x.mean()) / x.std()
    best, best_r = 0.0, -2.0
    for lam in LAMBDA_GRID:
        q = tukey_lambda_quantile(p, float(lam))
        qc = (q - q.mean()) / q.std()
        r = float((xc * qc).mean())
        if r > best_r:
            best, best_r = float(lam), r
    return best


def dark_stats(planes: torch.Tensor) -> dict:
    """Read variance, row variance, bias and residual of one dark frame's planes (C, H, W)."""
    mean = planes.mean(dim=(-2, -1))
    x = planes - mean[:, None, None]
    w = x.shape[-1]
    rows = x.mean(dim=-1)
    total = x.var(dim=(-2, -1))
    row_var = (rows.var(dim=-1) - total / w).clamp_min(0) / (1 - 1 / w)
    residual = x - rows[..., None]
    return {
        "bias": mean.numpy(),
        "read_var": (total - row_var).numpy(),
        "row_var": row_var.numpy(),
        "residual": residual,
    }


def calibrate_iso(
    iso: float,
    flats: list[RawImage],
    darks: list[RawImage],
    method: str = "flat",
) -> IsoFit:
    """Fit one ISO from its frames (see the module docstring)."""
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    if method == "flat" and len(flats) + len(darks) < 2:
        raise ParameterError(
            f"ISO {iso:g}: {len(flats) + len(darks)} frame(s); the flat-field method needs at "
            "least 2 (flats at different exposures, or a flat and a dark frame)"
        )
    if not flats:
        raise ParameterError(f"ISO {iso:g}: no flat-field frames (only dark frames)")
    first = flats[0]
    span = float(first.white_level) - float(np.mean(first.black_level))
    tile = TILE
    if method == "flat":
        stats = [tile_stats(planes_of(r), span, tile) for r in flats]
    else:
        stats = [patch_stats(planes_of(r), span) for r in flats]
    dark_planes = [planes_of(r) for r in darks]
    dark_tiles = [tile_stats(p, span, tile) for p in dark_planes]
    dark = [dark_stats(p) for p in dark_planes]
    nch = stats[0].mean.shape[0]
    names = CHANNELS if nch == 4 else ("R", "G", "B")
    if method == "flat":
        fit_args = {"rel_err": math.sqrt(2 / (tile * tile - 3))}
    else:
        n = PATCH_BLOCKS**2
        fit_args = {
            "quantile": PATCH_QUANTILE,
            "correction": _mad_quantile_ratio(PATCH_QUANTILE, n),
            "rel_err": math.sqrt(2.7 / n),
        }
    channels, points = {}, {}
    all_m, all_v = [], []
    for c, name in enumerate(names):
        m = np.concatenate([s.mean[c][s.valid[c]] for s in stats])
        v = np.concatenate([s.var[c][s.valid[c]] for s in stats])
        if dark:  # dark tiles anchor the line at zero signal
            m = np.concatenate([m, *(s.mean[c] for s in dark_tiles)])
            v = np.concatenate([v, *(s.var[c] for s in dark_tiles)])
        if m.size < 8:
            raise ParameterError(f"ISO {iso:g}: too few unsaturated tiles ({m.size}) to fit")
        k, offset, bm, bv = fit_variance_line(m, v, **fit_args)
        read_var = (
            float(np.mean([d["read_var"][c] for d in dark])) if dark else offset
        ) - QUANTIZATION_VARIANCE
        channels[name] = {"K": k, "read_sigma": math.sqrt(max(read_var, 0.0))}
        if dark:
            channels[name]["bias"] = float(np.mean([d["bias"][c] for d in dark]))
        points[name] = (bm, bv)
        all_m.append(m)
        all_v.append(v)
    k, offset, _, _ = fit_variance_line(np.concatenate(all_m), np.concatenate(all_v), **fit_args)
    if dark:
        read_var = float(np.mean([d["read_var"].mean() for d in dark])) - QUANTIZATION_VARIANCE
        row_var = float(np.mean([d["row_var"].mean() for d in dark]))
        lam = fit_lambda(torch.cat([d["residual"].reshape(-1) for d in dark]))
    else:
        read_var = offset - QUANTIZATION_VARIANCE
        row_var = _row_var_from_tiles(stats, tile) if method == "flat" else None
        lam = None
    return IsoFit(
        iso=iso,
        K=k,
        read_sigma=math.sqrt(max(read_var, 0.0)),
        row_sigma=None if row_var is None else math.sqrt(row_var),
        lam=lam,
        channels=channels,
        frames=len(flats),
        darks=len(darks),
        points=points,
    )


def _row_var_from_tiles(stats: list[TileStats], tile: int) -> float:
    """Inverse-variance weighted mean of the tiles' row variances (weight ∝ (T / var)²)."""
    rv = np.concatenate([s.row_var[s.valid] for s in stats])
    w = 1 / np.maximum(np.concatenate([s.var[s.valid] for s in stats]) / tile, 1e-12) ** 2
    return max(float((rv * w).sum() / w.sum()), 0.0)


def patch_stats(planes: torch.Tensor, span: float, blocks: int = PATCH_BLOCKS) -> TileStats:
    """Noise variance of each tile of a photo by a robust high-pass (patch method).

    The diagonal Haar detail ``(a − b − c + d) / 2`` of each 2×2 block of a plane
    removes the local mean, linear gradients and row offsets; its variance is the
    pixel variance. Per tile of ``blocks``×``blocks`` details, the variance is
    estimated from the median absolute deviation, which ignores a few edges.
    """
    _, h, w = planes.shape
    x = planes[:, : h // 2 * 2, : w // 2 * 2]
    d = (x[:, 0::2, 0::2] - x[:, 0::2, 1::2] - x[:, 1::2, 0::2] + x[:, 1::2, 1::2]) / 2
    d = _tiles(d, blocks).flatten(-2)
    xt = _tiles(x, 2 * blocks).flatten(-2)
    mad = (d - d.median(dim=-1, keepdim=True).values).abs().median(dim=-1).values
    var = (MAD_TO_SIGMA * mad) ** 2
    valid = xt.amax(dim=-1) < SATURATION * span
    return TileStats(xt.mean(dim=-1).numpy(), var.numpy(), np.zeros(var.shape), valid.numpy())


def _mad_quantile_ratio(q: float, n: int, trials: int = 20_000) -> float:
    """The q-quantile of the MAD variance estimate over σ² for n normal samples."""
    g = torch.Generator().manual_seed(0)
    z = torch.randn(trials, n, generator=g, dtype=torch.float64)
    mad = (z - z.median(dim=-1, keepdim=True).values).abs().median(dim=-1).values
    return float(torch.quantile((MAD_TO_SIGMA * mad) ** 2, q))


def same_camera(raws: list[RawImage]) -> None:
    """Raise if the raws come from different cameras (make/model or CFA)."""
    ref = raws[0]
    for r in raws[1:]:
        if (r.make, r.model) != (ref.make, ref.model):
            raise ParameterError(
                f"{r.path}: camera {r.make} {r.model} differs from {ref.path} "
                f"({ref.make} {ref.model}); calibrate one camera at a time"
            )
        if r.cfa != ref.cfa or r.data.ndim != ref.data.ndim:
            raise ParameterError(f"{r.path}: CFA layout differs from {ref.path}")


def _loglinear(ks: list[float], sigmas: list[float]) -> dict:
    """ln σ = slope · ln K + bias by least squares (two or more points)."""
    lk, ls = np.log(ks), np.log(sigmas)
    slope, bias = np.polyfit(lk, ls, 1)
    return {"model": "loglinear", "slope": float(slope), "bias": float(bias)}


def build_profile(fits: list[IsoFit], raw: RawImage, name: str, method: str) -> dict:
    """A rawsim profile (JSON-ready) from per-ISO fits and one of the raws."""
    fits = sorted(fits, key=lambda f: f.iso)
    isos = [f.iso for f in fits]
    warnings = []
    for f in fits:
        if not f.K > MIN_GAIN:
            warnings.append(
                f"ISO {f.iso:g}: fitted K {f.K:.3g} DN/e⁻ (no measurable shot noise); "
                f"floored at {MIN_GAIN:g}"
            )
            f.K = MIN_GAIN * (1 + 1e-3 * len(warnings))  # keeps K increasing with ISO
    ks = [f.K for f in fits]
    how = (
        f"rawsim calibrate ({'flat-field' if method == 'flat' else 'smooth-patch, less accurate'}"
        f" method) on {sum(f.frames for f in fits)} frame(s)"
        + (f" and {sum(f.darks for f in fits)} dark frame(s)" if any(f.darks for f in fits) else "")
        + f" of this camera at ISO {', '.join(f'{i:g}' for i in isos)}"
    )
    single = len(fits) == 1
    if single:
        gain = {"model": "linear", "slope": ks[0] / isos[0], "intercept": 0.0}
    elif all(b > a for a, b in zip(ks, ks[1:], strict=False)):
        gain = {"model": "table", "iso": isos, "k": ks}
    else:
        raise ParameterError(
            "fitted K does not increase with ISO "
            + ", ".join(f"ISO {i:g}: {k:.4g}" for i, k in zip(isos, ks, strict=True))
        )

    def sigma_curve(values: list[float]) -> dict:
        if single or min(values) <= 0:
            return {"model": "table", "iso": isos, "sigma": [max(v, 1e-6) for v in values]}
        return _loglinear(ks, values)

    black = float(np.mean(raw.black_level))
    white = float(raw.white_level)
    bits = max(1, math.ceil(math.log2(white + 1)))
    xyz = raw.xyz_to_camera
    matrix_note = "the files' XYZ→camera matrix (LibRaw)"
    if xyz is None:
        xyz, matrix_note = np.eye(3), "identity: the files carry no colour matrix"
    noise = {"gain": gain, "read_sigma": sigma_curve([f.read_sigma for f in fits])}
    source = {
        "xyz_to_camera": matrix_note,
        "black_level": "the files' black level (LibRaw), mean over the CFA sites",
        "white_level": "the files' white level (LibRaw)",
        "iso_range": "the calibrated ISOs",
        "noise.gain": how,
        "noise.read_sigma": how + ("; σ from dark frames" if fits[0].darks else ""),
    }
    if all(f.lam is not None and f.row_sigma for f in fits):
        noise["tukey_sigma"] = sigma_curve([f.tukey_sigma for f in fits])
        noise["tukey_lambda"] = {"k": ks, "lambda": [f.lam for f in fits]}
        noise["row_sigma"] = sigma_curve([f.row_sigma for f in fits])
        bias = [np.mean([f.channels[c]["bias"] for f in fits]) for c in CHANNELS]
        noise["channel_bias"] = [float(b) for b in bias]
        for key in ("tukey_sigma", "tukey_lambda", "row_sigma", "channel_bias"):
            source[f"noise.{key}"] = how + "; from the dark frames"
    return {
        "name": name,
        "make": raw.make,
        "model": raw.model,
        "cfa_pattern": raw.cfa.pattern if raw.cfa is not None else "RGGB",
        "bit_depth": bits,
        "black_level": black,
        "white_level": white,
        "xyz_to_camera": [[float(v) for v in row] for row in np.asarray(xyz)],
        "iso_range": [isos[0], isos[-1]],
        "base_iso": isos[0],
        "noise": noise,
        "source": source,
        "calibration": [f.to_dict() for f in fits],
        "warnings": warnings,
    }
