"""Dark shading and black-level error from dark frames (``rawsim calibrate --dark-shading``).

The quantities are :mod:`rawsim.noise.dark_shading`'s (PMN, Feng et al. 2022):
per pixel, the mean of the dark frames at each ISO less the black level and its
channel's bias is fitted as ``k · ISO + b`` in each gain range; per ISO, the
spread of the frames' black levels (less what row and read noise add to a
frame's mean) is the black-level error's σ.

Frames are streamed (:func:`accumulate`): per ISO a per-pixel sum and sum of
squares, so memory grows with the frame size and the number of ISOs, not with
the number of frames.

How many frames: the mean of n frames is the pattern plus noise of variance v/n
(v a pixel's variance from frame to frame); it correlates ρ with the pattern
(variance p) when n ≥ (v/p)/(1/ρ² − 1), 9.3 v/p at ρ = 0.95
(:func:`frames_needed`), and at least :data:`MIN_FRAMES`. A line k·ISO + b needs
two ISOs or more in each gain range. Fewer are refused, with the figures.

The pattern also inflates what :mod:`rawsim.cameras.calibrate` measures: a dark frame's
variance and a flat tile's. :class:`PatternRemoval` takes it out first (a
second pass over the frames).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rawsim.errors import ParameterError
from rawsim.io.atomic import atomic_output
from rawsim.io.raw import RawImage
from rawsim.noise.dark_shading import write_maps

#: Correlation with the true pattern that a calibrated map must reach (see
#: :func:`frames_needed`).
MAP_CORRELATION = 0.95
#: Fewest dark frames per ISO: the black-level error's spread from n frames has a
#: relative standard error of 1/√(2(n − 1)), 27 % at 8.
MIN_FRAMES = 8


class DarkAccumulator:
    """Streamed statistics of dark frames, per ISO: per-pixel sums of the frames and of
    their squares (float64 (H, W) each), sums of each frame's row means and their
    squares ((H,) each) and of the frame means. Memory grows with the number of ISOs
    and the frame size, not with the number of frames."""

    def __init__(self) -> None:
        self.n: dict[float, int] = {}
        self.sum: dict[float, np.ndarray] = {}
        self.sum2: dict[float, np.ndarray] = {}
        self.rows: dict[float, np.ndarray] = {}
        self.rows2: dict[float, np.ndarray] = {}
        self.means: dict[float, list[float]] = {}  # Σ m, Σ m² of the frame means
        self.period: tuple[int, int] = (1, 1)

    def add(self, mosaic: np.ndarray, iso: float, path: str = "") -> None:
        """Add a dark frame (H, W) DN at ``iso``."""
        x = np.asarray(mosaic, np.float64)
        if x.ndim != 2:
            raise ParameterError(f"{path}: dark shading needs CFA mosaics, got shape {x.shape}")
        if self.sum and x.shape != next(iter(self.sum.values())).shape:
            first = next(iter(self.sum.values())).shape
            raise ParameterError(f"{path}: frame {x.shape} differs in size from {first}")
        if iso not in self.n:
            self.n[iso] = 0
            self.sum[iso], self.sum2[iso] = np.zeros_like(x), np.zeros_like(x)
            self.rows[iso], self.rows2[iso] = np.zeros(x.shape[0]), np.zeros(x.shape[0])
            self.means[iso] = [0.0, 0.0]
        rows = x.mean(axis=1)
        self.n[iso] += 1
        self.sum[iso] += x
        self.sum2[iso] += x * x
        self.rows[iso] += rows
        self.rows2[iso] += rows * rows
        m = float(rows.mean())
        self.means[iso][0] += m
        self.means[iso][1] += m * m

    @property
    def isos(self) -> list[float]:
        return sorted(self.n)

    def mean(self, iso: float) -> np.ndarray:
        """The per-pixel mean (H, W) DN of the frames at ``iso``."""
        return self.sum[iso] / self.n[iso]

    def temporal_variance(self, iso: float) -> float:
        """A pixel's variance from frame to frame (DN², mean over the pixels)."""
        n = self.n[iso]
        var = (self.sum2[iso] - self.sum[iso] ** 2 / n) / (n - 1)
        return float(var.mean())

    def black_level_sigma(self, iso: float) -> float:
        """σ (DN) of the frames' black level, less what row and read noise add to a frame
        mean: with V_m the variance of the frame means and V_r that of a row's mean
        between frames (averaged over rows), row noise ρ of variance s gives
        V_m = σ² + s/H and V_r = σ² + s, so s = (V_r − V_m)·H/(H − 1)."""
        n, h = self.n[iso], self.rows[iso].size
        s, s2 = self.means[iso]
        var_m = (s2 - s * s / n) / (n - 1)
        var_r = float(((self.rows2[iso] - self.rows[iso] ** 2 / n) / (n - 1)).mean())
        row = max(var_r - var_m, 0.0) * h / (h - 1)
        return math.sqrt(max(var_m - row / h, 0.0))


