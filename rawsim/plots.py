"""PNG plots of noise models and calibration fits (matplotlib, written atomically)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rawsim.cameras.profiles import SensorProfile
from rawsim.io.atomic import atomic_output


def _figure():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_isos(profile: SensorProfile, count: int = 5) -> list[float]:
    """``count`` ISOs spread log-evenly over the profile's range (rounded)."""
    lo, hi = profile.iso_range
    if hi <= lo:
        return [lo]
    logs = np.linspace(math.log(lo), math.log(hi), count)
    return sorted({float(round(math.exp(v))) for v in logs})


def plot_noise_profile(profile: SensorProfile, path: str | Path, models=None) -> Path:
    """σ (DN) versus signal above black at several ISOs, log-log, one line per model."""
    plt = _figure()
    models = models or (["physics"] if profile.noise.has_physics else []) + ["poisson-gaussian"]
    span = profile.white_level - profile.black_level
    signal = np.geomspace(1.0, span, 200)
    fig, ax = plt.subplots(figsize=(7, 5), dpi=100)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, iso in enumerate(plot_isos(profile)):
        for j, model in enumerate(models):
            levels = profile.noise.levels(model, iso)
            sigma = np.sqrt(levels.variance(signal).numpy())
            ax.plot(
                signal,
                sigma,
                color=colours[i % len(colours)],
                linestyle="-" if j == 0 else "--",
                label=f"ISO {iso:g} ({model})",
            )
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="signal above black (DN)",
        ylabel="noise σ (DN)",
        title=f"{profile.make} {profile.model} ({profile.name})",
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, plt, path)


def plot_calibration(fits, path: str | Path, title: str = "") -> Path:
    """Variance versus mean (DN, log-log) per channel with the fitted line, one panel per ISO.

    Points are the signal bins with their bootstrap standard errors; the legend
    gives K and read σ ± their standard errors. Unreliable fits say so in the title.
    """
    plt = _figure()
    n = len(fits)
    fig, axes = plt.subplots(1, n, figsize=(5 * n, 4.2), dpi=100, squeeze=False)
    for ax, fit in zip(axes[0], fits, strict=True):
        lo, hi = np.inf, 0.0
        for name, (means, variances, errors) in fit.points.items():
            shown = means > 0
            ax.errorbar(
                means[shown],
                variances[shown],
                yerr=errors[shown],
                fmt="o",
                markersize=3,
                capsize=2,
                label=name,
            )
            if shown.any():
                lo, hi = min(lo, float(means[shown].min())), max(hi, float(means[shown].max()))
        x = np.geomspace(lo, hi, 50) if hi > lo else np.array([1.0, 10.0])
        offset = fit.read_sigma**2 + 1 / 12
        k_err = fit.errors.get("K", float("nan"))
        r_err = fit.errors.get("read_sigma", float("nan"))
        ax.plot(
            x,
            fit.K * x + offset,
            "k-",
            label=f"K {fit.K:.4g} ± {k_err:.2g}, σ_read {fit.read_sigma:.3g} ± {r_err:.2g}",
        )
        if k_err == k_err:
            ax.fill_between(
                x,
                (fit.K - k_err) * x + offset,
                (fit.K + k_err) * x + offset,
                color="k",
                alpha=0.15,
                linewidth=0,
            )
        ax.set_xscale("log")
        ax.set_yscale("log")
        state = "" if not fit.problems else " — unreliable"
        ax.set(
            xlabel="mean above black (DN)", ylabel="variance (DN²)", title=f"ISO {fit.iso:g}{state}"
        )
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, plt, path)


def plot_tone_curves(path: str | Path) -> Path:
    """The tone curves (display value versus linear, log-x) at their defaults and with
    the filmic curves' exposure and white: the README's figure."""
    import torch

    from rawsim.isp.tone import apply_tone_curve

    plt = _figure()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), dpi=100)
    x = torch.from_numpy(np.geomspace(1e-3, 4.0, 400))
    settings = {
        "defaults (exposure 0, own white)": [(c, 0.0, None) for c in TONE_CURVE_NAMES],
        "exposure (white auto)": [(c, e, None) for c in ("hable",) for e in (0.0, 1.0, 2.0, 3.0)],
        "white (exposure 1)": [(c, 1.0, w) for c in ("aces",) for w in (1.0, 2.0, 4.0, 12.0)],
    }
    for ax, (title, curves) in zip(axes, settings.items(), strict=True):
        ax.plot(x, x.clamp(0, 1), ":", color="grey", label="none (clip at 1)")
        for curve, exposure, white in curves:
            y = apply_tone_curve(x, curve, exposure, white).clamp(max=1.0)
            label = (
                curve
                if title.startswith("defaults")
                else (
                    f"{curve} exposure {exposure:g}"
                    if white is None
                    else f"{curve} white {white:g}"
                )
            )
            ax.plot(x, y, label=label)
        ax.set_xscale("log")
        ax.set(xlabel="linear value (1 = the sensor's white)", ylabel="display value (linear)")
        ax.set_title(title)
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, plt, path)


TONE_CURVE_NAMES = ("smoothstep", "reinhard", "aces", "hable")


def _save(fig, plt, path) -> Path:
    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
