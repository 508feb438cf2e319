"""Sensor profiles: JSON descriptions of real cameras, loaded into frozen, validated objects.

A profile is found by name in the bundled ``sensor_profiles/`` folder or read
from a path. Two formats are accepted: rawsim's own (see README, "Sensor
profiles") and the seed's flat config keys (``bayer_pattern``, ``bit``,
``color_matrix_d50``, …). Every error names the file and the key.

Loading needs no torch (NumPy only), so the command line lists, shows and checks
profiles at once.
"""

from __future__ import annotations

import difflib
import json
import math
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from rawsim import cameras
from rawsim.cameras import spectra
from rawsim.cfa import CFA
from rawsim.color import (
    as_matrix,
    camera_from_srgb,
    daylight_gains,
    split_seed_matrix,
    xyz_to_camera_from_ccm,
)
from rawsim.errors import ParameterError, ProfileError
from rawsim.noise.dark_shading import read_black_level_error, read_spec
from rawsim.noise.spec import (
    DEFAULT_SPREAD,
    GainCurve,
    LambdaCurve,
    NoiseLevels,
    NoiseSpec,
    SeedGaussian,
    SigmaCurve,
)

#: Keys of rawsim's format whose numbers must cite a source.
SOURCED_KEYS = (
    "xyz_to_camera",
    "black_level",
    "white_level",
    "iso_range",
    "noise.gain",
    "noise.read_sigma",
)
#: Physics-model keys: all or none; each cites a source when present.
PHYSICS_KEYS = ("noise.tukey_sigma", "noise.tukey_lambda", "noise.row_sigma")
#: The physics model's optional dark terms (:mod:`rawsim.noise.dark_shading`).
DARK_KEYS = ("noise.dark_shading", "noise.black_level_error")
#: Optional noise keys that cite a source when present.
OPTIONAL_SOURCED_KEYS = (*PHYSICS_KEYS, "noise.channel_bias", "noise.spread", *DARK_KEYS)
#: How a profile's noise was obtained (its optional ``noise_kind`` key).
NOISE_KINDS = ("measured", "estimated")
#: How a source begins that marks a value as assumed, not taken from a table or a file.
ASSUMED = "assumed"
#: How ``source.xyz_to_camera`` begins where the matrix only stands in for a missing one
#: (``rawsim calibrate`` on files without one; a seed config without ``color_matrix_d50``).
NO_MATRIX = "none:"
SEED_KEYS = (
    "sensor_size",
    "sensor_res",
    "bit",
    "black_level",
    "bayer_pattern",
    "white_balance_d50",
    "color_matrix_d50",
    "gamma_param",
    "iso_base",
    "read_noise_std",
    "shot_noise_std_alpha",
    "shot_noise_std_beta",
    "wavelengths",
    "red_spectral_response",
    "green_spectral_response",
    "blue_spectral_response",
)