def frames_needed(noise_var: float, pattern_var: float) -> float:
    """Frames per ISO for a per-pixel mean that correlates :data:`MAP_CORRELATION` with
    a pattern of variance ``pattern_var``, from pixels of temporal variance ``noise_var``.

    The mean of n frames is pattern + noise of variance v/n; its correlation with the
    pattern is 1/√(1 + v/(n p)) ≥ ρ when n ≥ (v/p) / (1/ρ² − 1) = 9.26 v/p at ρ = 0.95.
    """
    if pattern_var <= 0:
        return math.inf
    return noise_var / pattern_var / (1.0 / MAP_CORRELATION**2 - 1.0)


@dataclass
class DarkShadingFit:
    """Calibrated maps (n ranges, H, W) DN and per-ISO figures; ``problems`` says why
    they are not to be trusted (empty when they are)."""

    iso_ranges: list[tuple[float, float]]
    k: np.ndarray
    b: np.ndarray
    black_level_sigma: dict[float, float]
    per_iso: dict[float, dict]
    problems: list[str]


def fit_dark_shading(
    acc: DarkAccumulator,
    reference: dict[float, np.ndarray | float],
    switch_isos: tuple[float, ...] = (),
) -> DarkShadingFit:
    """Fit D = k·ISO + b per pixel in each gain range from the accumulated dark frames.

    ``reference[iso]`` (H, W), or one number for all pixels, is what each pixel's dark
    level is measured from: the black level plus its channel's bias (the rest is the
    pattern). ``switch_isos``
    are the ISOs where a new gain range starts (none: one range). Per pixel, a
    least-squares line over the range's ISOs, each mean weighted by n/v (its
    frames over its pixels' temporal variance). Problems: fewer than
    :data:`MIN_FRAMES` frames at an ISO, fewer frames than :func:`frames_needed`
    for the pattern measured there, fewer than two ISOs in a range.
    """
    isos = acc.isos
    per_iso, ranges, ks, bs = {}, [], [], []
    problems = count_problems(acc.n, switch_isos)
    if any(acc.n[i] < 2 for i in isos):
        return DarkShadingFit([], np.zeros((0, 0, 0)), np.zeros((0, 0, 0)), {}, {}, problems)
    for iso in isos:
        n, v = acc.n[iso], acc.temporal_variance(iso)
        pattern = acc.mean(iso) - reference[iso]
        p = float(pattern.var()) - v / n  # the mean's spatial variance less its noise
        need = max(MIN_FRAMES, math.ceil(frames_needed(v, p)))
        per_iso[iso] = {
            "frames": n,
            "temporal_sigma": math.sqrt(v),
            "pattern_sigma": math.sqrt(max(p, 0.0)),
            "frames_needed": need if math.isfinite(need) else None,
        }
        if p <= 0:
            problems.append(
                f"ISO {iso:g}: no dark pattern above the noise of the mean of {n} frame(s) "
                f"(temporal σ {math.sqrt(v):.3g} DN): the map would be noise"
            )
        elif n < need:
            problems.append(
                f"ISO {iso:g}: {n} dark frame(s); a pattern of σ {math.sqrt(p):.3g} DN under "
                f"temporal noise of σ {math.sqrt(v):.3g} DN needs at least {need} for a map "
                f"that correlates {MAP_CORRELATION} with it"
            )
    for group in gain_ranges(isos, switch_isos):
        if len(group) < 2:  # a problem count_problems gave
            continue
        w = np.array([acc.n[i] / acc.temporal_variance(i) for i in group])
        x = np.array(group)
        xm = float((w * x).sum() / w.sum())
        sxx = float((w * (x - xm) ** 2).sum())
        means = [acc.mean(i) - reference[i] for i in group]
        ym = sum(wi * m for wi, m in zip(w, means, strict=True)) / w.sum()
        k = sum(wi * (xi - xm) * m for wi, xi, m in zip(w, x, means, strict=True)) / sxx
        ranges.append((float(group[0]), float(group[-1])))
        ks.append(k)
        bs.append(ym - k * xm)
    sigma = {i: acc.black_level_sigma(i) for i in isos if acc.n[i] > 2}
    if not ks:
        return DarkShadingFit(
            [], np.zeros((0, 0, 0)), np.zeros((0, 0, 0)), sigma, per_iso, problems
        )
    return DarkShadingFit(ranges, np.stack(ks), np.stack(bs), sigma, per_iso, problems)


