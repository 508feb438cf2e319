"""The noise model of any raw: per colour, variance = a · s + b (DN²) at s DN above black.

:func:`noise_model_for` takes the first of these that exists, and says which:

1. ``profile``: a profile the user names (``--noise-profile``: a bundled name or a
   JSON file, such as ``rawsim calibrate``'s output), at the raw's ISO;
2. ``camera profile``: the bundled profile whose make and model are the raw's;
3. ``dng``: the raw's DNG NoiseProfile tag (rawsim's own DNGs carry one), one
   (S, O) pair for every colour or one per colour plane, in units of the DNG's
   own black-to-white range;
4. ``estimate``: a fit to the raw itself, by the patch method of ``rawsim
   calibrate`` (the flattest blocks of each signal level, after Foi et al. 2008),
   on at most :data:`ESTIMATE_SITES` sites (a centred crop of larger raws).
   Where that fit is unsure, it is still used and the reason is warned; where it
   gives no line, the read noise alone is taken from the flattest blocks (the
   model is then signal-independent, and said so).

The camera database's model for the raw's camera (:mod:`rawsim.cameras`; noise
estimated from the pixel size for most cameras) is not taken by default: it is
named beside the estimate (:func:`database_note`), and ``--noise-profile "MAKE
MODEL"`` takes it. On the real raws of four older cameras (Canon EOS D30, PowerShot
S40 and G2, Nikon D1), the database's gain was 0.05–0.25 × the raw's own fit, that
is a full well of 228 000 e⁻ for the D30's 10.5 µm pixels and 40 000 e⁻ for the
S40's 3.4 µm ones, where their fits give 32 000 and 6 400: the pixel-size law was
fitted on modern sensors.

A profile's figures are the affine variance of its noise model at the ISO
(:meth:`~rawsim.noise.spec.NoiseLevels.affine_variance`: gain K, read, row and
quantisation variance), in the profile's DN; a raw from the same camera has the
same DN. An ISO outside the profile's range is clamped to it, with a warning.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rawsim.errors import ParameterError
from rawsim.io.raw import RawImage

SOURCES = ("profile", "camera profile", "dng", "estimate")
#: Sites the estimate reads at most: larger raws give a centred crop of this many
#: (whole CFA periods), where the noise is the same and the fit takes a second, not five.
ESTIMATE_SITES = 6_000_000
#: The smallest variance gain a (DN²/DN) the transform is given: a signal-independent
#: model gets this much shot noise, far below any sensor's, so the transform stays finite.
MIN_GAIN = 1e-6


@dataclass(frozen=True)
class NoiseModel:
    """Variance ``a[c]·s + b[c]`` (DN²) of a site of colour c (R, G, B) at s DN above
    black, where it came from (:data:`SOURCES`) and what exactly (``detail``)."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    source: str
    detail: str
    warnings: tuple[str, ...] = field(default_factory=tuple)

    def normalised(self, span: float) -> tuple[list[float], list[float]]:
        """(gain, offset) per colour for values normalised by ``span`` DN (white = 1):
        variance gain·x + offset."""
        gain = [max(a / span, MIN_GAIN) for a in self.a]
        return gain, [b / span**2 for b in self.b]

    @classmethod
    def from_dict(cls, d: dict) -> NoiseModel:
        """The model :meth:`to_dict` recorded."""
        a, b = tuple(d["variance_per_dn"]), tuple(d["variance_at_black_dn2"])
        return cls(a, b, d["source"], d["detail"])

    def to_dict(self) -> dict:
        """As the sidecar and ``rawsim info`` record it."""
        return {
            "source": self.source,
            "detail": self.detail,
            "variance_per_dn": list(self.a),
            "variance_at_black_dn2": list(self.b),
            "channels": ["R", "G", "B"],
        }


def stage_model(resolved) -> tuple[list[float], list[float]]:
    """(gain, offset) per colour of the model a resolved config (its ``raw_denoise``
    stage's ``info["noise_model"]``) holds, in the units its black level stage gives."""
    span = resolved.white_level - float(np.mean(resolved.raw.black_level))
    return NoiseModel.from_dict(resolved.info["noise_model"]).normalised(span)


def noise_model_for(raw: RawImage, profile: str | Path | None = None) -> NoiseModel:
    """The noise model of ``raw`` (see the module doc); ``profile`` a name or file."""
    if profile is not None:
        return _from_profile(raw, str(profile), "profile")
    match = camera_profile(raw)
    if match is not None:
        return _from_profile(raw, match, "camera profile")
    tag = dng_noise_profile(raw)
    if tag is not None:
        return tag
    model = estimate(raw)
    note = database_note(raw)
    return model if note is None else replace(model, detail=f"{model.detail}; {note}")


def database_note(raw: RawImage) -> str | None:
    """What the camera database's model for ``raw``'s camera gives (gain K and read σ
    at the raw's ISO, its kind) and how to take it instead, or None where the database
    does not hold the camera or the raw records no ISO."""
    from rawsim.cameras import find_camera

    cam = find_camera(raw.make, raw.model)
    if cam is None or not float(raw.iso or 0) > 0:
        return None
    name = cam.bundled or cam.name
    model = _from_profile(raw, name, "profile")
    return (
        f"the camera database's {cam.noise_kind} model for the {cam.label} gives K "
        f"{model.a[1]:.4g} DN/e-, read σ {math.sqrt(model.b[1]):.4g} DN "
        f"(--noise-profile {name} takes it)"
    )


def camera_profile(raw: RawImage) -> str | None:
    """The bundled profile made for ``raw``'s camera (make and model), or None."""
    return _bundled_cameras().get(_folded(raw.make, raw.model))