@dataclass(frozen=True)
class SensorProfile:
    """A camera sensor: CFA, levels (DN), colour, ISO range and noise.

    ``cfa`` is any periodic R/G/B layout: a 2×2 Bayer pattern, X-Trans (6×6) or
    rows such as ``"GRG/BGB/GRG"`` (the ``cfa_pattern`` key takes the same
    strings as :class:`~rawsim.cfa.CFA`). ``xyz_to_camera`` is the D65 XYZ → camera
    matrix (DNG ColorMatrix); ``white_balance`` the daylight gains (R, G, B) with
    G = 1; ``ccm_bias`` the bias row of a seed 4×3 colour matrix (camera → sRGB), if any.
    """

    name: str
    make: str
    model: str
    cfa: CFA
    bit_depth: int
    black_level: float
    white_level: float
    xyz_to_camera: tuple[tuple[float, float, float], ...]
    white_balance: tuple[float, float, float]
    iso_range: tuple[float, float] | None
    noise: NoiseSpec
    gamma: float = 2.2
    ccm_bias: tuple[float, float, float] | None = None
    size_mm: tuple[float, float] | None = None
    resolution: tuple[int, int] | None = None
    spectral: dict | None = None
    source: dict = field(default_factory=dict)
    path: str | None = None
    #: Why the profile is not to be trusted (``rawsim calibrate --force``); empty if it is.
    unreliable: tuple[str, ...] = ()
    #: ``measured`` (a calibration), ``estimated`` (the sensor's physics), or None (unstated).
    noise_kind: str | None = None

    def with_cfa(self, cfa: CFA | str) -> SensorProfile:
        """This profile with another CFA layout (e.g. ``"XTRANS"`` for a Bayer profile):
        levels, colour and noise stay; ``source["cfa_pattern"]`` records the change.
        A string that is no valid layout raises :class:`ParameterError`."""
        cfa = cfa if isinstance(cfa, CFA) else CFA(cfa)
        if cfa == self.cfa:
            return self
        note = f"set to {cfa.name} by the user; the profile's own layout is {self.cfa.name}"
        return replace(self, cfa=cfa, source={**self.source, "cfa_pattern": note})

    @property
    def curves(self) -> spectra.Curves | None:
        """The camera's spectral sensitivities (:mod:`rawsim.cameras.spectra`): measured
        where they are published, else estimated from its database matrix (``kind``
        says which); None where it has neither."""
        return spectra.of_profile(self)

    @property
    def assumed(self) -> tuple[str, ...]:
        """The keys whose value is assumed (their source begins "assumed"), not taken
        from a table, a file or a measurement."""
        return tuple(k for k, v in self.source.items() if str(v).casefold().startswith(ASSUMED))

    @property
    def colour_warning(self) -> str | None:
        """One line saying that the profile has no colour matrix and how to give it one;
        None where it has one. It has none where its source says so (:data:`NO_MATRIX`),
        where its XYZ → camera matrix is diagonal (camera RGB taken as XYZ: the identity
        ``rawsim calibrate`` writes for files without a matrix) and where it takes camera
        RGB as linear sRGB (a seed config without ``color_matrix_d50``, a profile of a
        camera no matrix is published for)."""
        m = np.asarray(self.xyz_to_camera, dtype=np.float64)
        said = str(self.source.get("xyz_to_camera", "")).startswith(NO_MATRIX)
        if said or np.allclose(m - np.diag(np.diag(m)), 0, atol=1e-6):
            what = "its XYZ→camera matrix is the identity, a stand-in"
        elif np.allclose(camera_from_srgb(m), np.eye(3), atol=1e-3):
            what = "it takes camera RGB as linear sRGB"
        else:
            return None
        return (
            f"profile {self.name!r} has no colour matrix ({what}), so the raws it makes do "
            "not have a real camera's colours; give it one with 'rawsim profiles from-raw' "
            "on a raw of the camera, or copy xyz_to_camera from a similar camera "
            "('rawsim profiles show NAME --json')"
        )

    def check_iso(self, iso: float) -> float:
        """Return ``iso`` if the profile allows it, else raise a clear error."""
        span = "" if self.iso_range is None else "{:g}–{:g}".format(*self.iso_range)
        if not iso > 0:
            within = f" (profile {self.name!r} takes {span})" if span else ""
            raise ParameterError(f"ISO must be > 0, got {iso:g}: give a positive ISO{within}")
        if self.iso_range is not None and not self.iso_range[0] <= iso <= self.iso_range[1]:
            raise ParameterError(
                f"ISO {iso:g} is outside the range of profile {self.name!r} ({span}): "
                "give an ISO within it, or another profile"
            )
        return iso

    def noise_levels(self, iso: float, model: str = "poisson-gaussian") -> NoiseLevels:
        """The noise parameters of ``model`` at ``iso``; the ISO must lie in the range."""
        return self.noise.levels(model, self.check_iso(iso))

    def to_dict(self) -> dict:
        """A JSON-ready summary (rawsim's format)."""
        return {
            "name": self.name,
            "make": self.make,
            "model": self.model,
            "cfa_pattern": self.cfa.pattern,
            "bit_depth": self.bit_depth,
            "black_level": self.black_level,
            "white_level": self.white_level,
            "xyz_to_camera": [list(r) for r in self.xyz_to_camera],
            "white_balance": list(self.white_balance),
            "iso_range": None if self.iso_range is None else list(self.iso_range),
            "noise": _noise_dict(self.noise),
            "gamma": self.gamma,
            "ccm_bias": None if self.ccm_bias is None else list(self.ccm_bias),
            "sensor_size_mm": self.size_mm,
            "resolution": self.resolution,
            "source": dict(self.source),
            "path": self.path,
            "unreliable": list(self.unreliable),
            "noise_kind": self.noise_kind,
            "spectral_sensitivities": None
            if (c := self.curves) is None
            else {"camera": c.label, "kind": c.kind, "source": c.source},
        }