def gain_ranges(isos: list[float], switch_isos: tuple[float, ...]) -> list[list[float]]:
    """``isos`` (sorted) split where each of ``switch_isos`` starts a gain range; the
    ranges that hold any."""
    edges = [-math.inf, *sorted(switch_isos), math.inf]
    groups = [[i for i in isos if lo <= i < hi] for lo, hi in zip(edges, edges[1:], strict=False)]
    return [g for g in groups if g]


def count_problems(frames: dict[float, int], switch_isos: tuple[float, ...] = ()) -> list[str]:
    """What no measurement can mend in a set of dark frames (``frames``: how many at
    each ISO): an ISO with one frame, a gain range with frames at one ISO. ``calibrate``
    refuses on these before it fits the flats."""
    isos = sorted(frames)
    problems = [
        f"ISO {i:g}: one dark frame; the pattern needs several" for i in isos if frames[i] < 2
    ]
    for group in gain_ranges(isos, switch_isos):
        if len(group) < 2:
            problems.append(
                f"gain range starting at ISO {group[0]:g}: dark frames at one ISO only; "
                "k·ISO + b needs at least two ISOs per gain range"
            )
    return problems


def accumulate(frames: Iterable[tuple[RawImage, float]]) -> DarkAccumulator:
    """Stream (raw, ISO) pairs of dark frames into a :class:`DarkAccumulator`; each raw
    can be dropped as soon as it is added (pass a generator that reads them)."""
    acc = DarkAccumulator()
    for raw, iso in frames:
        if raw.cfa is None:
            raise ParameterError(f"{raw.path}: dark shading needs CFA mosaics")
        acc.add(raw.data, iso, str(raw.path))
        acc.period = raw.cfa.period
    return acc


