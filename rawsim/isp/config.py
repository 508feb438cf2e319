"""The ISP's configuration: its stages, their parameters, validation and TOML.

A config is a list of tables, one per stage, in processing order::

    [[stage]]
    name = "white_balance"
    mode = "camera"

Every stage takes ``enabled`` (bool) besides its own keys; :func:`default_config`
lists them all with their defaults, and ``rawsim isp show`` prints it as TOML.
:func:`validate_config` rejects unknown stages and keys, bad values and orders
that cannot work (listing what is valid). :func:`white_balance` and
:func:`camera_to_output` give a stage's values for a particular raw.

No torch here: the compiled engine and ``rawsim process`` start without it. The
stages themselves are in :mod:`rawsim.isp.pipeline` (torch reference) and
:mod:`rawsim.engine.process` (compiled).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rawsim.color import SRGB_TO_XYZ, srgb_from_camera
from rawsim.errors import ParameterError
from rawsim.isp.curves import TransferSpec

DEMOSAIC_METHODS = ("wcd", "menon", "malvar", "bilinear")
HIGHLIGHT_MODES = ("clip", "blend")
TONE_CURVES = ("none", "smoothstep", "reinhard", "aces", "hable")
ANTI_ALIAS_METHODS = ("none", "weighted_average", "gaussian")
DENOISE_METHODS = ("none", "gaussian", "bilateral")
#: dcraw's lightness/chroma transform of the highlight blend (rows: L, C1, C2).
HIGHLIGHT_TRANSFORM = ((1.0, 1.0, 1.0), (1.7320508, -1.7320508, 0.0), (-1.0, -1.0, 2.0))
#: EXIF/TIFF orientation → (transpose first, flip rows, flip columns) of (…, H, W).
ORIENTATION_OPS = {
    1: (False, False, False),
    2: (False, False, True),
    3: (False, True, True),
    4: (False, True, False),
    5: (True, False, False),
    6: (True, False, True),
    7: (True, True, True),
    8: (True, True, False),
}

OUTPUT_SPACES = ("srgb", "xyz", "camera")
WB_MODES = ("camera", "daylight", "auto", "R,G,B")


def _choice(valid):
    def check(value):
        if value not in valid:
            raise ParameterError(f"{value!r}; valid: {', '.join(map(str, valid))}")
        return value

    return check


def _number(lo=-math.inf, hi=math.inf, integer=False):
    def check(value):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f"expected a number, got {value!r}")
        if not lo <= value <= hi or (integer and value != int(value)):
            kind = "an integer" if integer else "a number"
            raise ParameterError(f"expected {kind} in [{lo:g}, {hi:g}], got {value!r}")
        return int(value) if integer else float(value)

    return check


def _auto_or(check, what: str = "a number"):
    """``check``, or "auto"; numbers may come as text (the CLI's flags). ``what`` names
    the numbers in the error for other text."""

    def auto_or(value):
        if value == "auto":
            return value
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise ParameterError(f"expected {what} or auto, got {value!r}") from None
        return check(value)

    return auto_or


def tone_params(stage: dict) -> tuple[str, float, float | None]:
    """(curve, exposure, white or None for the curve's own) of a ``tone`` stage."""
    white = None if stage["white"] == "auto" else stage["white"]
    return stage["curve"], stage["exposure"], white


def _flag(value):
    if not isinstance(value, bool):
        raise ParameterError(f"expected true or false, got {value!r}")
    return value


def _wb_mode(value):
    if value in ("camera", "daylight", "auto"):
        return value
    gains = parse_gains(value)
    return ",".join(f"{g:g}" for g in gains)


def parse_gains(value) -> tuple[float, float, float]:
    """Parse ``"R,G,B"`` (or a list) into three positive gains."""
    parts = value.split(",") if isinstance(value, str) else value
    try:
        gains = tuple(float(p) for p in parts)
    except (TypeError, ValueError):
        gains = ()
    if len(gains) != 3 or not all(g > 0 and math.isfinite(g) for g in gains):
        raise ParameterError(f"{value!r}; valid: camera, daylight, auto or R,G,B gains > 0")
    return gains


def _transfer(value):
    return str(TransferSpec.parse(value))


def _shading_k(value):
    if not isinstance(value, list) or len(value) != 3:
        raise ParameterError(f"expected a list of 3 numbers, got {value!r}")
    return [_number()(v) for v in value]


@dataclass(frozen=True)
class Param:
    default: Any
    check: Callable[[Any], Any]
    help: str


#: Stage name → its parameters, in the default processing order.
STAGES: dict[str, dict[str, Param]] = {
    "black_level": {
        "white_level": Param(
            "file", _choice(("file", "auto")), "file, or auto (LibRaw's adjust_maximum_thr=0.75)"
        ),
    },
    "dead_pixel": {
        "threshold": Param(0.1, _number(1e-6), "deviation from the neighbours' mean (white = 1)"),
        "kernel": Param(3, _choice((3, 5)), "neighbourhood size within the colour plane"),
        "temperature": Param(0.01, _number(1e-6), "width of the soft decision"),
    },
    "lens_shading": {
        "k": Param([0.3, 0.15, 0.05], _shading_k, "V(r) = 1 + k1 r² + k2 r⁴ + k3 r⁶"),
        "strength": Param(1.0, _number(0), "0 = off, 1 = the full model"),
    },
    "anti_aliasing": {
        "method": Param("weighted_average", _choice(ANTI_ALIAS_METHODS[1:]), "blur kernel"),
        "sigma": Param(0.5, _number(1e-3), "Gaussian σ in plane pixels"),
    },
    "white_balance": {
        "mode": Param("camera", _wb_mode, "camera, daylight, auto (LibRaw's grey world) or R,G,B"),
    },
    "highlights": {
        "mode": Param("clip", _choice(HIGHLIGHT_MODES), "clip, or blend (after demosaic)"),
    },
    "demosaic": {
        "method": Param("wcd", _choice(DEMOSAIC_METHODS), "interpolation method"),
    },
    "denoise": {
        "method": Param("bilateral", _choice(DENOISE_METHODS[1:]), "filter"),
        "kernel": Param(5, _number(3, 15, integer=True), "window size (odd)"),
        "sigma": Param(1.0, _number(1e-3), "spatial σ (pixels)"),
        "sigma_color": Param(0.05, _number(1e-6), "range σ (linear units)"),
    },
    "color_matrix": {
        "output_space": Param(
            "srgb", _choice(OUTPUT_SPACES), "linear sRGB primaries, XYZ, or camera RGB"
        ),
    },
    "exposure": {
        "ev": Param(
            0.0,
            _auto_or(_number(-20, 20), "stops in [-20, 20]"),
            "stops (0 maps the white level to 1), or auto: the 99th percentile to 1 (LibRaw's "
            "auto-brightness)",
        ),
        "baseline": Param(
            "apply",
            _choice(("apply", "ignore")),
            "the DNG's BaselineExposure: apply (as Adobe's DNG SDK) or ignore (as LibRaw)",
        ),
    },
    "tone": {
        "curve": Param("none", _choice(TONE_CURVES), "tone curve"),
        "exposure": Param(
            0.0, _number(0, 4), "filmic curves: stops of gain before the curve (1 reached at 2^-ev)"
        ),
        "white": Param(
            "auto",
            _auto_or(_number(0.25, 12)),
            "filmic curves: white point in the curve's units (auto: reinhard 4, aces 7.24, "
            "hable 11.2); larger compresses highlights more",
        ),
    },
    "transfer": {"function": Param("srgb", _transfer, "srgb, gamma:G or linear")},
    "ycbcr": {},
    "orientation": {},
}
_DISABLED_BY_DEFAULT = {"dead_pixel", "lens_shading", "anti_aliasing", "denoise", "ycbcr"}
MOSAIC_ONLY = {"dead_pixel", "anti_aliasing", "demosaic"}
RGB_ONLY = {"color_matrix", "ycbcr", "orientation"}
#: Stages that need colour channels: skipped for monochrome data.
COLOUR_ONLY = {"white_balance", "highlights", "color_matrix", "ycbcr"}


def default_config() -> list[dict]:
    """Every stage with its defaults, in the default order."""
    return [
        {
            "name": name,
            "enabled": name not in _DISABLED_BY_DEFAULT,
            **{k: p.default for k, p in params.items()},
        }
        for name, params in STAGES.items()
    ]


def validate_config(config: Any, origin: str = "config") -> list[dict]:
    """Check a config (list of stage tables); fill defaults. Errors say what is valid."""
    if not isinstance(config, list) or not all(isinstance(s, dict) for s in config):
        raise ParameterError(f"{origin}: expected a list of [[stage]] tables")
    out, seen = [], set()
    for i, stage in enumerate(config):
        name = stage.get("name")
        where = f"{origin}: stage {i + 1}"
        if name not in STAGES:
            raise ParameterError(f"{where}: unknown stage {name!r}; valid: {', '.join(STAGES)}")
        if name in seen:
            raise ParameterError(f"{where}: stage {name!r} appears twice")
        seen.add(name)
        params = STAGES[name]
        unknown = sorted(set(stage) - set(params) - {"name", "enabled"})
        if unknown:
            valid = ", ".join(["enabled", *params]) or "enabled"
            raise ParameterError(f"{where} ({name}): unknown key {unknown[0]!r}; valid: {valid}")
        entry = {"name": name, "enabled": True}
        try:
            entry["enabled"] = _flag(stage.get("enabled", True))
        except ParameterError as err:
            raise ParameterError(f"{where} ({name}).enabled: {err}") from None
        for key, p in params.items():
            try:
                entry[key] = p.check(stage.get(key, p.default))
            except ParameterError as err:
                raise ParameterError(f"{where} ({name}).{key}: {err}") from None
        shapes_tone = name == "tone" and (entry["exposure"] != 0 or entry["white"] != "auto")
        if shapes_tone and entry["curve"] in ("none", "smoothstep"):
            raise ParameterError(
                f"{where} (tone): exposure and white shape the filmic curves (reinhard, aces, "
                f"hable), not {entry['curve']!r}; choose one with --tone"
            )
        out.append(entry)
    _check_order(out, origin)
    return out


def _check_order(config: list[dict], origin: str) -> None:
    names = [s["name"] for s in config if s["enabled"]]
    for required in ("black_level", "demosaic"):
        if required not in names:
            raise ParameterError(f"{origin}: the ISP needs an enabled {required!r} stage")
    split = names.index("demosaic")
    late = [n for n in names[split:] if n in MOSAIC_ONLY - {"demosaic"}]
    early = [n for n in names[:split] if n in RGB_ONLY]
    if late or early:
        bad = (late or early)[0]
        where = "before" if late else "after"
        raise ParameterError(f"{origin}: stage {bad!r} must come {where} 'demosaic'")
    if names.index("black_level") > split:
        raise ParameterError(f"{origin}: 'black_level' must come before 'demosaic'")
    if "orientation" in names and names[-1] != "orientation":
        raise ParameterError(f"{origin}: 'orientation' must be the last enabled stage")
    for s in config:
        if s["name"] == "highlights" and s["enabled"] and s["mode"] == "blend":
            if names.index("highlights") < split:
                raise ParameterError(
                    f"{origin}: highlights mode 'blend' needs RGB: put it after 'demosaic'"
                )


def load_config(path) -> list[dict]:
    """Read and validate a TOML config file."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except (OSError, UnicodeDecodeError) as err:
        reason = getattr(err, "strerror", None) or str(err)
        raise ParameterError(f"{path}: cannot read config ({reason})") from None
    return load_config_text(text, str(path))


def config_to_toml(config: list[dict]) -> str:
    """TOML text for a config, with a comment per stage; :func:`load_config` reads it back."""
    lines = ["# rawsim ISP config: stages run in this order; set enabled = false to skip one."]
    for stage in config:
        params = STAGES[stage["name"]]
        lines += [
            "",
            "[[stage]]",
            f'name = "{stage["name"]}"',
            f"enabled = {str(stage['enabled']).lower()}",
        ]
        for key, p in params.items():
            lines.append(f"{key} = {_toml_value(stage[key])}  # {p.help}")
    return "\n".join(lines) + "\n"


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def override(config: list[dict], **changes) -> list[dict]:
    """Apply the CLI's flags (``wb``, ``white_level``, ``demosaic``, ``highlights``,
    ``tone``, ``exposure``, ``output_space``, ``transfer``); None leaves a value as it is.
    Re-validates."""
    keys = {
        "wb": ("white_balance", "mode"),
        "white_level": ("black_level", "white_level"),
        "baseline_exposure": ("exposure", "baseline"),
        "demosaic": ("demosaic", "method"),
        "highlights": ("highlights", "mode"),
        "tone": ("tone", "curve"),
        "tone_exposure": ("tone", "exposure"),
        "tone_white": ("tone", "white"),
        "exposure": ("exposure", "ev"),
        "output_space": ("color_matrix", "output_space"),
        "transfer": ("transfer", "function"),
    }
    out = [dict(s) for s in config]
    for flag, value in changes.items():
        if value is None:
            continue
        stage, key = keys[flag]
        try:  # in the user's terms: the flag and what they typed
            value = STAGES[stage][key].check(value)
        except ParameterError as err:
            why = str(err).removeprefix(f"{value!r}; ")  # the value is said once
            raise ParameterError(f"--{flag.replace('_', '-')} {value!r}: {why}") from None
        matches = [s for s in out if s["name"] == stage]
        if not matches:
            out.append({"name": stage})
            matches = out[-1:]
        matches[0][key] = value
        matches[0]["enabled"] = True
        if flag == "highlights" and value == "blend":
            # Blending needs RGB: move the stage to just after demosaic.
            out.remove(matches[0])
            at = next(i for i, s in enumerate(out) if s["name"] == "demosaic") + 1
            out.insert(at, matches[0])
    return validate_config(out, "options")


def load_config_text(text: str, origin: str = "config") -> list[dict]:
    """Validate TOML text (see :func:`load_config`)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ParameterError(f"{origin}: not valid TOML ({err})") from None
    unknown = sorted(set(data) - {"stage"})
    if unknown:
        raise ParameterError(f"{origin}: unknown top-level key {unknown[0]!r}; valid: stage")
    return validate_config(data.get("stage", []), origin)


def auto_white_balance(raw) -> tuple[float, float, float]:
    """LibRaw's automatic white balance (``use_auto_wb``), G = 1: grey world over 8 × 8
    blocks of the raw data, from the top-left corner (edge blocks partial), leaving
    out every block that holds a value within 25 DN of the white level; each
    colour's multiplier is its count of sites over its sum above black."""
    data = raw.data.astype(np.float64)
    h, w = data.shape[:2]
    rows, cols = np.arange(0, h, 8), np.arange(0, w, 8)

    def blocks(x: np.ndarray) -> np.ndarray:  # (H, W) → per-block sums (H/8, W/8)
        return np.add.reduceat(np.add.reduceat(x, rows, axis=0), cols, axis=1)

    if raw.cfa is None:  # 3-channel data: every channel of every pixel
        over = (data > raw.white_level - 25).any(axis=2)
        above = np.maximum(data - np.asarray(raw.black_level, np.float64)[:3], 0.0)
        planes = [(above[..., c], np.ones((h, w))) for c in range(3)]
    else:
        over = data > raw.white_level - 25
        black = np.tile(np.asarray(raw.black_level, np.float64), (h // 2, w // 2))
        above = np.maximum(data - black, 0.0)
        colors = np.tile(np.asarray(raw.cfa.colors).reshape(2, 2), (h // 2, w // 2))
        planes = [(above * (colors == c), (colors == c).astype(np.float64)) for c in range(3)]
    keep = blocks(over.astype(np.float64)) == 0
    mul = []
    for values, sites in planes:
        total = blocks(values)[keep].sum()
        mul.append(blocks(sites)[keep].sum() / total if total > 0 else 0.0)
    if min(mul) <= 0:
        return (1.0, 1.0, 1.0)  # no usable block (all saturated, or black)
    return (float(mul[0] / mul[1]), 1.0, float(mul[2] / mul[1]))


#: LibRaw's default ``adjust_maximum_thr``: a data maximum above this share of the white
#: level becomes the white level.
ADJUST_MAXIMUM = 0.75


#: ``ev = "auto"``: the share of pixels allowed to clip (LibRaw's ``auto_bright_thr``),
#: and the most it brightens (stops).
AUTO_CLIP = 0.01
AUTO_MAX_STOPS = 8.0


def exposure_stops(stage: dict, raw, info: dict) -> float:
    """Stops of an ``exposure`` stage for this raw, recorded in ``info``.

    A number: it, plus the file's DNG BaselineExposure unless ``baseline =
    "ignore"``. ``auto``: :func:`auto_exposure_stops` (the baseline is then moot).
    """
    if stage["ev"] == "auto":
        stops = auto_exposure_stops(raw, info)
    else:
        stops = stage["ev"] + (raw.baseline_exposure if stage["baseline"] == "apply" else 0.0)
    info["exposure_stops"] = stops
    return stops


def auto_exposure_stops(raw, info: dict) -> float:
    """Stops that bring the image's 99th percentile to 1, as LibRaw's auto-brightness.

    Measured on the half-resolution planes (R, mean of the greens, B) after
    levels, the white balance and clipping at 1 and the colour matrix already
    resolved in ``info`` (the stages before exposure); the brightest channel's
    percentile counts. Never darkens (at most 1 is the clip), at most
    ``AUTO_MAX_STOPS``.
    """
    data = np.asarray(raw.data, dtype=np.float32)
    black = np.asarray(raw.black_level, dtype=np.float32)
    span = float(info.get("white_level", raw.white_level)) - float(black.mean())
    if raw.cfa is None:
        rgb = (data - black) / span
    else:
        h, w = data.shape[0] // 2 * 2, data.shape[1] // 2 * 2
        black = np.broadcast_to(black, (2, 2))
        planes = [(data[i:h:2, j:w:2] - black[i, j]) / span for i, j in raw.cfa.packed_sites]
        rgb = np.stack([planes[0], (planes[1] + planes[2]) / 2, planes[3]], axis=-1)
    rgb = np.maximum(rgb, 0.0)
    if rgb.shape[-1] == 3 and "white_balance" in info:
        rgb = np.minimum(rgb * np.asarray(info["white_balance"], dtype=np.float32), 1.0)
    if rgb.shape[-1] == 3 and "color_matrix" in info:
        rgb = rgb @ np.asarray(info["color_matrix"], dtype=np.float32).T
    top = float(np.percentile(rgb.reshape(-1, rgb.shape[-1]), 100 * (1 - AUTO_CLIP), axis=0).max())
    return float(np.clip(-np.log2(top), 0.0, AUTO_MAX_STOPS)) if top > 0 else AUTO_MAX_STOPS


def white_level(stage: dict, raw, info: dict) -> float:
    """The white level (DN) of a ``black_level`` stage for this raw: the file's, or with
    ``white_level = "auto"`` the image's maximum where that lies between 75 % of
    the file's and the file's (LibRaw's default render: the brightest value becomes
    white). Recorded in ``info["white_level"]``."""
    level = float(raw.white_level)
    if stage.get("white_level", "file") == "auto":
        top = float(raw.data.max())
        if ADJUST_MAXIMUM * level < top < level:
            level = top
    info["white_level"] = level
    return level


def white_balance(stage: dict, config: list[dict], raw, warnings: list[str], info: dict):
    """Gains (R, G, B) of a ``white_balance`` stage for this raw, as LibRaw chooses them.

    ``camera``: the camera's multipliers where LibRaw uses them; where they are
    missing or marked unusable (a first multiplier ≤ 0, e.g. −1 or ``[0, 1, 0, 0]``)
    LibRaw's automatic white balance, and where only the blue one is missing the
    daylight multipliers (which LibRaw then keeps). ``daylight``: the multipliers
    LibRaw starts from. ``auto``: :func:`auto_white_balance`. A fallback is warned
    and ``info["white_balance_source"]`` says which gains were used and why.

    With highlights clipped (LibRaw's default) the gains are scaled so that the
    smallest is 1, as LibRaw does: every channel reaches white together and clipped
    highlights stay neutral. With other highlight modes they keep G = 1.
    """
    mode, source = stage["mode"], stage["mode"]
    if mode == "camera" and raw.as_shot_wb is None:
        mode = raw.camera_wb_fallback
        why = f"the camera's multipliers are unusable ({raw.camera_wb_note})"
        source = f"{mode}: {why}, as LibRaw does"
        warnings.append(f"camera white balance: {why}; using {mode}, as LibRaw does")
    if mode == "daylight" and raw.daylight_wb is None:
        mode, source = "auto", "auto: no daylight multipliers"
        warnings.append("daylight white balance unknown: using auto (grey world)")
    if mode == "camera":
        gains = raw.as_shot_wb
    elif mode == "daylight":
        gains = raw.daylight_wb
    elif mode == "auto":
        gains = auto_white_balance(raw)
    else:
        gains, source = parse_gains(mode), "user"
    if any(s["name"] == "highlights" and s["enabled"] and s["mode"] == "clip" for s in config):
        low = min(gains)
        gains = tuple(float(g / low) for g in gains)
    info["white_balance"] = list(gains)
    info["white_balance_source"] = source
    return gains


def camera_to_output(raw, space: str) -> np.ndarray:
    """(3, 3) camera (white-balanced) → output-space matrix for this raw."""
    if space == "camera":
        return np.eye(3)
    if raw.xyz_to_camera is not None:
        to_srgb = srgb_from_camera(raw.xyz_to_camera)
    elif raw.camera_to_srgb is not None:
        to_srgb = raw.camera_to_srgb
    else:
        to_srgb = np.eye(3)
    return SRGB_TO_XYZ @ to_srgb if space == "xyz" else to_srgb
