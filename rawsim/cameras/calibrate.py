"""Noise calibration: estimate a sensor's noise parameters from its own raw files.

Frames are read one at a time and reduced to statistics of small blocks of their
CFA's phase planes, so memory does not grow with the number of frames. A phase
plane holds one site of the CFA period in every period (``m[r::ph, c::pw]``): R,
Gr, Gb and B for Bayer; the 36 sites of a 6×6 X-Trans period, pooled by colour
(8 R, 20 G, 8 B), or those of any periodic layout. Per ISO and channel, block
variance = K · mean + σ_read² + 1/12 is fitted over signal bins (log-spaced),
by weighted least squares with outlier bins dropped, in two passes: the second
normalises each block by the first line, so a bin's spread of levels does not
bias it, and drops blocks within 5 σ of the white level (clipping lowers the
variance). Every figure gets a standard error from a bootstrap over image
regions (4×4 per frame) or, for dark frames, over bands.

* ``flat`` (photon transfer, EMVA 1288 style): flat-field frames, ideally with
  an illumination gradient or at several exposures, and optional dark frames.
  A 32×32 tile's variance is taken after removing a fitted plane (illumination
  gradient) and its rows' offsets; a bin's value is the median. Frames are
  checked to be flat: a tile's variance must match its pixel noise measured by
  the high-pass below, which scene structure does not reach.
* ``patches``: ordinary photos, after Foi et al., "Practical Poissonian-Gaussian
  noise modeling and fitting for single-image raw-data", IEEE TIP 17(10), 2008:
  local means and finest-scale detail coefficients, grouped in level sets of the
  mean, then a line fit. Here the detail is a separable 4th-order difference
  ``[1 −4 6 −4 1]/√70`` along both axes (unit gain on white noise; it removes
  cubic trends and row or column offsets), and the smooth parts of each level
  set are its weak-texture 8×8 blocks, as in Liu, Tanaka & Okutomi, "Single-image
  noise level estimation for blind denoising", IEEE TIP 22(12), 2013: the 5 %
  quantile of the blocks' detail variance, divided by that quantile's value
  under pure noise (simulated). Texture only adds variance, so the low tail is
  the noise. Clipped blocks are excluded rather than modelled.

Dark frames give the read σ, the row σ (variance of full-width row means), the
per-channel bias and the read-noise shape λ (Tukey-lambda, largest
probability-plot correlation, as ELD). Fits that cannot be trusted (frames that
are not flat fields, too few signal levels, no shot noise, a negative read
variance, a poor line fit, dark frames that are not dark) are listed in
:attr:`IsoFit.problems`; the command refuses to write them.

All values are in DN of the raw file; K in DN/e⁻.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from rawsim.cameras.profiles import NO_MATRIX
from rawsim.errors import ParameterError, RawsimError
from rawsim.io.raw import RawImage, xyz_to_camera_of
from rawsim.noise.spec import QUANTIZATION_VARIANCE, tukey_lambda_variance

METHODS = ("flat", "patches")
#: The channels of a profile's ``noise.channel_bias`` (a Bayer CFA's; see :func:`_bias`).
CHANNELS = ("R", "Gr", "Gb", "B")
#: Tile side of the flat method and block side of the patch method (plane pixels).
TILE = 32
BLOCK = 8
#: A flat tile spans at most this many sensor pixels a side (the plane removed from a
#: tile cancels an illumination gradient's linear part only; what curves across it
#: grows with its footprint), but keeps at least MIN_TILE plane pixels a side (a tile's
#: median variance is biased low by ~2/(9·dof)): 32 for Bayer (64 pixels), 16 for
#: X-Trans (96 pixels; 32 would span 192 and overestimate K by 4 % at low ISO).
TILE_FOOTPRINT = 96
MIN_TILE = 16
#: The high-pass of the patch method and the flatness check (unit white-noise gain).
HIGH_PASS = np.array([1.0, -4.0, 6.0, -4.0, 1.0]) / math.sqrt(70.0)
#: Orders of the patch method's further detail filters (its systematic checks): scene
#: texture reaches a 6th- and an 8th-order difference less and less (by how much depends
#: on the texture's spectrum: fine texture reaches them nearly as much), noise equally.
#: K's systematic error is its largest distance from the K these give (issue 42: the
#: 6th order alone caught too little of fine texture's bias on unseen photos).
CHECK_ORDERS = (6, 8)
#: Quantile of block variances taken as the noise in a level set (patch method).
PATCH_QUANTILE = 0.05
#: Signal bins (log-spaced) and the fewest blocks a bin needs.
BINS = 16
MIN_BIN = {"flat": 3, "patches": 50}
#: Bootstrap: regions per frame side, resamples.
REGIONS = 4
RESAMPLES = 32
#: Blocks whose brightest pixel reaches this fraction of the range are dropped (first pass).
SATURATION = 0.95
#: A flat frame's median tile variance may exceed its high-pass noise by this factor.
FLATNESS = 1.5
#: A dark frame's mean may exceed black by this fraction of the range.
DARK_LEVEL = 0.005
#: Fewest usable signal bins, and the least ratio of the brightest to the darkest level.
MIN_LEVELS = 4
MIN_LEVEL_RATIO = 3.0
#: Largest plausible full well (e⁻): K below range / this is no measured shot noise.
MAX_FULL_WELL = 1e6
#: Largest relative standard error of K that is written without --force.
MAX_K_ERROR = 0.25
#: Dark-frame residual samples kept per frame for the λ fit.
LAMBDA_SAMPLES = 200_000
LAMBDA_GRID = np.round(np.arange(-0.45, 0.61, 0.01), 2)


class CalibrationRefused(RawsimError):
    """The frames do not support a trustworthy fit; ``problems`` says why."""

    def __init__(self, problems: list[str]):
        super().__init__("; ".join(problems))
        self.problems = problems


@dataclass(frozen=True)
class Camera:
    """What must agree between the frames of one calibration."""

    make: str
    model: str
    cfa: str | None
    ndim: int

    def describe(self) -> str:
        return f"{self.make} {self.model}".strip() or "unknown camera"


@dataclass
class FrameStats:
    """One frame reduced to block statistics; arrays have shape (C, N), DN above black
    (float32: about a tenth of the frame's size is kept per frame), one row per
    phase plane, ``channels`` (C,) naming each plane's colour channel.

    ``var`` is each block's noise variance estimate, ``row_var`` the variance of
    its rows' offsets (flat method) and ``group`` (N,) its region for the
    bootstrap. ``var_check`` (E, C, N) holds further estimates of each block's
    noise variance that the method's known bias reaches differently: the
    high-pass noise of a flat tile (which an illumination's curvature does not
    reach; E = 1), the :data:`CHECK_ORDERS` details of a patch block (which scene
    texture reaches less and less; E = 2); the largest distance of K from the K
    each of these gives is the fit's systematic error.
    ``tile`` is the flat method's tile side (:func:`tile_side`). ``flatness`` is
    the median ratio of tile variance to high-pass noise (flat method; ≈ 1 for a
    flat field).
    """

    path: str
    iso: float
    camera: Camera
    black: float
    white: float
    xyz_to_camera: np.ndarray | None
    channels: tuple[str, ...]
    mean: np.ndarray
    var: np.ndarray
    row_var: np.ndarray | None
    valid: np.ndarray
    group: np.ndarray
    var_check: np.ndarray
    flatness: float | None = None
    tile: int = TILE
    #: Where ``xyz_to_camera`` comes from (:func:`rawsim.io.raw.xyz_to_camera_of`).
    matrix_source: str = ""

    @property
    def span(self) -> float:
        return self.white - self.black


@dataclass
class DarkStats:
    """A dark frame per phase plane (``channels`` names each plane's colour): bias, and
    read and row variance per horizontal band (C, B)."""

    path: str
    iso: float
    camera: Camera
    channels: tuple[str, ...]
    bias: np.ndarray
    read_var: np.ndarray
    row_var: np.ndarray
    residual: np.ndarray  # a deterministic subsample of the pixels minus their row means
    mean_above_black: float


@dataclass
class IsoFit:
    """The fit at one ISO. Per-channel values (``channels``) are keyed by the CFA's
    channels: R, Gr, Gb, B for Bayer, R, G, B for any other layout (X-Trans) and for
    3-channel data.

    ``errors`` holds the standard error of K, read_sigma, row_sigma and lambda;
    those of K and (without dark frames) read_sigma are the statistical error (a
    bootstrap, under ``K_statistical``) and the systematic error (the largest
    distance from the fit of the method's further variance estimators,
    :attr:`FrameStats.var_check`, under ``K_systematic``) in quadrature.
    ``problems`` says why the fit is not to be trusted (empty when it is).
    """

    iso: float
    K: float
    read_sigma: float
    row_sigma: float | None
    lam: float | None
    errors: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    frames: int = 0
    darks: int = 0
    problems: list = field(default_factory=list)
    points: dict = field(default_factory=dict)  # for the plot: channel → (means, vars, errors)

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
            "uncertainty": self.errors,
            "channels": self.channels,
            "frames": self.frames,
            "dark_frames": self.darks,
            "reliable": not self.problems,
            "problems": self.problems,
        }


# ---------------------------------------------------------------- frame statistics


def planes_of(raw: RawImage) -> tuple[np.ndarray, tuple[str, ...]]:
    """The raw's planes above black (float64) and each plane's colour channel.

    A CFA mosaic gives its phase planes (:attr:`~rawsim.cfa.CFA.phase_sites`), cut to
    whole periods, each less its site's black level: (4, H/2, W/2) named R, Gr, Gb,
    B for Bayer; (36, H/6, W/6) named R, G or B for X-Trans
    (:attr:`~rawsim.cfa.CFA.phase_channels`). Data without a CFA: (3, H, W) named
    R, G, B, or (1, H, W) named Y.
    """
    data = raw.data.astype(np.float64)
    black = np.asarray(raw.black_level, dtype=np.float64)
    if raw.cfa is None:
        names = ("R", "G", "B") if data.shape[-1] == 3 else ("Y",) * data.shape[-1]
        return np.moveaxis(data - black, -1, 0), names
    ph, pw = raw.cfa.period
    h, w = data.shape[0] // ph * ph, data.shape[1] // pw * pw
    black = np.broadcast_to(black, (ph, pw))
    planes = np.stack([data[i:h:ph, j:w:pw] - black[i, j] for i, j in raw.cfa.phase_sites])
    return planes, raw.cfa.phase_channels


def difference_kernel(order: int) -> np.ndarray:
    """The ``order``-th finite difference, unit gain on white noise: (order + 1,).

    Order 4 is :data:`HIGH_PASS`; it removes polynomial trends of degree < order.
    """
    k = np.array([(-1.0) ** i * math.comb(order, i) for i in range(order + 1)])
    return k / math.sqrt(math.comb(2 * order, order))


def high_pass(x: np.ndarray, order: int = 4) -> np.ndarray:
    """The ``order``-th difference (:func:`difference_kernel`) along both of the last
    two axes, valid part only: (…, H − order, W − order)."""
    k = difference_kernel(order)
    h, w = x.shape[-2:]
    y = sum(k[i] * x[..., i : h - order + i, :] for i in range(order + 1))
    return sum(k[j] * y[..., :, j : w - order + j] for j in range(order + 1))


def _check_detail(planes: np.ndarray, order: int) -> np.ndarray:
    """The ``order``-th detail of (C, H, W) on the 4th-order detail's pixels:
    (C, H − 4, W − 4); the planes are mirrored at the edges for the extra support."""
    pad = (order - 4) // 2
    return high_pass(np.pad(planes, ((0, 0), (pad, pad), (pad, pad)), mode="reflect"), order)


def _blocks(x: np.ndarray, size: int) -> np.ndarray:
    """Whole ``size``×``size`` blocks of (C, H, W), row-major: (C, ny, nx, size, size)."""
    c, h, w = x.shape
    ny, nx = h // size, w // size
    if ny == 0 or nx == 0:
        raise ParameterError(f"image too small for {size}×{size} blocks per channel")
    x = x[:, : ny * size, : nx * size].reshape(c, ny, size, nx, size)
    return x.transpose(0, 1, 3, 2, 4)


def _regions(ny: int, nx: int) -> np.ndarray:
    """Region index (REGIONS × REGIONS grid) of each block of an ny × nx grid: (ny·nx,)."""
    ry = np.arange(ny) * REGIONS // ny
    rx = np.arange(nx) * REGIONS // nx
    return (ry[:, None] * REGIONS + rx[None, :]).reshape(-1)


def camera_of(raw: RawImage) -> Camera:
    return Camera(raw.make, raw.model, raw.cfa.pattern if raw.cfa else None, raw.data.ndim)


def tile_side(cfa) -> int:
    """The flat method's tile side in plane pixels for a raw of ``cfa`` (None: no CFA):
    :data:`TILE`, cut so the tile spans at most :data:`TILE_FOOTPRINT` sensor pixels,
    down to :data:`MIN_TILE`."""
    period = 1 if cfa is None else max(cfa.period)
    return max(MIN_TILE, min(TILE, TILE_FOOTPRINT // period))


def frame_stats(raw: RawImage, method: str, iso: float | None = None) -> FrameStats:
    """Block statistics of one flat frame (``flat``) or photo (``patches``)."""
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    planes, channels = planes_of(raw)
    black = float(np.mean(raw.black_level))
    span = float(raw.white_level) - black
    floor = -np.asarray(raw.black_level, dtype=np.float64).min()  # raw DN 0, above black
    tile = tile_side(raw.cfa)
    if method == "flat":
        x = _blocks(planes, tile)
        stats = _tile_stats(x)
        peak, low = x.max(axis=(-2, -1)), x.min(axis=(-2, -1))
        hp = (high_pass(x) ** 2).mean(axis=(-2, -1))
        ratio = stats[1] / np.maximum(hp, 1e-12)
        mean, var, row_var = stats
        checks = [hp]
    else:
        d = _blocks(high_pass(planes), BLOCK)
        support = _blocks(planes[:, 2:-2, 2:-2], BLOCK)
        var = (d**2).mean(axis=(-2, -1))
        checks = [
            (_blocks(_check_detail(planes, order), BLOCK) ** 2).mean(axis=(-2, -1))
            for order in CHECK_ORDERS
        ]
        mean = support.mean(axis=(-2, -1))
        peak, low = _block_extremes(planes, d.shape[1], d.shape[2])
        row_var, ratio = None, None
    ny, nx = mean.shape[1:]
    valid = (peak < SATURATION * span) & (low > floor)
    flat = lambda a: a.reshape(a.shape[0], -1)  # noqa: E731
    flatness = None
    if ratio is not None:
        ok = flat(valid)
        flatness = float(np.median(flat(ratio)[ok])) if ok.any() else math.inf
    xyz, xyz_from = xyz_to_camera_of(raw)
    return FrameStats(
        path=str(raw.path),
        iso=float(iso or raw.iso),
        camera=camera_of(raw),
        black=black,
        white=float(raw.white_level),
        xyz_to_camera=xyz,
        matrix_source=xyz_from,
        channels=channels,
        mean=flat(mean).astype(np.float32),  # statistics: float32 halves what is kept
        var=flat(var).astype(np.float32),
        row_var=None if row_var is None else flat(row_var).astype(np.float32),
        valid=flat(valid),
        group=_regions(ny, nx).astype(np.int32),
        var_check=np.stack([flat(c) for c in checks]).astype(np.float32),
        flatness=flatness,
        tile=tile,
    )


def _block_extremes(planes: np.ndarray, ny: int, nx: int) -> tuple[np.ndarray, np.ndarray]:
    """Max and min of each patch block's high-pass support, (C, ny, nx) each.

    Block (i, j) reads plane rows and columns [8i, 8i + 12): the 4×4 chunks
    2i, 2i + 1 and 2i + 2 along each axis.
    """
    c = planes.shape[0]
    chunks = planes[:, : 4 * (2 * ny + 1), : 4 * (2 * nx + 1)]
    chunks = chunks.reshape(c, 2 * ny + 1, 4, 2 * nx + 1, 4)

    def pool(a, f):
        a = f(f(a[:, 0:-2:2], a[:, 1:-1:2]), a[:, 2::2])
        return f(f(a[:, :, 0:-2:2], a[:, :, 1:-1:2]), a[:, :, 2::2])

    return (
        pool(chunks.max(axis=(2, 4)), np.maximum),
        pool(chunks.min(axis=(2, 4)), np.minimum),
    )


def _tile_stats(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, variance without rows' offsets and row-offset variance of tiles (…, T, T).

    A least-squares plane is removed from each tile first (illumination
    gradients); the row means of the residual then split its variance.
    """
    tile = x.shape[-1]
    mean = x.mean(axis=(-2, -1))
    t = np.arange(tile, dtype=np.float64) - (tile - 1) / 2
    norm = float((t**2).sum()) * tile
    slope_i = (x * t[:, None]).sum(axis=(-2, -1)) / norm
    slope_j = (x * t[None, :]).sum(axis=(-2, -1)) / norm
    r = x - mean[..., None, None] - slope_i[..., None, None] * t[:, None]
    r = r - slope_j[..., None, None] * t[None, :]
    total = (r**2).sum(axis=(-2, -1)) / (tile * tile - 3)
    rows = r.mean(axis=-1)
    rows_var = (rows**2).sum(axis=-1) / (tile - 2)
    row_var = (rows_var - total / tile) / (1 - 1 / tile)  # unbiased; may be < 0
    return mean, total - row_var, row_var


def dark_stats(raw: RawImage, iso: float | None = None, bands: int = 16) -> DarkStats:
    """Bias, read and row variance per horizontal band, and a residual sample of a dark frame."""
    planes, channels = planes_of(raw)
    c, h, w = planes.shape
    bands = max(1, min(bands, h // 8))
    edges = np.linspace(0, h, bands + 1).astype(int)
    bias, read_var, row_var = (np.empty((c, bands)) for _ in range(3))
    for b in range(bands):
        x = planes[:, edges[b] : edges[b + 1]]
        m = x.mean(axis=(-2, -1))
        r = x - m[:, None, None]
        rows = r.mean(axis=-1)
        total = r.reshape(c, -1).var(axis=-1, ddof=1)
        rv = (rows.var(axis=-1, ddof=1) - total / w) / (1 - 1 / w)
        bias[:, b], read_var[:, b], row_var[:, b] = m, total - rv, rv
    residual = (planes - planes.mean(axis=-1, keepdims=True)).reshape(-1)
    rng = np.random.default_rng(0)
    if residual.size > LAMBDA_SAMPLES:
        residual = residual[rng.choice(residual.size, LAMBDA_SAMPLES, replace=False)]
    return DarkStats(
        path=str(raw.path),
        iso=float(iso or raw.iso),
        camera=camera_of(raw),
        channels=channels,
        bias=bias,
        read_var=read_var,
        row_var=row_var,
        residual=residual.copy(),
        mean_above_black=float(planes.mean()),
    )


def same_camera(frames: list) -> None:
    """Raise if the frames come from different cameras (make/model or CFA)."""
    ref = frames[0]
    for f in frames[1:]:
        if (f.camera.make, f.camera.model) != (ref.camera.make, ref.camera.model):
            raise ParameterError(
                f"{f.path}: camera {f.camera.describe()} differs from {ref.path} "
                f"({ref.camera.describe()}); calibrate one camera at a time"
            )
        if f.camera != ref.camera:
            raise ParameterError(f"{f.path}: CFA layout differs from {ref.path}")


# ---------------------------------------------------------------- line fits


@functools.cache
def pure_noise_quantile(q: float = PATCH_QUANTILE, order: int = 4) -> float:
    """The q-quantile of a patch block's ``order``-th detail variance over σ² under white
    Gaussian noise."""
    rng = np.random.default_rng(0)
    z = rng.standard_normal((16, order + 32 * BLOCK, order + 32 * BLOCK))
    v = (_blocks(high_pass(z, order), BLOCK) ** 2).mean(axis=(-2, -1))
    return float(np.quantile(v, q))


def _bin_statistic(method: str, check: int | None = None) -> tuple[float, float]:
    """(quantile, divisor) of a bin's variances (of ``var``, or of ``var_check[check]``)
    that estimates its noise variance."""
    if method == "flat":
        return 0.5, 1.0
    order = 4 if check is None else CHECK_ORDERS[check]
    return PATCH_QUANTILE, pure_noise_quantile(PATCH_QUANTILE, order)


@dataclass
class Line:
    """variance = slope · mean + offset, with the bins it was fitted on (NaN: empty or dropped)."""

    slope: float
    offset: float
    bins: np.ndarray  # (BINS,) bin variance (DN²)
    levels: np.ndarray  # (BINS,) bin mean level (DN)
    #: (BINS,) the bins with enough blocks to be fitted (None: unknown); those of them
    #: that are NaN in ``bins`` were dropped as off the line.
    usable: np.ndarray | None = None
    #: K's distance from the line through every usable bin, the dropped ones too (patch
    #: method: a shot of few large flat patches, such as a colour chart, puts each bin on
    #: a few patches, and a bin off the line is then a patch's own bias, not an outlier).
    spread: float = 0.0


def _bin_edges(mean: np.ndarray) -> np.ndarray:
    """A bin for levels ≤ 0 (dark frames), then BINS log-spaced bins over the positive levels."""
    pos = mean[mean > 0]
    if pos.size == 0:
        return np.array([-np.inf, np.inf])
    lo, hi = float(pos.min()), float(pos.max())
    edges = np.geomspace(lo, hi * (1 + 1e-9), BINS + 1) if hi > lo else np.array([lo, hi + 1])
    return np.concatenate([[-np.inf], edges])


class _Bins:
    """Blocks sorted by (bin, value) once, for weighted bin quantiles (bootstrap weights)."""

    def __init__(self, mean: np.ndarray, value: np.ndarray, edges: np.ndarray, q: float):
        self.nbins = len(edges) - 1
        which = np.clip(np.searchsorted(edges, mean, side="right") - 1, 0, self.nbins - 1)
        self.order = np.lexsort((value, which))
        self.which, self.mean, self.value, self.q = which, mean, value[self.order], q
        self.ends = np.searchsorted(which[self.order], np.arange(self.nbins + 1))

    def __call__(self, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per bin: weighted mean level, weighted q-quantile of the values, total weight."""
        n = self.nbins
        total = np.bincount(self.which, weights, minlength=n)
        level = np.bincount(self.which, weights * self.mean, minlength=n) / np.maximum(total, 1e-12)
        cum = np.concatenate([[0.0], np.cumsum(weights[self.order])])
        target = cum[self.ends[:-1]] + self.q * total
        idx = np.clip(np.searchsorted(cum, target, side="left") - 1, 0, self.value.size - 1)
        return level, self.value[idx], total


def _line_from_bins(
    levels: np.ndarray,
    values: np.ndarray,
    counts: np.ndarray,
    method: str,
    tile: int = TILE,
    drop: bool = True,
) -> Line:
    """Weighted least squares (weight ∝ count / variance²), dropping bins off the line by
    more than 4 expected standard errors (+2 %) and refitting (not without ``drop``)."""
    ok = (counts >= MIN_BIN[method]) & np.isfinite(values)
    values = np.where(ok, values, np.nan)
    levels = np.where(counts > 0, levels, np.nan)
    if ok.sum() < 2:
        return Line(math.nan, math.nan, values, levels, ok)
    rel_err = math.sqrt(2 / (tile * tile - 3)) if method == "flat" else math.sqrt(2.7 / BLOCK**2)
    keep = ok.copy()
    for _ in range(3 if drop else 1):
        w = counts[keep] / np.maximum(values[keep], 1e-12) ** 2
        slope, offset = _weighted_line(levels[keep], values[keep], w)
        if not drop:
            break
        model = np.maximum(slope * levels + offset, 1e-12)
        err = model * rel_err / np.sqrt(np.maximum(counts, 1))
        new = ok & (np.abs(values - model) <= 4 * err + 0.02 * model)
        if new.sum() < 2 or (new == keep).all():
            break
        keep = new
    return Line(slope, offset, np.where(keep, values, np.nan), levels, ok)


def _weighted_line(m: np.ndarray, v: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    a = np.stack([m, np.ones_like(m)], 1) * np.sqrt(w)[:, None]
    sol, *_ = np.linalg.lstsq(a, v * np.sqrt(w), rcond=None)
    return float(sol[0]), float(sol[1])


@dataclass
class ChannelData:
    """Blocks of one channel (or all channels) over the frames of one ISO."""

    mean: np.ndarray
    var: np.ndarray
    group: np.ndarray  # bootstrap unit: frame × region
    tile: int = TILE  # the flat tiles' side (plane pixels): their variances' precision
    check: np.ndarray | None = None  # (E, N) further variance estimates (FrameStats.var_check)


def fit_with_errors(data: ChannelData, method: str, span: float) -> tuple[Line, np.ndarray, Line]:
    """The line of ``data``, its bootstrap and its check: (line, (RESAMPLES, 2 + BINS)
    draws, the check line).

    The first pass bins the raw variances. The second bins each block's
    variance over the first line at its level, scaled back at the bin's level,
    and drops blocks within 5 σ of the white level. The bootstrap resamples the
    groups (weights on the second pass); each draw row holds slope, offset and
    the bin values. A line is fitted to each row of ``data.check`` by the second
    pass (the same blocks, bins and first line); the check line is the one whose
    slope is farthest from the line's, NaN without checks or if any gives no line.
    """
    edges = _bin_edges(data.mean)
    q, divisor = _bin_statistic(method)
    ones = np.ones(data.mean.size)
    level, value, count = _Bins(data.mean, data.var, edges, q)(ones)
    first = _line_from_bins(level, value / divisor, count, method, data.tile)
    draws = np.full((RESAMPLES, 2 + len(edges) - 1), np.nan)
    unchecked = Line(math.nan, math.nan, first.bins, first.levels)
    if not math.isfinite(first.slope):
        return first, draws, unchecked
    model = np.maximum(first.slope * data.mean + first.offset, 1e-12)
    keep = data.mean + 5 * np.sqrt(model) < span

    def binned(var: np.ndarray) -> _Bins:
        return _Bins(data.mean[keep], var[keep] / model[keep], edges, q)

    def second(
        bins: _Bins, weights: np.ndarray, divisor: float = divisor, drop: bool = True
    ) -> Line:
        level, ratio, count = bins(weights)
        at = np.maximum(first.slope * level + first.offset, 1e-12)
        return _line_from_bins(level, ratio / divisor * at, count, method, data.tile, drop)

    bins, group = binned(data.var), data.group[keep]
    line = second(bins, np.ones(group.size))
    if method == "patches" and math.isfinite(line.slope):
        whole = second(bins, np.ones(group.size), drop=False)
        if math.isfinite(whole.slope):
            line.spread = abs(whole.slope - line.slope)
    check = unchecked
    if data.check is not None:
        checks = [
            second(binned(var), np.ones(group.size), _bin_statistic(method, e)[1])
            for e, var in enumerate(data.check)
        ]
        if all(math.isfinite(c.slope) for c in checks):
            check = max(checks, key=lambda c: abs(c.slope - line.slope))
    groups, inverse = np.unique(group, return_inverse=True)
    rng = np.random.default_rng(12345)
    for r in range(RESAMPLES):
        picks = np.bincount(rng.integers(0, groups.size, groups.size), minlength=groups.size)
        b = second(bins, picks[inverse].astype(np.float64))
        draws[r] = [b.slope, b.offset, *b.bins]
    return line, draws, check


def _std(x: np.ndarray) -> float:
    """Sample standard deviation of the finite values (NaN with fewer than 2)."""
    x = x[np.isfinite(x)]
    return float(np.std(x, ddof=1)) if x.size > 1 else math.nan


def _column_std(draws: np.ndarray) -> np.ndarray:
    """:func:`_std` of each column."""
    return np.array([_std(column) for column in draws.T])


def fit_lambda(residual: np.ndarray, max_samples: int = 400_000, seed: int = 0) -> float:
    """Tukey-lambda shape of a zero-mean sample: the λ of :data:`LAMBDA_GRID` of largest
    probability-plot correlation (the sorted sample against the law's quantiles at the
    plotting positions). One pass per λ: the quantiles' logs are shared, and the
    correlation is Σ x̂·q / (n·σ_q) with x̂ the standardised sample (mean 0)."""
    import torch

    from rawsim.noise.models import tukey_from_logs  # torch: only when dark frames are given

    x = np.asarray(residual, dtype=np.float64).reshape(-1)
    if x.size > max_samples:
        x = x[np.random.default_rng(seed).choice(x.size, max_samples, replace=False)]
    x = np.sort(x)
    n = x.size
    p = torch.from_numpy((np.arange(1, n + 1) - 0.3175) / (n + 0.365))
    low, high = p.log(), p.neg().log1p_()
    xc = torch.from_numpy((x - x.mean()) / x.std())
    xc -= xc.mean()  # exactly centred in float64, so Σ x̂·(q − q̄) = Σ x̂·q
    best, best_r = 0.0, -2.0
    for lam in LAMBDA_GRID:
        q = tukey_from_logs(low, high, float(lam))
        r = float(torch.dot(xc, q) / (n * q.std(correction=0)))
        if r > best_r:
            best, best_r = float(lam), r
    return best


# ---------------------------------------------------------------- one ISO


def calibrate_iso(
    iso: float, flats: list[FrameStats], darks: list[DarkStats], method: str = "flat"
) -> IsoFit:
    """Fit one ISO from its frames' statistics; problems are listed, not raised."""
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    if not flats:
        raise ParameterError(f"ISO {iso:g}: no flat-field frames (only dark frames)")
    if method == "flat" and len(flats) + len(darks) < 2:
        raise ParameterError(
            f"ISO {iso:g}: {len(flats) + len(darks)} frame(s); the flat-field method needs at "
            "least 2 (flats at different exposures, or a flat and a dark frame)"
        )
    problems = []
    span = flats[0].span
    if method == "flat":
        for f in flats:
            if f.flatness > FLATNESS:
                problems.append(
                    f"{f.path} is not a flat field (its tiles vary {f.flatness:.3g}× more than "
                    "its pixel noise: scene structure); shoot an evenly lit, defocused, "
                    "featureless surface, or use --method patches for ordinary photos"
                )
    for d in darks:
        if d.mean_above_black > DARK_LEVEL * span:
            problems.append(
                f"{d.path} is not a dark frame ({d.mean_above_black:.4g} DN above black, over "
                f"{DARK_LEVEL:.1%} of the range); shoot with the lens cap on at the same ISO"
            )
    planes = channel_planes(flats[0].channels)
    names = tuple(planes)
    per_channel = []
    for idx in planes.values():  # the phase planes of one colour channel, pooled
        m = [f.mean[c][f.valid[c]] for f in flats for c in idx]
        v = [f.var[c][f.valid[c]] for f in flats for c in idx]
        g = [f.group[f.valid[c]] + i * REGIONS**2 for i, f in enumerate(flats) for c in idx]
        check = [f.var_check[:, c][:, f.valid[c]] for f in flats for c in idx]
        estimators = flats[0].var_check.shape[0]
        if method == "flat":  # dark frames' tiles anchor all lines at zero signal
            for i, d in enumerate(darks):
                for c in idx:
                    m.append(np.zeros(d.read_var.shape[1]))
                    v.append(d.read_var[c])
                    check.append(np.broadcast_to(d.read_var[c], (estimators, d.read_var.shape[1])))
                    g.append(np.arange(d.read_var.shape[1]) + (len(flats) + i) * REGIONS**2)
        m, v, g = (np.concatenate(a) for a in (m, v, g))
        check = np.concatenate(check, axis=-1)
        per_channel.append(ChannelData(m, v, g, flats[0].tile, check))
    if min(d.mean.size for d in per_channel) < 8:
        raise CalibrationRefused(
            [f"ISO {iso:g}: too few unsaturated blocks to fit; expose the frames below white"]
        )
    pooled = {k: np.concatenate([getattr(d, k) for d in per_channel], -1) for k in _POOLED}
    line, draws, check = fit_with_errors(ChannelData(**pooled, tile=flats[0].tile), method, span)
    channels, points = {}, {}
    for name, data in zip(names, per_channel, strict=True):
        ch, ch_draws, ch_check = fit_with_errors(data, method, span)
        channels[name] = {
            "K": ch.slope,
            "K_error": math.hypot(_std(ch_draws[:, 0]), ch.slope - ch_check.slope, ch.spread),
            "read_sigma": math.sqrt(max(ch.offset - QUANTIZATION_VARIANCE, 0.0)),
        }
        ok = np.isfinite(ch.bins)
        points[name] = (ch.levels[ok], ch.bins[ok], _column_std(ch_draws[:, 2:])[ok])
    k_stat, k_sys = _std(draws[:, 0]), abs(line.slope - check.slope)
    if method == "patches":  # a chart's few patches: their bins' and channels' spread
        k_sys = math.hypot(k_sys, line.spread, _channel_spread(channels))
    errors = {"K": math.hypot(k_stat, k_sys), "K_statistical": k_stat, "K_systematic": k_sys}
    problems += _line_problems(line, draws, darks, span, errors["K"])
    if math.isfinite(line.slope) and not math.isfinite(check.slope):
        problems.append(
            f"a further variance estimator ({_CHECKS[method]}) gives no line, so K's "
            "systematic error is unknown; " + _LEVELS_HINT
        )
    if darks:
        read_var = np.concatenate([d.read_var.mean(axis=0) for d in darks])
        row_var = np.concatenate([d.row_var.mean(axis=0) for d in darks])
        read_sigma = math.sqrt(max(read_var.mean() - QUANTIZATION_VARIANCE, 0.0))
        row_sigma = math.sqrt(max(row_var.mean(), 0.0))
        errors["read_sigma"] = _sqrt_error(
            read_var.mean(), read_var.std(ddof=1) / math.sqrt(read_var.size)
        )
        errors["row_sigma"] = _sqrt_error(
            row_var.mean(), row_var.std(ddof=1) / math.sqrt(row_var.size)
        )
        for name, idx in planes.items():
            channels[name]["bias"] = float(np.mean([d.bias[idx].mean() for d in darks]))
            channels[name]["read_sigma"] = math.sqrt(
                max(np.mean([d.read_var[idx].mean() for d in darks]) - QUANTIZATION_VARIANCE, 0.0)
            )
        residual = np.concatenate([d.residual for d in darks])
        lam = fit_lambda(residual)
        parts = np.array_split(residual, 4)
        spread = _std(np.array([fit_lambda(p) for p in parts])) / 2
        errors["lambda"] = max(spread, 0.01 / math.sqrt(12))  # at least the grid's step
    else:
        read_var = line.offset - QUANTIZATION_VARIANCE
        read_sigma = math.sqrt(max(read_var, 0.0))
        sig = np.sqrt(np.maximum(draws[:, 1] - QUANTIZATION_VARIANCE, 0.0))
        systematic = _sqrt_error(read_var, abs(line.offset - check.offset))
        errors["read_sigma"] = math.hypot(_std(sig), systematic)
        row_sigma, lam = None, None
        if method == "flat":
            row_sigma, errors["row_sigma"] = _row_sigma_from_tiles(flats)
    return IsoFit(
        iso=iso,
        K=line.slope,
        read_sigma=read_sigma,
        row_sigma=row_sigma,
        lam=lam,
        errors=errors,
        channels=channels,
        frames=len(flats),
        darks=len(darks),
        problems=[f"ISO {iso:g}: {p}" for p in problems],
        points=points,
    )


#: The arrays of :class:`ChannelData` pooled over channels (along the blocks), and each
#: method's further variance estimators (:attr:`FrameStats.var_check`), as the problems
#: name them.
_POOLED = ("mean", "var", "group", "check")
_CHECKS = {
    "flat": "the tiles' high-pass noise",
    "patches": " or ".join(f"the {n}th-order detail" for n in CHECK_ORDERS),
}


def channel_planes(channels: tuple[str, ...]) -> dict[str, list[int]]:
    """The phase planes of each colour channel, channels in order of first appearance:
    ``{"R": [0], "Gr": [1], "Gb": [2], "B": [3]}`` for Bayer, ``{"G": [0, 1, 3, …],
    "R": [2, …], "B": [5, …]}`` (20, 8, 8 planes) for X-Trans."""
    planes: dict[str, list[int]] = {}
    for i, name in enumerate(channels):
        planes.setdefault(name, []).append(i)
    return planes


def _bias(channels: dict, name: str) -> float:
    """A fit's dark-frame bias of ``name``, one of :data:`CHANNELS`: a CFA without
    separate greens (X-Trans, 3-channel data) gives its G bias to Gr and Gb, which
    the noise model reads back as the G sites' bias (their mean); one grey channel
    (Y) gives its bias to all four."""
    if name in channels:
        return channels[name]["bias"]
    return channels.get("G", channels.get("Y"))["bias"]


def _channel_spread(channels: dict) -> float:
    """How far the channels' K scatter beyond their own errors: the weighted mean's error
    times √(χ²/dof − 1), 0 where they agree (χ²/dof ≤ 1) or fewer than 2 have a K.

    One sensor has one K; channels that disagree by more than their errors show a bias
    the pooled fit's bootstrap cannot see (on a chart, each channel sees the patches at
    other levels)."""
    k = np.array([c["K"] for c in channels.values()], dtype=np.float64)
    e = np.array([c["K_error"] for c in channels.values()], dtype=np.float64)
    ok = np.isfinite(k) & np.isfinite(e) & (e > 0)
    if ok.sum() < 2:
        return 0.0
    k, w = k[ok], 1 / e[ok] ** 2
    mean = float((w * k).sum() / w.sum())
    reduced = float((w * (k - mean) ** 2).sum()) / (k.size - 1)
    return math.sqrt(max(reduced - 1.0, 0.0) / float(w.sum()))


def _sqrt_error(var: float, var_error: float) -> float:
    """Standard error of √var from that of var (delta method)."""
    return var_error / (2 * math.sqrt(var)) if var > 0 else math.nan


def _line_problems(
    line: Line, draws: np.ndarray, darks: list, span: float, k_err: float
) -> list[str]:
    """Why a fitted line is not to be trusted (empty when it is); ``k_err`` is K's
    standard error, statistical and systematic."""
    if not math.isfinite(line.slope):
        return ["the frames give fewer than 2 signal levels; " + _LEVELS_HINT]
    ok = np.isfinite(line.bins)
    lv = line.levels[ok]
    problems = []
    positive = lv[lv > 0]
    spread = positive.max() / positive.min() if positive.size > 1 else 1.0
    if ok.sum() < MIN_LEVELS or (spread < MIN_LEVEL_RATIO and not darks):
        problems.append(
            f"only {int(ok.sum())} usable signal levels ({lv.min():.4g}–{lv.max():.4g} DN); "
            + _LEVELS_HINT
        )
        return problems
    if not line.slope > span / MAX_FULL_WELL:
        problems.append(
            f"no shot noise measured (K = {line.slope:.3g} DN/e⁻; a sensor's K exceeds its "
            f"range over 10⁶ e⁻, {span / MAX_FULL_WELL:.2g}): the frames look noise-free or "
            "processed; give the camera's raw files"
        )
    elif math.isfinite(k_err) and k_err > MAX_K_ERROR * line.slope:
        problems.append(
            f"K = {line.slope:.4g} ± {k_err:.2g} DN/e⁻ is too uncertain; add frames or levels"
        )
    if not darks and line.offset - QUANTIZATION_VARIANCE < 0:
        err = _std(draws[:, 1])
        problems.append(
            f"negative read variance ({line.offset - QUANTIZATION_VARIANCE:.3g} ± {err:.2g} "
            "DN²): the darkest levels do not pin the offset; add dark frames (--dark) or "
            "frames with deep shadows"
        )
    model = line.slope * line.levels[ok] + line.offset
    spread_err = _column_std(draws[:, 2:])[ok]
    scale = np.maximum(np.abs(model), 1e-12)  # noise-free frames: a model of 0
    err = np.maximum(np.nan_to_num(spread_err, nan=0.0), 0.01 * scale)
    chi2 = float(np.mean(((line.bins[ok] - model) / err) ** 2))
    rms = float(np.sqrt(np.mean(((line.bins[ok] - model) / scale) ** 2)))
    if chi2 > 9 and rms > 0.05:
        problems.append(
            f"variance does not follow a line in the signal ({rms:.0%} rms off it, "
            f"χ²/bin {chi2:.3g}); the frames may be processed, or mix exposures and settings"
        )
    # Bins with too few blocks to fit were never on or off the line (a chart's dark
    # surround and the gaps between its patches leave some levels nearly empty).
    usable = np.isfinite(line.levels) if line.usable is None else line.usable
    dropped = int((usable & ~ok).sum())
    if dropped > ok.sum():
        problems.append(
            f"{dropped} of {dropped + int(ok.sum())} signal levels were off the fitted line"
        )
    return problems


_LEVELS_HINT = (
    "shoot flats at several exposures (e.g. 1/8, 1/4, 1/2 and 3/4 of white) or with an "
    "illumination gradient"
)


def _row_sigma_from_tiles(flats: list[FrameStats]) -> tuple[float, float]:
    """Inverse-variance weighted mean of the tiles' row variances → (row σ, its error)."""
    rv = np.concatenate([f.row_var[f.valid] for f in flats])
    w = 1 / np.maximum(np.concatenate([f.var[f.valid] / f.tile for f in flats]), 1e-12) ** 2
    value = float((rv * w).sum() / w.sum())
    err = math.sqrt(float((w**2 * (rv - value) ** 2).sum())) / float(w.sum())
    return math.sqrt(max(value, 0.0)), _sqrt_error(value, err)


# ---------------------------------------------------------------- profile


def _loglinear(ks: list[float], sigmas: list[float]) -> dict:
    """ln σ = slope · ln K + bias by least squares (two or more points)."""
    lk, ls = np.log(ks), np.log(sigmas)
    slope, bias = np.polyfit(lk, ls, 1)
    return {"model": "loglinear", "slope": float(slope), "bias": float(bias)}


def build_profile(
    fits: list[IsoFit], frame: FrameStats, name: str, method: str, forced: bool = False
) -> dict:
    """A rawsim profile (JSON-ready) from per-ISO fits and one of the frames.

    With ``forced``, fits with problems are written and the profile lists them
    under ``unreliable``; K ≤ 0 is then floored so the profile still loads.
    """
    fits = sorted(fits, key=lambda f: f.iso)
    isos = [f.iso for f in fits]
    unreliable = [p for f in fits for p in f.problems]
    if unreliable and not forced:
        raise CalibrationRefused(unreliable)
    ks = []
    for f in fits:  # floors only matter for forced fits; keeps K increasing with ISO
        ks.append(max(f.K, (ks[-1] if ks else 0.0) * (1 + 1e-6) + 1e-6))
    how = (
        f"rawsim calibrate ({'flat-field' if method == 'flat' else 'single-image'} method) on "
        f"{sum(f.frames for f in fits)} frame(s)"
        + (f" and {sum(f.darks for f in fits)} dark frame(s)" if any(f.darks for f in fits) else "")
        + f" of this camera at ISO {', '.join(f'{i:g}' for i in isos)}"
    )
    single = len(fits) == 1
    if single:
        gain = {"model": "linear", "slope": ks[0] / isos[0], "intercept": 0.0}
    elif all(b > a for a, b in zip(ks, ks[1:], strict=False)):
        gain = {"model": "table", "iso": isos, "k": ks}
    else:
        raise CalibrationRefused(
            [
                "fitted K does not increase with ISO ("
                + ", ".join(f"ISO {i:g}: {k:.4g}" for i, k in zip(isos, ks, strict=True))
                + "); check the files' ISO metadata or give each ISO its own frames"
            ]
        )

    def sigma_curve(values: list[float]) -> dict:
        if single or min(values) <= 0:
            return {"model": "table", "iso": isos, "sigma": [max(v, 1e-6) for v in values]}
        return _loglinear(ks, values)

    white = frame.white
    bits = max(1, math.ceil(math.log2(white + 1)))
    xyz = frame.xyz_to_camera
    matrix_note = f"{frame.path}, as 'rawsim process' renders it: {frame.matrix_source}"
    if xyz is None:
        xyz = np.eye(3)
        matrix_note = (
            f"{NO_MATRIX} the files carry no colour matrix ({frame.path}: "
            f"{frame.matrix_source}); the identity stands in"
        )
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
        bias = [np.mean([_bias(f.channels, c) for f in fits]) for c in CHANNELS]
        noise["channel_bias"] = [float(b) for b in bias]
        for key in ("tukey_sigma", "tukey_lambda", "row_sigma", "channel_bias"):
            source[f"noise.{key}"] = how + "; from the dark frames"
    profile = {
        "name": name,
        "make": frame.camera.make,
        "model": frame.camera.model,
        "cfa_pattern": frame.camera.cfa or "RGGB",
        "bit_depth": bits,
        "black_level": frame.black,
        "white_level": white,
        "xyz_to_camera": [[float(v) for v in row] for row in np.asarray(xyz)],
        "iso_range": [isos[0], isos[-1]],
        "base_iso": isos[0],
        "noise": noise,
        "source": source,
        "calibration": [f.to_dict() for f in fits],
    }
    if unreliable:
        profile["unreliable"] = ["written with calibrate --force", *unreliable]
    return profile