def _noise_dict(noise: NoiseSpec) -> dict:
    out = {
        "gain": _curve_dict(noise.gain),
        "read_sigma": _curve_dict(noise.read_sigma),
        "gaussian": vars(noise.gaussian).copy(),
    }
    if noise.has_physics:
        out["tukey_sigma"] = _curve_dict(noise.tukey_sigma)
        out["tukey_lambda"] = {
            "k": list(noise.tukey_lambda.k),
            "lambda": list(noise.tukey_lambda.lam),
        }
        out["row_sigma"] = _curve_dict(noise.row_sigma)
    out["channel_bias"] = list(noise.channel_bias)
    out["spread"] = noise.spread
    if noise.dark_shading is not None:
        out["dark_shading"] = noise.dark_shading.to_dict()
    if noise.black_level_error is not None:
        ble = noise.black_level_error
        out["black_level_error"] = {"iso": list(ble.iso), "sigma": list(ble.sigma)}
    return out


def _curve_dict(curve) -> dict:
    return {
        k: (list(v) if isinstance(v, tuple) else v)
        for k, v in vars(curve).items()
        if v not in ((), None)
    }


def profile_dir() -> Path:
    """The folder of bundled profiles."""
    return Path(str(resources.files("rawsim.cameras") / "sensor_profiles"))


def list_profiles() -> list[str]:
    """Names of the bundled profiles, sorted."""
    return sorted(p.stem for p in profile_dir().glob("*.json"))


