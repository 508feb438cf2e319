"""What a camera's spectral sensitivities give: its colour matrix under any light
(:func:`color_matrix`, the DNG ColorMatrix) and the ACES input transform as rawtoaces
makes it (:func:`aces_idt`, with :func:`best_illuminant` for a shot's white balance).

Both fit a 3 × 3 matrix on rawtoaces' 190 training reflectances lit by the illuminant:
the camera's responses (sensitivities · illuminant · reflectance, summed over the
grid) against the colours a standard observer sees (the CIE 1931 observer in place
of the sensitivities). Each matrix keeps the illuminant's white exactly: the camera's
white goes to the observer's white. The fits are Levenberg–Marquardt least squares
on per-patch colour differences, started from the linear least-squares matrix:

- :func:`color_matrix` minimises the CIEDE2000 ΔE, in CIELAB relative to the
  illuminant's own white (the fit the DNG specification's calibration describes);
- :func:`aces_idt` minimises rawtoaces' objective (the CIELAB distance, ΔE*ab, after
  CAT02 adaptation to the ACES white; its six free parameters, each row summing to 1),
  so that it reproduces rawtoaces (and ``colour.matrix_idt``, which implements it).

Shapes: curves (81, 3), spectra (81,), reflectances (81, N), all on
:data:`rawsim.spectral.tables.WAVELENGTHS`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rawsim.color import CAT02, chromatic_adaptation, delta_e_2000, xyz_to_lab
from rawsim.colorspaces import RGB_SPACES
from rawsim.errors import ParameterError
from rawsim.spectral import tables


@dataclass(frozen=True)
class MatrixFit:
    """A fitted XYZ → camera matrix (DNG ColorMatrix: the illuminant's white XYZ, Y = 1,
    maps to camera values whose largest is 1) with its fit on the training patches."""

    xyz_to_camera: np.ndarray
    white_xyz: np.ndarray
    mean_delta_e: float
    max_delta_e: float


def camera_responses(curves: np.ndarray, light: np.ndarray, reflectances: np.ndarray):
    """(N, 3) camera RGB of ``reflectances`` (81, N) lit by ``light`` (81,)."""
    return (reflectances * light[:, None]).T @ curves


def observer_xyz(light: np.ndarray, reflectances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((N, 3) XYZ of the lit reflectances, (3,) XYZ of the light's white), Y = 1 at white."""
    cmf = tables.cmf()
    white = cmf.T @ light
    return camera_responses(cmf, light, reflectances) / white[1], white / white[1]


def color_matrix(curves: np.ndarray, light: np.ndarray) -> MatrixFit:
    """The XYZ → camera matrix of a camera with ``curves`` under ``light``, fitted to
    minimise the CIEDE2000 ΔE of the 190 training patches (see the module's notes)."""
    refl = tables.training_reflectances()
    rgb_white = curves.T @ light
    if not (rgb_white > 0).all():
        raise ParameterError("the camera's curves see nothing of this light in some channel")
    rgb = camera_responses(curves, light, refl) / rgb_white  # white-balanced: white = 1
    xyz, white = observer_xyz(light, refl)
    lab = xyz_to_lab(xyz, white)

    def matrix(p: np.ndarray) -> np.ndarray:  # camera (white-balanced) → XYZ, 1 → white
        m = p.reshape(3, 2)
        return np.column_stack([m, white - m.sum(axis=1)])

    def residuals(p: np.ndarray) -> np.ndarray:
        return delta_e_2000(xyz_to_lab(rgb @ matrix(p).T, white), lab)

    start = np.linalg.lstsq(rgb, xyz, rcond=None)[0].T[:, :2].ravel()
    to_camera = np.linalg.inv(matrix(_least_squares(residuals, start)) @ np.diag(1 / rgb_white))
    to_camera /= (to_camera @ white).max()
    errors = delta_e(curves, light, to_camera, refl)
    return MatrixFit(to_camera, white, float(errors.mean()), float(errors.max()))


def converter_xyz(curves: np.ndarray, light: np.ndarray, xyz_to_camera, reflectances):
    """What a raw converter makes of the camera's responses to ``reflectances`` (81, N)
    under ``light`` with ``xyz_to_camera`` (any scale), as the DNG specification
    renders: camera → XYZ by the matrix's inverse, the camera's white (its response to
    the light) taken as the white. Returns ((N, 3) XYZ, (3,) the white's XYZ), Y = 1 at
    that white."""
    to_xyz = np.linalg.inv(np.asarray(xyz_to_camera, dtype=np.float64))
    white = to_xyz @ (curves.T @ light)
    seen = camera_responses(curves, light, reflectances) @ to_xyz.T / white[1]
    return seen, white / white[1]


def delta_e(curves: np.ndarray, light: np.ndarray, xyz_to_camera, reflectances=None):
    """(N,) CIEDE2000 ΔE of ``reflectances`` (81, N; the training patches unless given)
    under ``light`` between what the observer sees and what a raw converter makes of
    the camera's responses with ``xyz_to_camera`` (:func:`converter_xyz`), each side
    CIELAB relative to its own white."""
    refl = tables.training_reflectances() if reflectances is None else reflectances
    xyz, white = observer_xyz(light, refl)
    seen = xyz_to_lab(*converter_xyz(curves, light, xyz_to_camera, refl))
    return delta_e_2000(seen, xyz_to_lab(xyz, white))


