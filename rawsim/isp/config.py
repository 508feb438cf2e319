"""The ISP's configuration: its stages, their parameters, validation and TOML.

A config is a list of tables, one per stage, in processing order::

    [[stage]]
    name = "white_balance"
    mode = "camera"

Every stage takes ``enabled`` (bool) besides its own keys; :func:`default_config`
lists them all with their defaults, and ``rawsim isp show`` prints it as TOML.
:func:`validate_config` rejects unknown stages and keys, bad values and orders
that cannot work (listing what is valid). :func:`resolve_white_balance` and
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
    "black_level": {},
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
        "mode": Param("camera", _wb_mode, "camera, daylight, auto (grey world) or R,G,B"),
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
    "exposure": {"ev": Param(0.0, _number(-20, 20), "stops; 0 maps the white level to 1")},
    "tone": {"curve": Param("none", _choice(TONE_CURVES), "tone curve")},
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
    """Apply the CLI's flags (``wb``, ``demosaic``, ``highlights``, ``tone``, ``exposure``,
    ``output_space``, ``transfer``); None leaves a value as it is. Re-validates."""
    keys = {
        "wb": ("white_balance", "mode"),
        "demosaic": ("demosaic", "method"),
        "highlights": ("highlights", "mode"),
        "tone": ("tone", "curve"),
        "exposure": ("exposure", "ev"),
        "output_space": ("color_matrix", "output_space"),
        "transfer": ("transfer", "function"),
    }
    out = [dict(s) for s in config]
    for flag, value in changes.items():
        if value is None:
            continue
        stage, key = keys[flag]
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


@dataclass(frozen=True)
class TransferSpec:
    """A parsed transfer name: ``srgb``, ``linear`` or ``gamma:G``."""

    kind: str
    gamma: float = 1.0

    @classmethod
    def parse(cls, text: str) -> TransferSpec:
        """Parse ``"srgb"``, ``"linear"`` or ``"gamma:2.2"``."""
        text = str(text).strip().lower()
        if text in ("srgb", "linear"):
            return cls(text)
        if text.startswith("gamma:"):
            try:
                gamma = float(text.split(":", 1)[1])
            except ValueError:
                gamma = float("nan")
            if not gamma > 0:
                raise ParameterError(f"bad transfer {text!r}: gamma must be a number > 0")
            return cls("gamma", gamma)
        raise ParameterError(f"unknown transfer {text!r}; valid: srgb, linear, gamma:G")

    def __str__(self) -> str:
        return f"gamma:{self.gamma:g}" if self.kind == "gamma" else self.kind

    def encode(self, x):
        """Linear → display values (torch tensors: :mod:`rawsim.isp.transfer`)."""
        from rawsim.isp.transfer import gamma_encode, srgb_encode

        if self.kind == "srgb":
            return srgb_encode(x)
        if self.kind == "gamma":
            return gamma_encode(x, self.gamma)
        return x

    def decode(self, v):
        """Display → linear values (torch tensors)."""
        from rawsim.isp.transfer import gamma_decode, srgb_decode

        if self.kind == "srgb":
            return srgb_decode(v)
        if self.kind == "gamma":
            return gamma_decode(v, self.gamma)
        return v


def grey_world_gains(mosaic: np.ndarray, cfa, black, white) -> tuple[float, float, float]:
    """Grey-world gains (G = 1): mean(G) / mean(C) over unsaturated sites, black subtracted."""
    x = (mosaic.astype(np.float64) - black) / (white - black)
    colors = np.asarray(cfa.colors).reshape(2, 2) if cfa is not None else None
    means = []
    for c in range(3):
        if colors is None:
            v = x[..., c]
        else:
            v = np.concatenate(
                [x[r::2, q::2].ravel() for r in range(2) for q in range(2) if colors[r, q] == c]
            )
        v = v[v < 0.98]
        means.append(max(float(v.mean()) if v.size else 0.0, 1e-6))
    return (means[1] / means[0], 1.0, means[1] / means[2])


def resolve_white_balance(mode: str, raw, warnings: list[str]) -> tuple[float, float, float]:
    """Gains for ``mode`` and this raw, falling back (with a warning) when unknown."""
    if mode not in ("camera", "daylight", "auto"):
        return parse_gains(mode)
    if mode == "camera":
        if raw.as_shot_wb is not None:
            return raw.as_shot_wb
        warnings.append("camera white balance unknown: using daylight")
        mode = "daylight"
    if mode == "daylight":
        if raw.daylight_wb is not None:
            return raw.daylight_wb
        warnings.append("daylight white balance unknown: using grey world")
    h, w = raw.data.shape[:2]
    black = raw.black_level if raw.cfa is None else np.tile(raw.black_level, (h // 2, w // 2))
    return grey_world_gains(raw.data, raw.cfa, black, raw.white_level)


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