def load_profile(name_or_path: str | Path) -> SensorProfile:
    """Load a profile: a bundled one by name (``"sony_a7s2"``), a profile JSON by path, or
    any camera of :mod:`rawsim.cameras` by its name (``"Sony ILCE-7M3"``, ``"sony a7 iii"``)."""
    text = str(name_or_path)
    path = Path(text)
    if not (path.suffix == ".json" or path.exists()):
        folded = {n.casefold(): n for n in list_profiles()}
        bundled = folded.get(text.casefold())
        if bundled is None and ("/" not in text or cameras.find(text)):  # "HS10/HS11"
            return _from_database(text)
        path = profile_dir() / f"{bundled}.json" if bundled else path
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ProfileError(
            f"{path}: profile file not found (check the path, or give a camera's name: "
            "'rawsim profiles list --search TEXT')"
        ) from None
    except IsADirectoryError:
        raise ProfileError(f"{path} is a folder: give a profile's JSON file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ProfileError(f"{path}: cannot read profile ({err})") from None
    except json.JSONDecodeError as err:
        raise ProfileError(f"{path}: not valid JSON (line {err.lineno}: {err.msg})") from None
    profile = profile_from_dict(data, str(path))
    if path.parent == profile_dir() and profile.noise_kind is None:
        kind = cameras.bundled_noise(path.stem)
        if kind:
            source = {**profile.source, "noise_kind": kind["noise_source"]}
            profile = replace(profile, noise_kind=kind["noise_kind"], source=source)
    return profile


def _from_database(name: str) -> SensorProfile:
    """The camera database's profile for ``name``; the bundled one where it holds the camera."""
    cam = cameras.find(name)
    if cam is None:
        names = list_profiles()
        close = [n for n in difflib.get_close_matches(name.casefold(), names, n=2, cutoff=0.6)]
        close += cameras.closest(name)
        hint = f"did you mean {close[0]}? " if close else ""
        if len(close) > 1:
            hint += f"(also close: {', '.join(close[1:5])}); "
        raise ProfileError(
            f"unknown sensor profile {name!r} (no bundled profile or camera of that name): {hint}"
            f"bundled: {', '.join(names)}; find any camera with "
            "'rawsim profiles list --search TEXT', or give a path to a profile JSON file"
        )
    if cam.bundled:
        return load_profile(cam.bundled)
    return profile_from_dict(cam.profile_data(), f"<camera database: {cam.label}>")


def profile_from_dict(data: Any, origin: str = "<profile>") -> SensorProfile:
    """Validate a parsed profile (either format) into a :class:`SensorProfile`."""
    r = _Reader(data, origin)
    if not isinstance(data, dict):
        raise ProfileError(f"{origin}: a profile must be a JSON object")
    if "bayer_pattern" in data or "bit" in data:
        return _from_seed(r)
    return _from_rawsim(r)


class _Reader:
    """Typed access to a profile's keys; every error names the file and the key path."""

    def __init__(self, data: Any, origin: str) -> None:
        self.data, self.origin = data, origin

    def fail(self, key: str, why: str):
        raise ProfileError(f"{self.origin}: key {key!r}: {why}")

    def has(self, key: str) -> bool:
        try:
            self.raw(key)
        except ProfileError:
            return False
        return True

    def raw(self, key: str, default: Any = ...) -> Any:
        node = self.data
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                if default is not ...:
                    return default
                self.fail(key, "missing")
            node = node[part]
        return node

    def number(self, key: str, default: Any = ..., positive=False, minimum=None) -> float:
        value = self.raw(key, default)
        if value is None and default is None:
            return None
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
        ):
            self.fail(key, f"expected a finite number, got {value!r}")
        if positive and not value > 0:
            self.fail(key, f"must be > 0, got {value!r}")
        if minimum is not None and value < minimum:
            self.fail(key, f"must be ≥ {minimum}, got {value!r}")
        return float(value)

    def numbers(self, key: str, length: int | None = None, default: Any = ..., positive=False):
        value = self.raw(key, default)
        if value is None and default is None:
            return None
        if isinstance(value, tuple):  # a default
            value = list(value)
        if not isinstance(value, list) or (length is not None and len(value) != length):
            want = f"a list of {length} numbers" if length else "a list of numbers"
            self.fail(key, f"expected {want}, got {value!r}")
        out = []
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                self.fail(f"{key}[{i}]", f"expected a finite number, got {v!r}")
            if positive and not v > 0:
                self.fail(f"{key}[{i}]", f"must be > 0, got {v!r}")
            out.append(float(v))
        return tuple(out)

    def matrix(self, key: str, rows: int) -> tuple:
        value = self.raw(key)
        if not isinstance(value, list) or len(value) != rows:
            self.fail(key, f"expected {rows} rows of 3 numbers, got {value!r}")
        return tuple(_row(self, key, i, row) for i, row in enumerate(value))

    def string(self, key: str, default: Any = ...) -> str:
        value = self.raw(key, default)
        if not isinstance(value, str) or not value:
            self.fail(key, f"expected a non-empty string, got {value!r}")
        return value

    def cfa(self, key: str) -> CFA:
        """A Bayer name, ``XTRANS``, or any periodic R/G/B layout as rows (see :class:`CFA`)."""
        try:
            return CFA(self.string(key))
        except ParameterError as err:
            self.fail(key, str(err))

    def curve(self, key: str, kind: str):
        model = self.string(f"{key}.model")
        if kind == "gain":
            if model == "linear":
                return GainCurve(
                    "linear",
                    slope=self.number(f"{key}.slope", positive=True),
                    intercept=self.number(f"{key}.intercept", 0.0),
                )
            if model == "table":
                iso, k = self._table(key, "k")
                if any(b <= a for a, b in zip(k, k[1:], strict=False)):
                    self.fail(f"{key}.k", f"K must increase with ISO, got {list(k)}")
                return GainCurve("table", iso=iso, k=k)
            self.fail(f"{key}.model", f"unknown gain model {model!r}; valid: linear, table")
        if model == "loglinear":
            return SigmaCurve(
                "loglinear", slope=self.number(f"{key}.slope"), bias=self.number(f"{key}.bias")
            )
        if model == "table":
            iso, sigma = self._table(key, "sigma")
            return SigmaCurve("table", iso=iso, sigma=sigma)
        self.fail(f"{key}.model", f"unknown sigma model {model!r}; valid: loglinear, table")

    def lambda_curve(self, key: str) -> LambdaCurve:
        k = self.numbers(f"{key}.k", positive=True)
        lam = self.numbers(f"{key}.lambda", len(k))
        if not k or any(b <= a for a, b in zip(k, k[1:], strict=False)):
            self.fail(f"{key}.k", "must be a non-empty, strictly increasing list of gains")
        # λ > −½ keeps the variance finite; λ > 1 (a bounded, flat-topped law) is what
        # PMN measures on the IMX686's 10-bit dark frames at ISO 100.
        if any(not v > -0.5 for v in lam):
            self.fail(f"{key}.lambda", f"each λ must be > −0.5 (finite variance), got {list(lam)}")
        return LambdaCurve(k, lam)

    def _table(self, key: str, values: str):
        iso = self.numbers(f"{key}.iso", positive=True)
        vals = self.numbers(f"{key}.{values}", len(iso), positive=True)
        if not iso or any(b <= a for a, b in zip(iso, iso[1:], strict=False)):
            self.fail(f"{key}.iso", "must be a non-empty, strictly increasing list")
        return iso, vals


