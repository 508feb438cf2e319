"""Lens calibrations from lensfun's database: the lookup, and the remap both backends apply.

lensfun (through lensfunpy, used only here) knows cameras (their crop factor)
and lenses (their distortion, lateral chromatic aberration (TCA) and
vignetting, calibrated over focal length, aperture and distance). This module
finds the camera and lens of a raw (:func:`raw_lens`, from its metadata) or of a
name (:func:`lens_params`), records them as :class:`LensParams` (a plain dict
for sidecars, :meth:`LensParams.to_dict`), and turns them into a
:class:`LensField` for one image size: what the torch reference
(:mod:`rawsim.isp.lens`) and the compiled engine (:mod:`rawsim.engine.lens`)
evaluate, the same way, to correct the lens (``reverse=False``) or to add it to a
clean image (``reverse=True``).

**The field.** lensfun's distortion and TCA models (``poly3``, ``poly5``,
``ptlens``; ``linear``, ``poly3``) are radial about the lens centre: channel k of
the output pixel at radius r (pixels) samples the input at radius g_k(r) along
the same ray. g_k is sampled at least every pixel of radius from lensfun's own
``Modifier`` (``apply_subpixel_geometry_distortion``, one point per call: the
scalar code; lensfun's vectorised rows approximate 1/√ with SSE's ``rsqrt`` and
accumulate coordinates in float32, errors of 0.2–1 px on a 24 MP frame), so the
correction is lensfun's by construction, with lensfun's crop-factor and
aspect-ratio conventions, and costs 1-D tables instead of full-resolution
coordinate maps. Coordinates are lensfun's: pixel centres at integers, the
frame from 0 to W − 1. That the models are radial is checked at the frame's
corners for every field. The reverse inverts g_k numerically (it must be
monotone over the frame), so adding a lens and correcting it is an identity up
to resampling.

**Vignetting** (lensfun's ``pa`` model, V(ρ) = 1 + k1 ρ² + k2 ρ⁴ + k3 ρ⁶, ρ = 1
at the corner of the calibration sensor) is evaluated here, in lensfun's
coordinates: lensfunpy gives its gains only for whole images. Correcting
divides by V at the position each channel samples (lensfun devignettes the
source before remapping it); adding multiplies by V at the output pixel.

**Lateral CA on the mosaic.** lensfun applies TCA to the distorted (sensor)
coordinates that its distortion gives green: correcting a lens is TCA's field
(:func:`tca_field`, red and blue relative to green, in the sensor's frame) then the
field without TCA (:func:`without_tca`, every colour moved as green), to 1e-4 px.
:func:`mosaic_tca_fields` splits TCA's field into one field per red and blue
plane of a Bayer mosaic, so that the CA is taken out before the demosaic.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from rawsim.errors import ParameterError

#: What the lens stage can correct (lensfun's models), in the order they are recorded.
CORRECTIONS = ("distortion", "tca", "vignetting")
#: Focus distance (m) when the metadata has none: lensfunpy's default, "far".
DEFAULT_DISTANCE = 1000.0
#: Radius step (px) of lensfun's profile where the reverse samples it beyond the frame.
STEP = 1.0
#: Fewest intervals of a field's table: small images too resolve steep vignetting
#: (1/V of lensfun's data rises tenfold within 2 % of the radius at some corners).
MIN_KNOTS = 4096
#: Largest disagreement (px) between the radial tables and lensfun at the frame's
#: corners before a model counts as not radial.
RADIAL_TOLERANCE = 0.02


@dataclass(frozen=True)
class LensParams:
    """A lens and its settings, as recorded (``to_dict``) and replayed (``of``).

    Attributes:
        lens: the lens's model name as lensfun lists it.
        lens_maker: its maker in lensfun.
        lens_crop_factor: the crop factor of the sensor it was calibrated on
            (identifies the calibration among lensfun's entries of that name).
        crop_factor: the crop factor of the image's sensor (the camera's in
            lensfun; the lens's own where the camera is unknown).
        focal_length: mm, within the lens's range.
        aperture: f-number, or None (then no vignetting).
        distance: focus distance in m (> 0).
        corrections: which of :data:`CORRECTIONS` apply: those requested that
            lensfun has data for at this focal length (and aperture).
        camera: the camera as lensfun names it ("" if unknown), for the record.
    """

    lens: str
    lens_maker: str
    lens_crop_factor: float
    crop_factor: float
    focal_length: float
    aperture: float | None
    distance: float
    corrections: tuple[str, ...] = CORRECTIONS
    camera: str = ""
    lensfun: str = field(default="", compare=False)

    def to_dict(self) -> dict:
        """The record: plain JSON values (``corrections`` a list), with lensfun's version."""
        out = asdict(self)
        out["corrections"] = list(self.corrections)
        return out

    @classmethod
    def of(cls, value: LensParams | dict) -> LensParams:
        """``value`` itself, or its record (:meth:`to_dict`) checked."""
        if isinstance(value, LensParams):
            return value
        if not isinstance(value, dict):
            raise ParameterError(f"lens parameters must be a dict, got {type(value).__name__}")
        names = [f for f in cls.__dataclass_fields__]
        unknown = sorted(set(value) - set(names))
        missing = [k for k in names[:7] if k not in value]
        if unknown or missing:
            what = f"unknown key {unknown[0]!r}" if unknown else f"missing key {missing[0]!r}"
            raise ParameterError(f"lens parameters: {what}; keys: {', '.join(names)}")
        params = dict(value)
        params["corrections"] = tuple(params.get("corrections", CORRECTIONS))
        bad = [c for c in params["corrections"] if c not in CORRECTIONS]
        if bad:
            valid = ", ".join(CORRECTIONS)
            raise ParameterError(f"lens parameters: correction {bad[0]!r}; valid: {valid}")
        for key in ("lens_crop_factor", "crop_factor", "focal_length", "distance"):
            params[key] = _positive(params[key], f"lens parameters: {key}")
        if params["aperture"] is not None:
            params["aperture"] = _positive(params["aperture"], "lens parameters: aperture")
        return cls(**params)


def _positive(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{what} must be a number, got {value!r}")
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{what} must be finite and > 0, got {value!r}")
    return float(value)


# ------------------------------------------------------------------ the database
@functools.lru_cache(maxsize=1)
def database():
    """lensfun's database (lensfunpy's bundled files and any installed ones), loaded once."""
    import lensfunpy

    return lensfunpy.Database()


def lensfun_version() -> str:
    """The lensfun library's version, e.g. ``0.3.4``."""
    import lensfunpy

    return ".".join(str(v) for v in lensfunpy.lensfun_version[:3])


def find_camera(make: str, model: str):
    """lensfun's camera for EXIF ``make`` and ``model``, or None. A model without its
    make (``Canon``, ``EOS 700D``: rawsim's sensor profiles and the DNGs they write)
    is looked up as lensfun spells it too (``Canon EOS 700D``)."""
    make, model = _named(make), _named(model)
    if not make or not model:
        return None
    found = database().find_cameras(make, model)
    if not found and _camera_text(make, model) != model.strip():
        found = database().find_cameras(make, _camera_text(make, model))
    return found[0] if found else None


def _name(text: str) -> str:
    return " ".join(text.split()).casefold()


def find_lens(name: str, camera=None, required: bool = False):
    """lensfun's lens of this name: with a ``camera``, lensfun's own matching among the
    lenses that fit it, best first; without one (or none found there), the lens whose
    model is ``name`` (case and spacing aside), preferring one calibrated on a sensor
    no larger than the camera's. None if there is none, or with ``required`` a
    :class:`ParameterError` naming the closest lens lensfun knows."""
    db = database()
    if camera is not None:
        found = db.find_lenses(camera, None, name)
        exact = [lens for lens in found if _name(lens.model) == _name(name)]
        if exact or found:
            return (exact or found)[0]
    same = [lens for lens in db.lenses if _name(lens.model) == _name(name)]
    if camera is not None and same:
        fits = [lens for lens in same if lens.crop_factor <= camera.crop_factor * 1.01]
        same = sorted(fits or same, key=lambda lens: -lens.crop_factor)
    if same:
        return same[0]
    if not required:
        return None
    raise ParameterError(f"lens {name!r} is not in lensfun's database{_closest(name, camera)}")


def _closest(name: str, camera=None) -> str:
    """'; the closest is …' from lensfun's loose matching, or a hint where it has none."""
    db = database()
    found = db.find_lenses(camera, None, name, loose_search=True) if camera is not None else []
    if not found:
        import difflib

        models = {lens.model: lens for lens in db.lenses}
        near = difflib.get_close_matches(name, list(models), n=1, cutoff=0.5)
        found = [models[m] for m in near]
    if not found:
        return "; give its name as lensfun lists it (see lensfun's lens list)"
    return f"; the closest is {found[0].model!r} ({found[0].maker})"


def _lens_by_identity(params: LensParams):
    """The lens a record names (maker, model and calibration crop factor)."""
    for lens in database().lenses:
        if (
            lens.model == params.lens
            and lens.maker == params.lens_maker
            and abs(lens.crop_factor - params.lens_crop_factor) < 1e-3
        ):
            return lens
    raise ParameterError(
        f"lens {params.lens!r} ({params.lens_maker}, crop factor "
        f"{params.lens_crop_factor:g}) is not in this lensfun's database ({lensfun_version()})"
    )


# ------------------------------------------------------------------ parameters
def lens_params(
    lens: str,
    focal_length: float | None,
    aperture: float | None = None,
    distance: float | None = None,
    make: str = "",
    model: str = "",
    corrections: tuple[str, ...] = CORRECTIONS,
    adding: bool = False,
) -> tuple[LensParams, list[str]]:
    """The record of lens ``lens`` (its name as lensfun lists it) at ``focal_length``
    (mm; None: a prime's own, a zoom needs one), ``aperture`` (f-number, or None: no
    vignetting) and ``distance`` (m; None:
    :data:`DEFAULT_DISTANCE`) on the camera ``make``/``model`` (EXIF names), with
    one-line warnings: a camera lensfun does not know (the lens's calibration crop
    factor is assumed), corrections lensfun has no data for. ``adding``: the warnings
    speak of adding the lens (``rawsim unprocess --lens``), not of correcting it.

    Raises :class:`ParameterError` for a lens lensfun does not know (naming the
    closest), a focal length outside the lens's range, or none for a zoom.
    """
    warnings: list[str] = []
    what, done = ("lens", "added") if adding else ("lens correction", "corrected")
    camera = find_camera(make, model)
    found = find_lens(lens, camera, required=True)
    if focal_length is None:
        if found.max_focal > found.min_focal * 1.001:
            raise ParameterError(
                f"{found.model} is a zoom ({found.min_focal:g}–{found.max_focal:g} mm): "
                "pass --focal-length MM"
            )
        focal_length = found.min_focal
    focal = _positive(focal_length, "focal length")
    if not found.min_focal * 0.99 <= focal <= found.max_focal * 1.01:
        raise ParameterError(
            f"focal length {focal:g} mm is outside {found.model}'s "
            f"{found.min_focal:g}–{found.max_focal:g} mm: another lens? pass --lens NAME"
        )
    if camera is None:
        crop = found.crop_factor
        who = _camera_text(make, model)
        who = f"the camera {who!r}" if who else "the camera (the raw names none)"
        warnings.append(
            f"{what}: lensfun does not know {who}: assuming the sensor "
            f"{found.model} was calibrated on (crop factor {crop:.3g})"
        )
    else:
        crop = camera.crop_factor
    distance = DEFAULT_DISTANCE if distance is None else _positive(distance, "focus distance")
    aperture = None if aperture is None else _positive(aperture, "aperture")
    available = _available(found, focal, aperture, distance)
    if "vignetting" in corrections and aperture is None:
        warnings.append(f"{what}: no aperture known: vignetting not {done}; pass --aperture F")
    missing = [c for c in corrections if c not in available and (c != "vignetting" or aperture)]
    if missing:
        warnings.append(
            f"{what}: lensfun has no {' or '.join(missing)} data for {found.model} "
            f"at {focal:g} mm: not {done}"
        )
    params = LensParams(
        lens=found.model,
        lens_maker=found.maker,
        lens_crop_factor=float(found.crop_factor),
        crop_factor=float(crop),
        focal_length=focal,
        aperture=aperture,
        distance=distance,
        corrections=tuple(c for c in CORRECTIONS if c in corrections and c in available),
        camera="" if camera is None else _camera_text(camera.maker, camera.model),
        lensfun=lensfun_version(),
    )
    return params, warnings


def _available(lens, focal: float, aperture: float | None, distance: float) -> set[str]:
    """The corrections lensfun has data for (vignetting: its ``pa`` model, with an aperture)."""
    import lensfunpy

    out = set()
    dist = lens.interpolate_distortion(focal)
    if dist is not None and dist.model != lensfunpy.DistortionModel.NONE:
        out.add("distortion")
    tca = lens.interpolate_tca(focal)
    if tca is not None and tca.model != lensfunpy.TCAModel.NONE:
        out.add("tca")
    if aperture is not None:
        vig = lens.interpolate_vignetting(focal, aperture, distance)
        if vig is not None and vig.model == lensfunpy.VignettingModel.PA:
            out.add("vignetting")
    return out


def _number(text: str | None) -> float | None:
    """An EXIF rational or number as exiv2 writes it ("180/10", "5.6"), or None."""
    if not text:
        return None
    try:
        num, _, den = text.split()[0].partition("/")
        value = float(num) / float(den or 1)
    except (ValueError, ZeroDivisionError):
        return None
    return value if math.isfinite(value) and value > 0 else None


def raw_lens(
    make: str,
    model: str,
    metadata,
    lens: str = "auto",
    focal_length: float | str = "auto",
    aperture: float | str = "auto",
    distance: float | str = "auto",
    corrections: tuple[str, ...] = CORRECTIONS,
) -> tuple[LensParams | None, list[str]]:
    """The lens of a raw: from its metadata (a :class:`~rawsim.io.metadata.PhotoMetadata`:
    LensModel, FocalLength, FNumber, SubjectDistance) where a value is ``"auto"``,
    else the value given. Returns the record and one-line warnings, or None and the
    warning saying why the raw cannot be corrected and what to pass: no lens in the
    metadata (old raws), a lens lensfun does not know, no focal length.

    A lens named explicitly that lensfun does not know raises :class:`ParameterError`,
    as does an explicit focal length outside the lens's range.
    """
    name = metadata.get("Exif.Photo.LensModel") if lens == "auto" else lens
    camera_name = _camera_text(make, model)
    if not name:
        return None, [
            f"lens correction: the raw names no lens (no LensModel){_of(camera_name)}: "
            "not corrected; pass --lens NAME as lensfun lists it"
        ]
    camera = find_camera(make, model)
    if lens != "auto":
        find_lens(name, camera, required=True)  # a name the user gave: an error
    elif find_lens(name, camera) is None:
        return None, [
            f"lens correction: lens {name!r} (from the metadata) is not in lensfun's "
            f"database{_of(camera_name)}{_closest(name, camera)}: not corrected; "
            "pass --lens NAME if it is that lens"
        ]
    focal = focal_length
    if focal == "auto":
        focal = _number(metadata.get("Exif.Photo.FocalLength"))
    if focal is None:
        return None, [
            "lens correction: no focal length in the metadata: not corrected; "
            "pass --focal-length MM"
        ]
    fnumber = _number(metadata.get("Exif.Photo.FNumber")) if aperture == "auto" else aperture
    if distance == "auto":
        distance = _number(metadata.get("Exif.Photo.SubjectDistance"))
        distance = None if distance is None or distance > 1e6 else distance  # 2³²−1: infinity
    try:
        return lens_params(name, focal, fnumber, distance, make, model, corrections)
    except ParameterError as err:  # a focal length outside the lens's range
        if focal_length != "auto":
            raise
        return None, [f"lens correction: {err}: not corrected"]


def _camera_text(make: str, model: str) -> str:
    """ "Canon EOS 60D" for make Canon, model "Canon EOS 60D"; "SONY ILCE-6000";
    the model alone where the make is not known; "" where neither is."""
    make, model = _named(make), _named(model)
    if model.casefold().startswith(make.casefold()):
        return model
    return f"{make} {model}".strip()


def _named(name: str) -> str:
    """A camera name, or "" for none: rawsim's raws say "unknown" where the file
    names no make or model (:class:`~rawsim.io.raw.RawImage`), which is no name."""
    name = (name or "").strip()
    return "" if name.casefold() == "unknown" else name


def _of(camera: str) -> str:
    return f" for the {camera}" if camera else ""


# ------------------------------------------------------------------ the field
@dataclass(frozen=True)
class LensField:
    """The remap of one image size, as both backends evaluate it.

    Output pixel (y, x) (integers) lies at radius r = |(x − cx, y − cy)| from the lens
    centre; channel k of it is ``gain_k(r) · I_k(centre + (p − centre) · ratio_k(r))``,
    sampled by Lanczos-3 (:mod:`rawsim.resample`), where ``ratio_k`` and ``gain_k`` are
    interpolated linearly in
    ``table`` (n, 3, 2) float32 (``[:, k, 0]`` ratio, ``[:, k, 1]`` gain) at t = r · scale
    (float32): knots at most a pixel of radius apart (at least :data:`MIN_KNOTS`
    intervals), from the centre (t = 0) to the farthest pixel (t = n − 1).

    Attributes:
        height, width: the image it is for (pixels).
        centre: (cy, cx), the lens centre in pixel coordinates.
        scale: knots per pixel of radius (≥ 1), float32-exact.
        table: (n, 3, 2) float32, read-only.
        reverse: False: corrects the lens; True: adds it to a clean image.
    """

    height: int
    width: int
    centre: tuple[float, float]
    scale: float
    table: np.ndarray = field(repr=False)
    reverse: bool = False


def lens_field(
    params: LensParams | dict, height: int, width: int, reverse: bool = False
) -> LensField:
    """The :class:`LensField` of ``params`` for an image of ``height`` × ``width`` pixels
    (the frame the lens imaged: a half-size render gets its own). ``reverse``: the field
    that adds the lens (distortion, TCA, vignetting) to a clean image instead.

    Raises :class:`ParameterError` where lensfun's model is not radial, folds back
    within the frame (reverse), or its vignetting reaches 0.
    """
    return _field(LensParams.of(params), int(height), int(width), bool(reverse))


@functools.lru_cache(maxsize=16)
def _field(params: LensParams, height: int, width: int, reverse: bool) -> LensField:
    import lensfunpy

    if height < 1 or width < 1:
        raise ParameterError(f"lens field: image of {height} × {width} pixels")
    lens = _lens_by_identity(params)
    # lensfun's frame: pixel centres at 0 … W − 1; its unit is half the shorter side.
    wm, hm = max(width - 1, 1), max(height - 1, 1)
    size = min(wm, hm)
    cx, cy = (wm + lens.center_x * size) / 2, (hm + lens.center_y * size) / 2
    corners = [(0, 0), (width - 1, 0), (0, height - 1), (width - 1, height - 1)]
    reach = max(max(math.hypot(x - cx, y - cy) for x, y in corners), 1.0)
    n = max(int(math.ceil(reach)), MIN_KNOTS) + 1  # ≤ 1 px apart, the last at the farthest pixel
    radii = np.linspace(0.0, reach, n)
    scale = float(np.float32((n - 1) / reach))

    flags = 0
    if "distortion" in params.corrections:
        flags |= lensfunpy.ModifyFlags.DISTORTION
    if "tca" in params.corrections:
        flags |= lensfunpy.ModifyFlags.TCA
    modifier = None
    if flags:
        modifier = lensfunpy.Modifier(lens, params.crop_factor, width, height)
        modifier.initialize(
            params.focal_length,
            params.aperture or lens.min_aperture or 8.0,  # used by vignetting only
            params.distance,
            scale=1.0,
            targeom=lens.type,
            pixel_format=np.float32,
            flags=flags,
            reverse=False,
        )

    def profile(r: np.ndarray) -> np.ndarray:
        """(len(r), 3) radii g_k(r) where lensfun samples channel k for radius r."""
        return _radial_profile(modifier, cx, cy, r)

    if not reverse:
        source = profile(radii)
        ratio = _ratio(source, radii)
        check = _radial_check(modifier, cx, cy, corners, radii, ratio)
    else:
        # g_k over enough radius that it passes the farthest output pixel, then inverted.
        top = reach + 2 * STEP
        while True:
            r_u = np.arange(int(math.ceil(top / STEP)) + 1) * STEP
            g = profile(r_u)
            if (g[-1] >= reach + STEP).all() or top > 8 * reach + 8:
                break
            top *= 1.25
        for k in range(3):
            rising = np.diff(g[:, k]) > 0
            last = np.searchsorted(g[:, k], reach + STEP)
            if not rising[: max(last, 1)].all() or g[-1, k] < reach + STEP:
                raise ParameterError(
                    f"lens {params.lens!r} at {params.focal_length:g} mm: lensfun's model folds "
                    "back within the frame: it cannot be inverted to add the lens"
                )
        source = np.stack([np.interp(radii, g[:, k], r_u) for k in range(3)], axis=1)
        ratio = _ratio(source, radii)
        forward = np.stack([np.interp(radii, r_u, g[:, k]) for k in range(3)], axis=1)
        check = _radial_check(modifier, cx, cy, corners, radii, _ratio(forward, radii))
    if check is not None:
        raise ParameterError(
            f"lens {params.lens!r} at {params.focal_length:g} mm: lensfun's model is not radial "
            f"about the lens centre (off by {check:.3g} px at a corner): rawsim cannot evaluate it"
        )

    gain = np.ones((n, 3))
    if "vignetting" in params.corrections:
        vig = lens.interpolate_vignetting(params.focal_length, params.aperture, params.distance)
        k1, k2, k3 = vig.terms[:3]
        # ρ = 1 at the corner of the calibration sensor (lensfun's vignetting unit). Where a
        # channel samples beyond the frame's farthest pixel (there is only padding there)
        # the gain holds its value at that radius.
        unit = 2 * params.lens_crop_factor / (params.crop_factor * math.hypot(wm, hm))
        at = radii[:, None] if reverse else np.minimum(source, reach)
        rho2 = (unit * at) ** 2
        v = 1 + k1 * rho2 + k2 * rho2**2 + k3 * rho2**3
        if not (v > 0).all():
            raise ParameterError(
                f"lens {params.lens!r}: lensfun's vignetting reaches 0 within the frame at "
                f"{params.focal_length:g} mm, f/{params.aperture:g}: correct without vignetting"
            )
        gain = v * np.ones((1, 3)) if reverse else 1 / v
    table = np.stack([ratio, gain], axis=-1).astype(np.float32)
    table.flags.writeable = False
    return LensField(height, width, (float(cy), float(cx)), scale, table, reverse)


def without_tca(params: LensParams | dict) -> LensParams:
    """``params`` without the TCA correction: its field moves every colour as green."""
    params = LensParams.of(params)
    return replace(params, corrections=tuple(c for c in params.corrections if c != "tca"))


def tca_field(params: LensParams | dict, height: int, width: int) -> LensField:
    """The field of ``params``'s lateral CA alone (gains 1, green's ratio 1): where
    red and blue sit relative to green, in the frame the lens imaged."""
    params = LensParams.of(params)
    return lens_field(replace(params, corrections=("tca",)), height, width)


def mosaic_tca_fields(
    params: LensParams | dict, colors: tuple[int, ...], height: int, width: int
) -> list[tuple[int, int, LensField]]:
    """(row, column, field) for each red and blue site of a 2 × 2 Bayer period
    (``colors``: the colour of sites (0, 0), (0, 1), (1, 0), (1, 1); 0 R, 1 G, 2 B) on
    a mosaic of ``height`` × ``width``: the field (:func:`tca_field`) on that site's own
    plane (``mosaic[row::2, column::2]``: half the pixels each way, its centre moved
    and halved, its radius in plane pixels), every channel of its table the site's
    colour's. A grey remap (:func:`rawsim.isp.lens.remap_lens`) of the plane through
    it puts that colour where green is."""
    full = tca_field(params, height, width)
    cy, cx = full.centre
    out = []
    for site, colour in enumerate(colors):
        if colour == 1:
            continue
        oy, ox = divmod(site, 2)
        table = np.ascontiguousarray(full.table[:, [colour] * 3, :])
        table.flags.writeable = False
        plane = LensField(
            (height - oy + 1) // 2,
            (width - ox + 1) // 2,
            ((cy - oy) / 2, (cx - ox) / 2),
            float(np.float32(2 * full.scale)),
            table,
        )
        out.append((oy, ox, plane))
    return out


def _radial_profile(modifier, cx: float, cy: float, radii: np.ndarray) -> np.ndarray:
    """(len(radii), 3): the radius at which lensfun samples each channel for an output
    pixel at radius r, along the ray to the right of the centre; r where it corrects nothing."""
    out = np.repeat(radii[:, None].astype(np.float64), 3, axis=1)
    if modifier is None:
        return out
    ray = np.float32(cx) + radii.astype(np.float32)  # the points lensfun evaluates
    r_in = ray.astype(np.float64) - cx
    apply = modifier.apply_subpixel_geometry_distortion
    y = float(np.float32(cy))
    found = np.empty((radii.size, 3))
    for i, x in enumerate(ray.tolist()):
        coords = apply(x, y, 1, 1)
        if coords is None:
            return out
        found[i] = np.hypot(coords[0, 0, :, 0] - cx, coords[0, 0, :, 1] - cy)
    # back onto the requested radii (float32 moved the points by < 0.5 ulp)
    return np.stack([np.interp(radii, r_in, found[:, k]) for k in range(3)], axis=1)


def _ratio(source: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """source / r per channel; at r = 0, extrapolated from the next two entries."""
    ratio = np.ones_like(source)
    ratio[1:] = source[1:] / radii[1:, None]
    if len(radii) > 2:
        ratio[0] = 2 * ratio[1] - ratio[2]
    return ratio


def _radial_check(modifier, cx, cy, corners, radii, ratio) -> float | None:
    """The largest gap (px) between lensfun's coordinates at the frame's corners and
    the radial tables', if above :data:`RADIAL_TOLERANCE`; else None."""
    if modifier is None:
        return None
    worst = 0.0
    for x, y in corners:
        coords = modifier.apply_subpixel_geometry_distortion(float(x), float(y), 1, 1)
        if coords is None:
            return None
        r = math.hypot(x - cx, y - cy)
        for k in range(3):
            q = np.interp(r, radii, ratio[:, k])
            expect = (cx + (x - cx) * q, cy + (y - cy) * q)
            worst = max(worst, float(np.hypot(*(coords[0, 0, k] - expect))))
    return worst if worst > RADIAL_TOLERANCE else None