def white_balance(curves: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(3,) the gains that make ``light`` neutral for ``curves``, the least 1 (rawtoaces)."""
    b = 1 / (curves.T @ light)
    return b / b.min()


def aces_idt(curves: np.ndarray, light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """rawtoaces' spectral input transform for ``curves`` under ``light``: ((3, 3) B,
    camera RGB white-balanced by ``b`` → ACES2065-1, rows summing to 1; (3,) ``b``,
    :func:`white_balance`)."""
    refl = tables.training_reflectances()
    strongest = int(np.argmax(curves.max(axis=0)))
    light = light / np.sum(light * curves[:, strongest])
    b = white_balance(curves, light)
    rgb = camera_responses(curves, light, refl) * b
    xyz, white = observer_xyz(light, refl)
    aces = RGB_SPACES["aces2065-1"]
    aces_white = np.asarray(aces.white, dtype=np.float64)
    xyz = xyz @ chromatic_adaptation(white, aces_white, CAT02).T
    lab = xyz_to_lab(xyz, aces_white)
    to_xyz = aces.to_xyz

    def matrix(p: np.ndarray) -> np.ndarray:
        m = p.reshape(3, 2)
        return np.column_stack([m, 1 - m.sum(axis=1)])

    def residuals(p: np.ndarray) -> np.ndarray:
        return (xyz_to_lab(rgb @ (to_xyz @ matrix(p)).T, aces_white) - lab).ravel()

    return matrix(_least_squares(residuals, np.array([1.0, 0, 0, 1, 0, 0]))), b


def aces_from_camera(curves: np.ndarray, gains, space: str) -> tuple[np.ndarray, dict]:
    """The spectral input transform for camera RGB already white-balanced by ``gains``
    (3,), as ``rawsim process`` holds it, into ``space`` ("aces2065-1" or "acescg"),
    by rawtoaces' procedure: B of :func:`aces_idt` under the candidate light whose
    white balance is nearest ``gains`` (:func:`best_illuminant`). The white balance
    stays the one used (B's rows sum to 1, so its neutral stays neutral); rawtoaces'
    own b for that light is reported beside it. Returns ((3, 3) matrix, what was
    used: the light, b, B)."""
    name, light = best_illuminant(curves, gains)
    idt, b = aces_idt(curves, light)
    matrix = idt
    if space == "acescg":
        to_ap1 = np.linalg.solve(RGB_SPACES["acescg"].to_xyz, RGB_SPACES["aces2065-1"].to_xyz)
        matrix = to_ap1 @ idt
    elif space != "aces2065-1":
        raise ParameterError(f"no spectral input transform into {space!r}: ACES spaces only")
    used = {"illuminant": name, "b": np.round(b, 6).tolist(), "B": np.round(idt, 6).tolist()}
    return matrix, used


def rawtoaces_illuminants() -> dict[str, np.ndarray]:
    """rawtoaces' candidate lights for a shot: CIE daylights at 4000–25000 K in 500 K
    steps (nominal, :func:`~rawsim.spectral.tables.rescaled` as the CIE's tables are),
    blackbodies at 1000–3500 K and the ISO 7589 studio tungsten, by name ("D65",
    "3000K", "ISO7589")."""
    lights = {
        f"D{int(tables.rescaled(k) / 100)}": tables.daylight(tables.rescaled(k))
        for k in range(4000, 25001, 500)
    }
    lights |= {f"{k}K": tables.blackbody(k) for k in range(1000, 3501, 500)}
    lights["ISO7589"] = tables.illuminant("ISO7589")
    return lights


def best_illuminant(curves: np.ndarray, gains) -> tuple[str, np.ndarray]:
    """The rawtoaces candidate (:func:`rawtoaces_illuminants`) whose white balance for
    ``curves`` is nearest the shot's ``gains`` (3,): least Σ (b_i / gains − 1)², both
    normalised to their least gain. Returns (name, (81,) spectrum)."""
    g = np.asarray(gains, dtype=np.float64)
    g = g / g.min()
    lights = rawtoaces_illuminants()
    name = min(lights, key=lambda n: np.sum((white_balance(curves, lights[n]) / g - 1) ** 2))
    return name, lights[name]


def _least_squares(residuals: Callable, x: np.ndarray, iterations: int = 200) -> np.ndarray:
    """Levenberg–Marquardt on ``residuals(x)`` (a vector), forward-difference
    Jacobian; stops when a step no longer lowers the sum of squares by 1e-12 of it."""
    r = residuals(x)
    cost, damping = r @ r, 1e-3
    for _ in range(iterations):
        h = 1e-7 * (1 + np.abs(x))
        jac = np.stack(
            [(residuals(x + h[i] * np.eye(len(x))[i]) - r) / h[i] for i in range(len(x))], 1
        )
        normal, grad = jac.T @ jac, jac.T @ r
        while True:
            step = np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-12), -grad)
            r_new = residuals(x + step)
            new = r_new @ r_new
            if new < cost:
                break
            damping *= 4
            if damping > 1e12:
                return x
        done = cost - new <= 1e-12 * cost
        x, r, cost, damping = x + step, r_new, new, damping / 3
        if done:
            break
    return x