def _row(r: _Reader, key: str, i: int, row: Any) -> tuple:
    if not isinstance(row, list) or len(row) != 3:
        r.fail(f"{key}[{i}]", f"expected 3 numbers, got {row!r}")
    for v in row:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            r.fail(f"{key}[{i}]", f"expected finite numbers, got {row!r}")
    return tuple(float(v) for v in row)


def _levels(r: _Reader, bits_key: str, black_key: str, white_key: str | None):
    bits = r.number(bits_key)
    if bits != int(bits) or not 1 <= bits <= 16:
        r.fail(bits_key, f"must be an integer in 1..16, got {bits:g}")
    bits = int(bits)
    top = (1 << bits) - 1  # the largest code (rawsim.isp.levels.white_level_for_bits)
    black = r.number(black_key, minimum=0)
    white = r.number(white_key, top) if white_key else float(top)
    if white > top:
        r.fail(white_key, f"{white:g} does not fit in {bits} bits")
    if not white > black:
        r.fail(white_key or black_key, f"white level {white:g} must exceed black level {black:g}")
    return bits, black, white


def _gains(r: _Reader, key: str, xyz_to_camera) -> tuple[float, float, float]:
    if r.has(key):
        return r.numbers(key, 3, positive=True)
    try:
        return tuple(float(v) for v in daylight_gains(xyz_to_camera))
    except ParameterError as err:
        r.fail("xyz_to_camera", str(err))


def _check_invertible(r: _Reader, key: str, m) -> None:
    try:
        if abs(float(np.linalg.det(as_matrix(m, key)))) < 1e-9:
            r.fail(key, "matrix is singular")
    except ParameterError as err:
        r.fail(key, str(err))


def _from_rawsim(r: _Reader) -> SensorProfile:
    name = r.string("name")
    bits, black, white = _levels(r, "bit_depth", "black_level", "white_level")
    xyz = r.matrix("xyz_to_camera", 3)
    _check_invertible(r, "xyz_to_camera", xyz)
    iso_range = r.numbers("iso_range", 2, positive=True)
    if iso_range[1] < iso_range[0]:
        r.fail("iso_range", f"minimum {iso_range[0]:g} exceeds maximum {iso_range[1]:g}")
    gain = r.curve("noise.gain", "gain")
    read = r.curve("noise.read_sigma", "sigma")
    base = r.number("base_iso", iso_range[0], positive=True)
    try:
        for iso in iso_range:
            gain(iso)
        k_base = gain(base)
    except ParameterError as err:
        r.fail("noise.gain", str(err))
    if r.has("noise.gaussian"):
        gaussian = SeedGaussian(
            iso_base=r.number("noise.gaussian.iso_base", positive=True),
            read_noise_std=r.number("noise.gaussian.read_noise_std", minimum=0),
            shot_noise_std_alpha=r.number("noise.gaussian.shot_noise_std_alpha", minimum=0),
            shot_noise_std_beta=r.number("noise.gaussian.shot_noise_std_beta", 0.0, minimum=0),
        )
    else:  # the seed model matching K and read σ at the base ISO
        gaussian = SeedGaussian(base, read(base, k_base), math.sqrt(k_base), 0.0)
    physics = {key: r.has(key) for key in PHYSICS_KEYS}
    if any(physics.values()) and not all(physics.values()):
        missing = [k for k, v in physics.items() if not v]
        r.fail(missing[0], "the physics model needs all of " + ", ".join(PHYSICS_KEYS))
    spec = NoiseSpec(
        gain,
        read,
        gaussian,
        tukey_sigma=r.curve("noise.tukey_sigma", "sigma") if physics[PHYSICS_KEYS[0]] else None,
        tukey_lambda=r.lambda_curve("noise.tukey_lambda") if physics[PHYSICS_KEYS[1]] else None,
        row_sigma=r.curve("noise.row_sigma", "sigma") if physics[PHYSICS_KEYS[2]] else None,
        channel_bias=r.numbers("noise.channel_bias", 4, (0.0, 0.0, 0.0, 0.0)),
        spread=r.number("noise.spread", DEFAULT_SPREAD, minimum=0),
        dark_shading=_optional(r, DARK_KEYS[0], read_spec),
        black_level_error=_optional(r, DARK_KEYS[1], read_black_level_error),
    )
    if not spec.has_physics and (spec.dark_shading or spec.black_level_error):
        r.fail(DARK_KEYS[0], "dark shading and black-level error need the physics model's keys")
    source = r.raw("source")
    if not isinstance(source, dict):
        r.fail("source", "expected an object mapping keys to their sources")
    sourced = SOURCED_KEYS + tuple(k for k in OPTIONAL_SOURCED_KEYS if r.has(k))
    for key in sourced:
        if not isinstance(source.get(key), str) or not source[key].strip():
            r.fail(f"source.{key}", "missing: every number needs a source")
    return SensorProfile(
        name=name,
        make=r.string("make"),
        model=r.string("model"),
        cfa=r.cfa("cfa_pattern"),
        bit_depth=bits,
        black_level=black,
        white_level=white,
        xyz_to_camera=xyz,
        white_balance=_gains(r, "white_balance", xyz),
        iso_range=(iso_range[0], iso_range[1]),
        noise=spec,
        gamma=r.number("gamma", 2.2, positive=True),
        size_mm=r.numbers("sensor_size_mm", 2, None, positive=True),
        resolution=r.numbers("resolution", 2, None, positive=True),
        source=dict(source),
        path=None if r.origin.startswith("<") else r.origin,
        unreliable=_strings(r, "unreliable"),
        noise_kind=_noise_kind(r),
    )


