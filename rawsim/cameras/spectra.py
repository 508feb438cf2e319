"""Cameras' RGB spectral sensitivities, under the camera database's names: measured
(the curves of the Academy's rawtoaces-data, Apache-2.0) or estimated from the
camera's colour matrix.

``spectra.json`` is built by ``tools/spectra/build.py``: 49 of the repository's 52
cameras, on the grid of :mod:`rawsim.spectral.tables` (380–780 nm, 5 nm), each with
its file, commit and licence. (ARRI D21, Insta360 X5 and Hasselblad L2D-20c are not
in the database: LibRaw reads none of their raws.) A profile has curves where its
camera does (:func:`of_profile`): the database's cameras by name, the bundled profiles
by their camera.

``spectra_estimated.json`` is built by ``tools/spectra/estimate.py``: for each database
camera without measured curves, the curves in the space of the 52 measured cameras'
(the mean and two principal components per channel) that reproduce its D65
XYZ → camera matrix (Adobe's, as LibRaw tabulates it) best, stored as coefficients of
that basis and rebuilt on loading. Their leave-one-out error on the measured cameras
is :func:`leave_one_out`. A camera whose matrix no curves in that space reproduce as
well as twice the measured cameras' worst (old CMY and four-colour sensors, some
backs: ``not_estimated``) has none.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from importlib import resources

import numpy as np

from rawsim import cameras
from rawsim.errors import ParameterError

#: What a camera's curves are: ``measured`` (rawtoaces-data), ``estimated`` (from its
#: colour matrix), ``given`` (a profile's own ``*_spectral_response``).
KINDS = ("measured", "estimated", "given")


@dataclass(frozen=True)
class Curves:
    """A camera's spectral sensitivities: ``rgb`` (81, 3) float64, ≥ 0, relative, on
    :data:`rawsim.spectral.tables.WAVELENGTHS`; ``camera`` its database name;
    ``source`` where they come from (a measurement's file, release, commit and
    licence, or the estimate's method), as one line; ``kind`` one of :data:`KINDS`."""

    camera: str
    label: str
    rgb: np.ndarray
    source: str
    kind: str = "given"


@cache
def _data() -> dict:
    return json.loads((resources.files("rawsim.cameras") / "spectra.json").read_text())


@cache
def _estimated() -> dict:
    return json.loads((resources.files("rawsim.cameras") / "spectra_estimated.json").read_text())


@cache
def _basis() -> np.ndarray:
    return np.asarray(_estimated()["basis"]["vectors"], dtype=np.float64)


def names(kind: str = "measured") -> list[str]:
    """The database names of the cameras that have curves of ``kind`` ("measured",
    "estimated" or "any"), sorted."""
    if kind == "measured":
        return list(_data()["cameras"])
    if kind == "estimated":
        return list(_estimated()["cameras"])
    if kind == "any":
        return sorted([*_data()["cameras"], *_estimated()["cameras"]])
    raise ParameterError(f"no curves of kind {kind!r}: measured, estimated or any")


def labels(kind: str = "measured") -> list[str]:
    """The cameras that have curves of ``kind`` (:func:`names`), as a person writes
    them ("Nikon D850"), sorted."""
    return sorted(cameras.find(n).label for n in names(kind))


def leave_one_out() -> dict:
    """The estimate's leave-one-out error on the 49 measured cameras of the database
    (each estimated in a basis of the other 51 from its Adobe matrix): ``rms`` (each
    channel at a peak of 1; mean, worst) and ``delta_e00_D65``, ``delta_e00_A`` (the
    ColorChecker's patches as the measured curves see them against as the estimated
    curves see them, each through the matrix fitted for its own curves under that
    light; mean over all patches, worst camera's mean, worst patch), and
    ``per_camera``: {name: {"rms", "delta_e00_D65": [mean, max], "delta_e00_A"}}."""
    return _estimated()["leave_one_out"]


def not_estimated(profile) -> tuple[float, float] | None:
    """Where a :class:`~rawsim.cameras.profiles.SensorProfile`'s camera got no estimate
    as its matrix is too far from the measured cameras': the (mean, worst) ΔE00 with
    which that matrix renders the training patches seen through the best curves of the
    basis; None for other cameras."""
    cam = _camera_of(profile)
    found = None if cam is None else _estimated()["not_estimated"].get(cam.name)
    return None if found is None else tuple(found)


def of_camera(name: str) -> Curves | None:
    """The curves of the database camera ``name`` (any name :func:`rawsim.cameras.find`
    takes): the measured ones where it has them, else the estimated ones; None where it
    has neither."""
    cam = cameras.find(name)
    if cam is None:
        return None
    entry = _data()["cameras"].get(cam.name)
    if entry is not None:
        src = _data()["source"]
        return Curves(
            camera=cam.name,
            label=cam.label,
            rgb=np.asarray(entry["rgb"], dtype=np.float64).T,
            source=(
                f"rawtoaces-data {src['release']} ({src['commit'][:12]}) {entry['file']}, "
                f"measured by {entry['creator']}, {entry['licence']}"
            ),
            kind="measured",
        )
    entry = _estimated()["cameras"].get(cam.name)
    if entry is None:
        return None
    b = np.asarray(entry["coefficients"], dtype=np.float64)
    # ≥ 0 as fitted; the coefficients' rounding to six digits may dip a hair below
    rgb = np.maximum(np.einsum("cwk,ck->wc", _basis(), b), 0.0)
    method, loo = _estimated()["method"], leave_one_out()
    de_a, (mean, _) = loo["delta_e00_A"], entry["matrix_delta_e00"]
    low, _, high = method["measured_matrix_delta_e00"]
    return Curves(
        camera=cam.name,
        label=cam.label,
        rgb=rgb,
        source=(
            "estimated from its D65 matrix (Adobe's, as LibRaw tabulates it) in the space "
            f"of rawtoaces-data's 52 measured cameras' curves ({method['built_by']}): "
            f"through them that matrix renders the 190 training patches {mean:.2f} ΔE00 off "
            f"on average (the measured cameras: {low:.2f}–{high:.2f}); leave-one-out on "
            f"{loo['cameras']} measured cameras: ΔE00 under A {de_a['mean']:.2f} mean, "
            f"{de_a['worst_patch']:.2f} worst patch"
        ),
        kind="estimated",
    )


def of_make_model(make: str, model: str) -> Curves | None:
    """The curves of the camera a file's Make and Model name (any form
    :func:`rawsim.cameras.find_camera` takes), None where it has none."""
    found = cameras.find_camera(make, model)
    return None if found is None else of_camera(found.name)


def of_profile(profile) -> Curves | None:
    """The curves of a :class:`~rawsim.cameras.profiles.SensorProfile`'s camera
    (:func:`of_camera`): a database camera's by its name, a bundled or user profile's
    by its make and model; None where the camera has none."""
    found = _camera_of(profile)
    return None if found is None else of_camera(found.name)


def _camera_of(profile) -> cameras.Camera | None:
    found = cameras.find(profile.name) if "_" in profile.name else None
    return found or cameras.find_camera(profile.make, profile.model)
