"""A spectral scene seen by a camera: its raw camera RGB, exactly, from the camera's
spectral sensitivities and the light.

The raw value of channel c at a pixel is the sum over the grid
(:data:`~rawsim.spectral.tables.WAVELENGTHS`, 380–780 nm, 5 nm) of

- ``curve_c · light · reflectance`` for a reflectance scene,
- ``curve_c · radiance`` for a radiance scene,

divided by ``Σ curve_G · light``: a perfect white reflector under the light (or a
radiance equal to the light) gives G = 1, as sRGB white gives G = 1 after the RGB path's
inverse white balance, and R, B the camera's neutral (:func:`neutral`, the DNG's
AsShotNeutral). The scene is put on the grid by linear interpolation, its end values
held beyond its ends (:func:`rawsim.spectral.tables.resample`); as interpolation is
linear, the sum is taken through the (N, 3) weights it gives the scene's own bands
(:func:`band_weights`), the same numbers with no (81, H, W) copy of the scene. The
sum is the compiled engine's (:mod:`rawsim.engine.spectral`), which reads the scene
where it lies, with :func:`integrate` its torch reference.

A named light is the CIE's (or ISO's) table scaled to 100 at 560 nm
(:func:`rawsim.spectral.tables.illuminant`), as is a light read from a file; a light a
scene carries as a spectrum is taken as it is, in the scene's units.

Shapes: curves (81, 3), spectra on the grid (81,), scenes (H, W, N) with N wavelengths.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rawsim.cameras import spectra
from rawsim.errors import ParameterError
from rawsim.spectral import fit, tables

if TYPE_CHECKING:
    import torch

#: How many cameras a refusal names before "… and N more".
_NAMED = 12
#: DNG CalibrationIlluminant codes (EXIF LightSource) of the two matrices written.
ILLUMINANT_A, ILLUMINANT_D65 = tables.LIGHT_SOURCES["A"], tables.LIGHT_SOURCES["D65"]


@dataclass(frozen=True)
class Light:
    """The light a scene is rendered under: ``spectrum`` (81,) on the grid; ``name``
    (a table's name, a file's path, or ``"the scene's spectrum"``); ``origin``:
    ``"scene"`` (it carries it), ``"--illuminant"`` (given), ``"default"`` (D65 for a
    reflectance scene that has none); ``file``: whether ``name`` is a file read."""

    spectrum: np.ndarray
    name: str
    origin: str
    file: bool = False


def curves_for(profile) -> spectra.Curves:
    """The spectral sensitivities a profile's camera is simulated with: its measured or
    estimated ones (:mod:`rawsim.cameras.spectra`), else a seed config's
    ``wavelengths`` and ``*_spectral_response`` put on the grid. Raises
    :class:`ParameterError` naming the cameras that have measured curves where it has
    none of these."""
    known = spectra.of_profile(profile)
    if known is not None:
        return known
    seed = profile.spectral
    if seed is not None:
        where = f"profile {profile.name!r} ({profile.path or 'config'})"
        rgb = tables.resample(
            seed["wavelengths"],
            np.column_stack([seed["red"], seed["green"], seed["blue"]]),
            f"{where}: its spectral responses",
        )
        source = f"{where}: its wavelengths and red/green/blue_spectral_response"
        return spectra.Curves(profile.name, profile.name, rgb, source)
    names = spectra.labels()
    more = len(names) - _NAMED
    listed = ", ".join(names[:_NAMED])
    if more > 0:
        listed += f" and {more} more"
    raise ParameterError(
        f"profile {profile.name!r} ({profile.make} {profile.model}) has no spectral "
        f"sensitivities, so it cannot see a spectral scene: give --profile a camera of "
        f"the database (measured curves: {listed}; the curves column of 'rawsim profiles "
        "list' marks the estimated ones)"
    )


def light_of(carried: np.ndarray | str | None, given: str | None, nm, kind: str, what: str):
    """The :class:`Light` a scene is rendered under and a warning or None: ``given``
    (``--illuminant``: a name or a file) where there is one, else the one the scene
    ``carried`` (a name, or a spectrum on its wavelengths ``nm``), else D65 for a
    reflectance; a radiance without either is refused (``what`` names the file)."""
    warning = None
    if given is not None:
        named = str(given).upper() in tables.ILLUMINANTS
        name = str(given).upper() if named else str(given)
        if carried is not None:
            said = carried if isinstance(carried, str) else "a spectrum"
            warning = f"the scene carries its illuminant ({said}); --illuminant {name} is used"
        return Light(tables.illuminant(given), name, "--illuminant", not named), warning
    if isinstance(carried, str):
        try:
            return Light(tables.illuminant(carried), carried.upper(), "scene"), None
        except ParameterError:
            raise ParameterError(
                f"{what}: unknown illuminant {carried!r}: name one of "
                f"{', '.join(tables.ILLUMINANTS)}, or give --illuminant"
            ) from None
    if carried is not None:
        light = tables.resample(nm, carried, f"{what}: its illuminant")
        return Light(light, "the scene's spectrum", "scene"), None
    if kind == "radiance":
        raise ParameterError(
            f"{what}: a radiance scene needs its illuminant, to know its white: give "
            f"--illuminant ({', '.join(tables.ILLUMINANTS)} or a file), or store one in it"
        )
    return Light(tables.illuminant("D65"), "D65", "default"), None


def band_weights(nm, curves: np.ndarray, light: np.ndarray, kind: str) -> np.ndarray:
    """(N, 3) float64 weights of a scene's N bands at wavelengths ``nm``: raw camera RGB
    = scene (…, N) @ weights (see the module's notes for the normalisation)."""
    nm = np.asarray(nm, dtype=np.float64)
    onto_grid = tables.resample(nm, np.eye(len(nm)), "the scene's wavelengths")  # (81, N)
    white = curves[:, 1] @ light
    if not white > 0:
        raise ParameterError("the camera's green curve sees nothing of this light")
    seen = curves * light[:, None] if kind == "reflectance" else curves
    return onto_grid.T @ seen / white


def camera_rgb(
    scene: np.ndarray, nm, curves: np.ndarray, light: np.ndarray, kind: str, *, engine=None
) -> np.ndarray:
    """(H, W, 3) float32 raw camera RGB of ``scene`` (H, W, N), float32 of any strides,
    at wavelengths ``nm``: linear, white (reflectance 1) at G = 1; summed in float64
    through the :func:`band_weights`. ``engine``: by the compiled kernel
    (:func:`rawsim.engine.spectral.integral_kernel`, which reads the scene in place)
    or by the torch reference (:func:`integrate`); None: the kernel where numba is
    installed."""
    weights = band_weights(nm, curves, light, kind)
    if engine is None:
        from rawsim import engine as compiled

        engine = compiled.available()
    if engine:
        from rawsim.engine.spectral import camera_rgb as compiled_rgb

        return compiled_rgb(np.asarray(scene, np.float32), weights)
    return integrate(scene, weights).numpy()


#: Rows of a scene :func:`integrate` takes at a time: its float64 copy of them is
#: 8 · W · N bytes a row (40 MB for 64 rows of a 2448-wide, 31-band scene).
REFERENCE_ROWS = 64


def integrate(scene: np.ndarray, weights: np.ndarray, device="cpu") -> torch.Tensor:
    """The torch reference of :func:`rawsim.engine.spectral.integral_kernel`: (H, W, 3)
    float32 on ``device``, ``scene`` (H, W, N) times ``weights`` (N, 3), a float64
    einsum over :data:`REFERENCE_ROWS` rows at a time (each copied to ``device``)."""
    import torch

    h, w, n = scene.shape
    if weights.shape != (n, 3):
        raise ParameterError(f"scene {scene.shape} and weights {weights.shape} do not match")
    by = torch.as_tensor(weights, dtype=torch.float64, device=device)
    out = torch.empty((h, w, 3), dtype=torch.float32, device=device)
    for top in range(0, h, REFERENCE_ROWS):
        rows = slice(top, top + REFERENCE_ROWS)
        strip = torch.tensor(scene[rows], dtype=torch.float64, device=device)
        out[rows] = torch.einsum("hwn,nc->hwc", strip, by).float()
    return out


def neutral(curves: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(3,) the camera's response to ``light``'s white, G = 1: the DNG's AsShotNeutral."""
    white = curves.T @ light
    return white / white[1]


_fits: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}


def dng_matrices(curves: spectra.Curves) -> tuple[np.ndarray, np.ndarray]:
    """((3, 3) XYZ → camera under illuminant A, the same under D65): the DNG's
    ColorMatrix1 and ColorMatrix2 (:func:`rawsim.spectral.fit.color_matrix`), fitted
    once per camera."""
    key = (curves.camera, curves.source)
    if key not in _fits:
        _fits[key] = tuple(
            fit.color_matrix(curves.rgb, tables.illuminant(n)).xyz_to_camera for n in ("A", "D65")
        )
    return _fits[key]


def record(kind: str, wavelengths, curves: spectra.Curves, light: Light, neutral, matrices):
    """The sidecar's ``spectral`` record of a scene seen: its ``kind``, ``wavelengths``
    (nm), the ``curves`` (camera, kind, source), the ``light`` (:func:`light_record`),
    the camera's ``neutral`` and the DNG's ``matrices`` (XYZ → camera under A and
    D65)."""
    a, d65 = matrices
    return {
        "kind": kind,
        "wavelengths": [float(v) for v in wavelengths],
        "curves": {"camera": curves.label, "kind": curves.kind, "source": curves.source},
        "illuminant": light_record(light),
        "neutral": [float(v) for v in neutral],
        "color_matrix_1": {"illuminant": "A", "xyz_to_camera": a.tolist()},
        "color_matrix_2": {"illuminant": "D65", "xyz_to_camera": d65.tolist()},
    }


def light_record(light: Light) -> dict:
    """The sidecar's record of a :class:`Light`: its name (or file), whether it was read
    from a file, and where it came from (the scene, ``--illuminant``, the default)."""
    return {"name": light.name, "file": light.file, "origin": light.origin}