def _optional(r: _Reader, key: str, read):
    """An optional key read by ``read(value, key, origin)``, None when absent."""
    return read(r.raw(key), key, r.origin) if r.has(key) else None


def _noise_kind(r: _Reader) -> str | None:
    value = r.raw("noise_kind", None)
    if value not in (None, *NOISE_KINDS):
        r.fail("noise_kind", f"expected one of {', '.join(NOISE_KINDS)}, got {value!r}")
    return value


def _strings(r: _Reader, key: str) -> tuple[str, ...]:
    """An optional list of strings (empty when absent)."""
    value = r.raw(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        r.fail(key, f"expected a list of strings, got {value!r}")
    return tuple(value)


def _from_seed(r: _Reader) -> SensorProfile:
    """The seed's flat config keys (SPEC, RGBSensor); defaults are the seed's."""
    data = r.data
    unknown = sorted(set(data) - set(SEED_KEYS) - {"name", "make", "model", "iso_range"})
    if unknown:
        r.fail(unknown[0], f"unknown key; valid: {', '.join(SEED_KEYS)}")
    data = {"bit": 10, "black_level": 64, "bayer_pattern": "rggb", **data}
    r = _Reader(data, r.origin)
    bits, black, white = _levels(r, "bit", "black_level", None)
    ccm = data.get("color_matrix_d50", [[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    try:
        matrix, bias = split_seed_matrix(ccm)
        xyz = tuple(tuple(float(v) for v in row) for row in xyz_to_camera_from_ccm(matrix))
    except ParameterError as err:
        r.fail("color_matrix_d50", str(err))
    gaussian = SeedGaussian(
        iso_base=r.number("iso_base", 100.0, positive=True),
        read_noise_std=r.number("read_noise_std", 0.5, minimum=0),
        shot_noise_std_alpha=r.number("shot_noise_std_alpha", 0.4, minimum=0),
        shot_noise_std_beta=r.number("shot_noise_std_beta", 0.0, minimum=0),
    )
    spectral = None
    if "wavelengths" in data:
        wl = r.numbers("wavelengths", positive=True)
        spectral = {"wavelengths": wl}
        for c in ("red", "green", "blue"):
            spectral[c] = r.numbers(f"{c}_spectral_response", len(wl))
    iso_range = r.numbers("iso_range", 2, None, positive=True)
    size = r.numbers("sensor_size", 2, (36.0, 24.0), positive=True)
    res = r.numbers("sensor_res", 2, (5472, 3648), positive=True)
    return SensorProfile(
        name=str(data.get("name", Path(r.origin).stem)),
        make=str(data.get("make", "rawsim")),
        model=str(data.get("model", "seed sensor")),
        cfa=r.cfa("bayer_pattern"),
        bit_depth=bits,
        black_level=black,
        white_level=white,
        xyz_to_camera=xyz,
        white_balance=r.numbers("white_balance_d50", 3, (2.0, 1.0, 1.8), positive=True),
        iso_range=iso_range,
        noise=NoiseSpec.from_seed(gaussian),
        gamma=r.number("gamma_param", 2.2, positive=True),
        ccm_bias=None if bias is None else tuple(float(v) for v in bias),
        size_mm=size,
        resolution=tuple(int(v) for v in res),
        spectral=spectral,
        source={"*": "seed config"},
        path=None if r.origin.startswith("<") else r.origin,
    )
