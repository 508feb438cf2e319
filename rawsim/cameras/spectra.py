"""Cameras' measured RGB spectral sensitivities: the curves of the Academy's
rawtoaces-data (Apache-2.0), under the camera database's names.

``spectra.json`` is built by ``tools/spectra/build.py``: 49 of the repository's 52
cameras, on the grid of :mod:`rawsim.spectral.tables` (380–780 nm, 5 nm), each with
its file, commit and licence. (ARRI D21, Insta360 X5 and Hasselblad L2D-20c are not
in the database: LibRaw reads none of their raws.) A profile has curves where its
camera does (:func:`of_profile`): the database's cameras by name, the bundled profiles
by their camera.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from importlib import resources

import numpy as np

from rawsim import cameras


@dataclass(frozen=True)
class Curves:
    """A camera's spectral sensitivities: ``rgb`` (81, 3) float64, relative, on
    :data:`rawsim.spectral.tables.WAVELENGTHS`; ``camera`` its database name;
    ``source`` its file, release, commit and licence, as one line."""

    camera: str
    label: str
    rgb: np.ndarray
    source: str


@cache
def _data() -> dict:
    return json.loads((resources.files("rawsim.cameras") / "spectra.json").read_text())


def names() -> list[str]:
    """The database names of the cameras that have curves, sorted."""
    return list(_data()["cameras"])


def labels() -> list[str]:
    """The cameras that have curves, as a person writes them ("Nikon D850"), sorted."""
    return sorted(cameras.find(n).label for n in names())


def of_camera(name: str) -> Curves | None:
    """The curves of the database camera ``name`` (any name :func:`rawsim.cameras.find`
    takes), None where it has none."""
    cam = cameras.find(name)
    entry = None if cam is None else _data()["cameras"].get(cam.name)
    if entry is None:
        return None
    src = _data()["source"]
    return Curves(
        camera=cam.name,
        label=cam.label,
        rgb=np.asarray(entry["rgb"], dtype=np.float64).T,
        source=(
            f"rawtoaces-data {src['release']} ({src['commit'][:12]}) {entry['file']}, "
            f"measured by {entry['creator']}, {entry['licence']}"
        ),
    )


def of_make_model(make: str, model: str) -> Curves | None:
    """The curves of the camera a file's Make and Model name (any form
    :func:`rawsim.cameras.find_camera` takes), None where it has none."""
    found = cameras.find_camera(make, model)
    return None if found is None else of_camera(found.name)


def of_profile(profile) -> Curves | None:
    """The curves of a :class:`~rawsim.cameras.profiles.SensorProfile`'s camera: a database
    camera's by its name, a bundled or user profile's by its make and model; None
    where the camera has none."""
    found = cameras.find(profile.name) if "_" in profile.name else None
    return of_camera(found.name) if found else of_make_model(profile.make, profile.model)
