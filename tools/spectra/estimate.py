"""Estimate the spectral sensitivities of every database camera without measured ones.

Run from the repository root after ``build.py``, with the same snapshot of
rawtoaces-data (its three cameras the database lacks join the basis) and
colour-science installed (for the ColorChecker's reflectances, used by the
leave-one-out only)::

    python tools/spectra/estimate.py \\
        --rawtoaces-data /work/.mirror/AcademySoftwareFoundation+rawtoaces-data/repo

Writes ``rawsim/cameras/spectra_estimated.json``: a basis, the leave-one-out figures
and, for each database camera without measured curves, its basis coefficients. The
method (see :mod:`rawsim.cameras.spectra`):

1. **Basis.** Each of the 52 measured cameras' channels is scaled to a peak of 1; per
   channel, the mean curve and the first :data:`COMPONENTS` principal components over
   the cameras (with their spread σ_k) span the space (Jiang et al. 2013 found two
   components per channel explain most of the variance).
2. **Fit.** A camera's curves are, per channel, c = b₀·mean + Σ b_k·φ_k. Its D65
   XYZ → camera matrix M (Adobe's, as LibRaw tabulates it) predicts the camera's
   responses to rawtoaces' 190 training patches lit by D65: M · XYZ. The responses of
   c are linear in b, so b is a linear least-squares fit to them, each patch weighted
   by 1/√(Y + 0.02) (dark patches count relatively), with a ridge that pulls the
   components towards the mean curve: Σ (b_k / (b₀·σ_k))² weighted by :data:`RIDGE` ×
   the residual of the mean curve alone (a Gaussian prior on the basis; the channel's
   scale b₀ is that fit's); the curves are kept ≥ 0 (a quadratic programme, SLSQP,
   where the least squares would go negative). The channels' scales come from M, so
   the curves' white balance is Adobe's; they are scaled to a largest value of 1.
   An estimate is kept where Adobe's matrix renders the training patches seen through
   it (:func:`rawsim.spectral.fit.delta_e`, D65) no worse than :data:`LIMIT` times the
   worst mean ΔE00 it renders a measured camera's patches with: a matrix beyond that
   (old CMY and four-colour sensors, some backs) is unlike any measured camera's, and
   the camera gets no curves (``not_estimated``, with its figure).
3. **Leave-one-out.** Each of the 49 measured cameras in the database is estimated
   from its own Adobe matrix in a basis of the other 51, and compared with its measured
   curves: the RMS difference (each channel scaled to a peak of 1) and the CIEDE2000
   ΔE of the ColorChecker's 24 patches under D65 and A as the measured curves see them
   against as the estimated curves see them, each side rendered to XYZ through the
   matrix fitted for its own curves under that light (:func:`rawsim.spectral.fit.
   color_matrix`, what spectral ``unprocess`` writes into its DNGs), CIELAB relative to
   its own white. :data:`COMPONENTS` and :data:`RIDGE` were chosen on these figures.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from build import camera_file, camera_files, sig  # noqa: E402

from rawsim import cameras  # noqa: E402
from rawsim.cameras import spectra  # noqa: E402
from rawsim.color import delta_e_2000, xyz_to_lab  # noqa: E402
from rawsim.spectral import fit, tables  # noqa: E402

#: Principal components per channel, besides the mean curve.
COMPONENTS = 2
#: The ridge's weight, relative to the mean curve's residual.
RIDGE = 0.3
#: An estimate is kept where Adobe's matrix renders the training patches seen through
#: it within LIMIT × the worst mean ΔE00 it renders a measured camera's patches with.
LIMIT = 2.0
#: Added to a patch's Y before weighting it by 1/√(Y + WEIGHT_FLOOR).
WEIGHT_FLOOR = 0.02


def measured_curves(repo: Path) -> tuple[dict[str, np.ndarray], dict]:
    """The 52 measured cameras' (81, 3) curves: the database's 49 by name, the others
    by maker and model, read from rawtoaces-data; and the others' entries as stored
    (file, licence, curves), so that the basis can be rebuilt from the package."""
    out = {n: spectra.of_camera(n).rgb for n in spectra.names()}
    others = {}
    files = camera_files(repo)
    used = {e["file"] for e in spectra._data()["cameras"].values()}
    for path in files:
        if path in used:
            continue
        d = camera_file(repo, path)
        h, main = d["header"], d["spectral_data"]["data"]["main"]
        rgb = [[sig(main[str(int(w))][c]) for w in tables.WAVELENGTHS] for c in range(3)]
        name = f"{h['manufacturer']} {h['model']}"
        out[name] = np.array(rgb, dtype=np.float64).T
        others[name] = {"file": path, "licence": h["license"], "rgb": rgb}
    return out, others


def peak_one(rgb: np.ndarray) -> np.ndarray:
    return rgb / rgb.max(axis=0)


def basis(curves: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """((3, 81, 1 + k) mean and components per channel, (3, k) their spread), rounded
    to six significant digits as stored."""
    x = np.stack([peak_one(c) for c in curves])
    vectors, spread = [], []
    for i in range(3):
        xi = x[:, :, i]
        mean = xi.mean(axis=0)
        _, s, vt = np.linalg.svd(xi - mean, full_matrices=False)
        comp = vt[:COMPONENTS]
        comp *= np.sign(comp[np.arange(COMPONENTS), np.abs(comp).argmax(axis=1)])[:, None]
        vectors.append(np.column_stack([mean, comp.T]))
        spread.append(s[:COMPONENTS] / np.sqrt(len(curves) - 1))
    rounded = np.vectorize(sig)
    return rounded(np.stack(vectors)), rounded(np.stack(spread))


class Estimator:
    """Fits curves in a basis to XYZ → camera matrices (step 2 of the module's notes)."""

    def __init__(self, vectors: np.ndarray, spread: np.ndarray):
        self.vectors, self.spread = vectors, spread
        d65 = tables.illuminant("D65")
        refl = tables.training_reflectances()
        self.xyz, _ = fit.observer_xyz(d65, refl)
        self.weights = 1 / np.sqrt(self.xyz[:, 1] + WEIGHT_FLOOR)
        self.responses = [
            fit.camera_responses(v, d65, refl) * self.weights[:, None] for v in vectors
        ]

    def coefficients(self, xyz_to_camera) -> np.ndarray:
        """(3, 1 + k) the basis coefficients of the curves that reproduce the matrix."""
        target = self.xyz @ np.asarray(xyz_to_camera, dtype=np.float64).T
        out = []
        for i in range(3):
            a, y, v = self.responses[i], target[:, i] * self.weights, self.vectors[i]
            scale = (a[:, 0] @ y) / (a[:, 0] @ a[:, 0])
            residual = np.sum((a[:, 0] * scale - y) ** 2)
            prior = np.zeros((1 + COMPONENTS, 1 + COMPONENTS))
            prior[1:, 1:] = np.diag(np.sqrt(RIDGE * residual) / (scale * self.spread[i]))
            a = np.vstack([a, prior])
            y = np.concatenate([y, np.zeros(1 + COMPONENTS)])
            b = np.linalg.lstsq(a, y, rcond=None)[0]
            out.append(b if (v @ b).min() >= 0 else nonnegative(a, y, v, b))
        b = np.array(out)
        return b / self.curves(b).max()

    def curves(self, b: np.ndarray) -> np.ndarray:
        return np.einsum("cwk,ck->wc", self.vectors, b)


def nonnegative(a: np.ndarray, y: np.ndarray, v: np.ndarray, start: np.ndarray):
    """argmin ‖a·b − y‖² subject to v·b ≥ 0 (the curve the coefficients make)."""
    norm = np.abs(y).max() ** 2
    return minimize(
        lambda b: np.sum((a @ b - y) ** 2) / norm,
        start,
        jac=lambda b: 2 * a.T @ (a @ b - y) / norm,
        method="SLSQP",
        constraints=[{"type": "ineq", "fun": lambda b: v @ b, "jac": lambda b: v}],
        options={"maxiter": 500, "ftol": 1e-15},
    ).x


def colorchecker() -> np.ndarray:
    """(81, 24) the ColorChecker's reflectances, as colour-science tabulates them."""
    import colour

    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values()
    return np.array([[sd[w] for w in tables.WAVELENGTHS] for sd in sds]).T


def rendered(curves: np.ndarray, light: np.ndarray, refl: np.ndarray) -> np.ndarray:
    """(N, 3) CIELAB of ``refl`` seen through ``curves`` under ``light``, rendered with
    the matrix fitted for the curves under that light, relative to its own white."""
    matrix = fit.color_matrix(curves, light).xyz_to_camera
    return xyz_to_lab(*fit.converter_xyz(curves, light, matrix, refl))


def leave_one_out(measured: dict[str, np.ndarray]) -> dict:
    chart = colorchecker()
    lights = {"D65": tables.illuminant("D65"), "A": tables.illuminant("A")}
    per = {}
    for name in spectra.names():
        estimator = Estimator(*basis([c for n, c in measured.items() if n != name]))
        truth = measured[name]
        est = estimator.curves(estimator.coefficients(cameras.find(name).data["xyz_to_camera"]))
        rms = float(np.sqrt(np.mean((peak_one(est) - peak_one(truth)) ** 2)))
        row = {"rms": round(rms, 4)}
        for key, light in lights.items():
            de = delta_e_2000(rendered(truth, light, chart), rendered(est, light, chart))
            row[f"delta_e00_{key}"] = [round(float(de.mean()), 3), round(float(de.max()), 3)]
        per[name] = row

    def summary(values: list[float], worst: list[float]) -> dict:
        at = int(np.argmax(values))
        return {
            "mean": round(float(np.mean(values)), 3),
            "worst_camera": round(float(values[at]), 3),
            "worst_camera_name": list(per)[at],
            "worst_patch": round(float(np.max(worst)), 3),
        }

    rms = [r["rms"] for r in per.values()]
    at = int(np.argmax(rms))
    return {
        "cameras": len(per),
        "rms": {
            "mean": round(float(np.mean(rms)), 4),
            "worst": round(float(rms[at]), 4),
            "worst_camera_name": list(per)[at],
        },
        **{
            f"delta_e00_{k}": summary(
                [r[f"delta_e00_{k}"][0] for r in per.values()],
                [r[f"delta_e00_{k}"][1] for r in per.values()],
            )
            for k in lights
        },
        "per_camera": per,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rawtoaces-data", type=Path, required=True)
    a = ap.parse_args()
    start = time.time()
    measured, others = measured_curves(a.rawtoaces_data)
    vectors, spread = basis(list(measured.values()))
    estimator = Estimator(vectors, spread)
    d65 = tables.illuminant("D65")
    have = set(spectra.names())
    adobe = [
        fit.delta_e(measured[n], d65, cameras.find(n).data["xyz_to_camera"]).mean()
        for n in spectra.names()
    ]
    limit = round(LIMIT * float(np.max(adobe)), 3)
    out, left_out = {}, {}
    for cam in cameras.cameras():
        if cam.name in have:
            continue
        b = estimator.coefficients(cam.data["xyz_to_camera"])
        stored = np.vectorize(sig)(b)
        de = fit.delta_e(np.maximum(estimator.curves(stored), 0), d65, cam.data["xyz_to_camera"])
        figure = [round(float(de.mean()), 3), round(float(de.max()), 3)]
        if figure[0] > limit:
            left_out[cam.name] = figure
            continue
        out[cam.name] = {"coefficients": stored.tolist(), "matrix_delta_e00": figure}
    loo = leave_one_out(measured)
    src = spectra._data()["source"]
    data = {
        "method": {
            "built_by": "tools/spectra/estimate.py",
            "basis": f"mean and {COMPONENTS} principal components per channel of the "
            f"{len(measured)} cameras of rawtoaces-data {src['release']} "
            f"({src['commit'][:12]}), each channel scaled to a peak of 1",
            "fit": "least squares on the responses to rawtoaces' 190 training patches under "
            "D65 that the camera's D65 XYZ→camera matrix (Adobe's, as LibRaw tabulates it) "
            f"predicts, weighted by 1/√(Y + {WEIGHT_FLOOR}), ridge {RIDGE} on the components, "
            "curves ≥ 0",
            "components": COMPONENTS,
            "ridge": RIDGE,
            "basis_cameras": [cameras.find(n).label if n in have else n for n in measured],
            "measured_matrix_delta_e00": [
                round(float(np.min(adobe)), 3),
                round(float(np.mean(adobe)), 3),
                round(float(np.max(adobe)), 3),
            ],
            "limit": limit,
        },
        "basis": {
            "vectors": vectors.tolist(),
            "spread": spread.tolist(),
        },
        "basis_only": others,
        "leave_one_out": loo,
        "cameras": out,
        "not_estimated": left_out,
    }
    (ROOT / "rawsim/cameras/spectra_estimated.json").write_text(json.dumps(data) + "\n")
    print(
        f"{len(out)} cameras estimated ({len(left_out)} beyond ΔE00 {limit}) in "
        f"{time.time() - start:.0f} s; leave-one-out over "
        f"{loo['cameras']}: RMS {loo['rms']['mean']:.4f} (worst {loo['rms']['worst']:.4f}), "
        + ", ".join(
            f"ΔE00 {k} {loo[f'delta_e00_{k}']['mean']:.2f} (worst camera "
            f"{loo[f'delta_e00_{k}']['worst_camera']:.2f}, patch "
            f"{loo[f'delta_e00_{k}']['worst_patch']:.2f})"
            for k in ("D65", "A")
        )
    )


if __name__ == "__main__":
    main()