@functools.cache
def _bundled_cameras() -> dict[str, str]:
    """Each bundled profile's camera (:func:`_folded`) → its name, read once a process."""
    from rawsim.cameras.profiles import list_profiles, load_profile

    cameras = {}
    for name in list_profiles():
        p = load_profile(name)
        cameras.setdefault(_folded(p.make, p.model), name)
    return cameras


def _folded(make: str, model: str) -> str:
    """'Canon', 'Canon EOS 700D' → 'canon eos 700d': the model with the make once."""
    make, model = " ".join(make.split()).casefold(), " ".join(model.split()).casefold()
    return model if model.startswith(make) else f"{make} {model}"


def _from_profile(raw: RawImage, name: str, source: str) -> NoiseModel:
    from rawsim.cameras.profiles import load_profile

    p = load_profile(name)
    warnings = []
    iso = float(raw.iso)
    if not iso > 0:
        raise ParameterError(
            f"{raw.path}: the raw records no ISO, so profile {p.name!r} gives no noise "
            "level; give --noise-profile a calibrated file for this ISO, or leave it out "
            "(rawsim then estimates the noise from the raw)"
        )
    if p.iso_range is not None and not p.iso_range[0] <= iso <= p.iso_range[1]:
        clamped = min(max(iso, p.iso_range[0]), p.iso_range[1])
        warnings.append(
            f"ISO {iso:g} is outside profile {p.name!r}'s range; its noise at ISO "
            f"{clamped:g} is used"
        )
        iso = clamped
    model = "physics" if p.noise.has_physics else "poisson-gaussian"
    a, b = p.noise.levels(model, iso).affine_variance(float(p.white_level - p.black_level))
    return NoiseModel(
        (a,) * 3, (b,) * 3, source, f"{p.name} ({model}) at ISO {iso:g}", tuple(warnings)
    )


def dng_noise_profile(raw: RawImage) -> NoiseModel | None:
    """The model from the raw's DNG NoiseProfile tag (51041), or None without one."""
    import tifffile

    try:
        with tifffile.TiffFile(raw.path) as tif:
            pages = [page for top in tif.pages for page in (top, *(top.pages or ()))]
            values = next((p.tags[51041].value for p in pages if 51041 in p.tags), None)
    except Exception:  # not TIFF-based, or unreadable here: LibRaw read it
        return None
    if values is None:
        return None
    pairs = np.asarray(values, dtype=np.float64).reshape(-1, 2)
    if not (np.isfinite(pairs).all() and (pairs[:, 0] >= 0).all() and (pairs[:, 1] >= 0).all()):
        return None
    span = float(raw.white_level) - float(np.mean(raw.black_level))
    if len(pairs) not in (1, 3):
        pairs = pairs[:1]  # planes other than R, G, B: the first stands for all
    s, o = (pairs[:, 0], pairs[:, 1]) if len(pairs) == 3 else (pairs[[0] * 3, 0], pairs[[0] * 3, 1])
    return NoiseModel(
        tuple(float(v * span) for v in s),
        tuple(float(v * span**2) for v in o),
        "dng",
        "the DNG NoiseProfile tag",
    )


def _central(raw: RawImage) -> RawImage:
    """``raw``, or for one of more than :data:`ESTIMATE_SITES` sites its centred crop of
    about that many, starting on a whole CFA period."""
    from dataclasses import replace

    h, w = raw.data.shape[:2]
    if h * w <= ESTIMATE_SITES:
        return raw
    scale = math.sqrt(ESTIMATE_SITES / (h * w))
    ph, pw = raw.cfa.period
    ch, cw = int(h * scale) // ph * ph, int(w * scale) // pw * pw
    y0, x0 = (h - ch) // 2 // ph * ph, (w - cw) // 2 // pw * pw
    return replace(raw, data=raw.data[y0 : y0 + ch, x0 : x0 + cw])


def estimate(raw: RawImage) -> NoiseModel:
    """A fit of the raw's own flattest blocks (``rawsim calibrate``'s patch method)."""
    from rawsim.cameras.calibrate import CalibrationRefused, calibrate_iso, frame_stats

    if raw.cfa is None:
        raise ParameterError(f"{raw.path}: no CFA mosaic, so no noise to estimate on it")
    stats = frame_stats(_central(raw), "patches")
    try:
        fit = calibrate_iso(raw.iso or 1.0, [stats], [], "patches")
    except CalibrationRefused as err:
        fit, problems = None, list(err.problems)
    else:
        problems = list(fit.problems)
    if fit is not None and math.isfinite(fit.K) and fit.K > 0 and math.isfinite(fit.read_sigma):
        b = max(fit.read_sigma, 0.0) ** 2 + 1 / 12
        warnings = (f"the estimated noise model is unsure: {problems[0]}",) if problems else ()
        detail = (
            f"fit to the raw's flattest blocks: K {fit.K:.4g} DN/e-, read σ {fit.read_sigma:.4g} DN"
        )
        return NoiseModel((fit.K,) * 3, (b,) * 3, "estimate", detail, warnings)
    from rawsim.cameras.calibrate import pure_noise_quantile

    valid = stats.valid
    var = np.asarray(stats.var, dtype=np.float64)[valid]
    if var.size == 0:
        raise ParameterError(
            f"{raw.path}: no unclipped flat blocks to estimate the noise from; give "
            "--noise-profile (a bundled profile or 'rawsim calibrate' output)"
        )
    b = float(np.quantile(var, 0.05) / pure_noise_quantile())
    why = problems[0] if problems else "no signal-dependent noise found"
    return NoiseModel(
        (0.0,) * 3,
        (b,) * 3,
        "estimate",
        f"read noise alone, from the raw's flattest blocks: σ {math.sqrt(b):.4g} DN",
        (f"the noise estimate found no shot noise ({why}); a signal-independent model is used",),
    )