def _site_means(x: np.ndarray, period: tuple[int, int]) -> np.ndarray:
    """Each CFA site's mean over the frame, laid over the frame (H, W)."""
    ph, pw = period
    h, w = x.shape
    tile = np.array([[x[i::ph, j::pw].mean() for j in range(pw)] for i in range(ph)])
    return np.tile(tile, (-(-h // ph), -(-w // pw)))[:h, :w]


class PatternRemoval:
    """The dark pattern measured by a :class:`DarkAccumulator`, taken out of frames
    before :mod:`rawsim.cameras.calibrate` reduces them, so the read σ and the flat tiles'
    variance are the noise's, not the pattern's.

    With M the per-pixel mean of the n dark frames at the frame's ISO and M̄ its
    CFA sites' means: a dark frame x becomes M̄ + (x − M)·√(n/(n − 1)) (its
    deviation from M has variance (1 − 1/n) of the noise's; the factor restores
    it; its channel bias M̄ stays); a flat x − (M − M̄). Frames at ISOs without
    dark frames pass unchanged.
    """

    def __init__(self, acc: DarkAccumulator) -> None:
        self.acc = acc

    def _pattern(self, raw: RawImage, iso: float) -> tuple[np.ndarray, np.ndarray] | None:
        if iso not in self.acc.n or raw.cfa is None:
            return None
        mean = self.acc.mean(iso)
        if raw.data.shape != mean.shape:
            raise ParameterError(
                f"{raw.path}: frame {raw.data.shape} differs in size from the dark frames "
                f"{mean.shape}"
            )
        return mean, _site_means(mean, raw.cfa.period)

    def dark(self, raw: RawImage, iso: float) -> RawImage:
        """A dark frame without the pattern (see the class)."""
        found = self._pattern(raw, iso)
        if found is None:
            return raw
        mean, sites = found
        n = self.acc.n[iso]
        return replace(raw, data=sites + (raw.data - mean) * math.sqrt(n / (n - 1)))

    def flat(self, raw: RawImage, iso: float) -> RawImage:
        """A flat (or any lit) frame without the pattern."""
        found = self._pattern(raw, iso)
        return raw if found is None else replace(raw, data=raw.data - (found[0] - found[1]))


def add_to_profile(
    profile: dict,
    acc: DarkAccumulator,
    output: str | Path,
    switch_isos: tuple[float, ...] = (),
    forced: bool = False,
) -> DarkShadingFit:
    """Fit the maps and the black-level error and add them to ``profile`` (a profile
    dict from :func:`rawsim.cameras.calibrate.build_profile`, written to ``output``): the maps
    go to ``<output stem>.dark.npz`` beside it. The pattern is measured from the
    profile's black level plus its channel bias (what the noise model adds).

    Raises :class:`rawsim.cameras.calibrate.CalibrationRefused` with the fit's problems
    unless ``forced`` (then they are listed under ``unreliable``).
    """
    from rawsim.cameras.calibrate import CalibrationRefused
    from rawsim.cfa import CFA
    from rawsim.noise.models import NoiseLevels, site_bias

    if not acc.n:
        raise ParameterError("--dark-shading needs dark frames (--dark)")
    noise = profile["noise"]
    if "channel_bias" not in noise:
        raise CalibrationRefused(["dark shading needs the physics model's dark-frame fits"])
    cfa = CFA(profile["cfa_pattern"])
    levels = NoiseLevels("physics", 1.0, channel_bias=tuple(noise["channel_bias"]))
    shape = next(iter(acc.sum.values())).shape
    bias = site_bias(levels, cfa, 0, *shape, "cpu")
    reference = profile["black_level"] + (0.0 if bias is None else bias.numpy())
    fit = fit_dark_shading(acc, {iso: reference for iso in acc.isos}, switch_isos)
    if fit.problems and not forced:
        raise CalibrationRefused(fit.problems)
    how = (
        f"rawsim calibrate --dark-shading on {sum(acc.n.values())} dark frame(s) at ISO "
        + ", ".join(f"{i:g} ({acc.n[i]})" for i in acc.isos)
    )
    source = profile["source"]
    if fit.k.size:
        path = Path(output).with_suffix(".dark.npz")
        with atomic_output(path) as tmp:
            write_maps(tmp, fit.iso_ranges, fit.k, fit.b, cfa.pattern)
        noise["dark_shading"] = {
            "file": path.name,
            "iso_ranges": [list(r) for r in fit.iso_ranges],
            "size": list(shape),
        }
        source["noise.dark_shading"] = how + "; per pixel, k·ISO + b per gain range"
    if fit.black_level_sigma:
        isos = sorted(fit.black_level_sigma)
        noise["black_level_error"] = {
            "iso": isos,
            "sigma": [fit.black_level_sigma[i] for i in isos],
        }
        source["noise.black_level_error"] = how + "; spread of the frames' black levels"
    if fit.problems:
        profile.setdefault("unreliable", ["written with calibrate --force"]).extend(fit.problems)
    profile["dark_shading_calibration"] = {f"{i:g}": v for i, v in fit.per_iso.items()}
    return fit
