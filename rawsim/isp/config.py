"""The ISP's configuration: one typed, validated description per stage, in order.

Users write a config as TOML, a list of tables, one per stage, in processing
order::

    [[stage]]
    name = "white_balance"
    mode = "camera"

Each table becomes one frozen stage description (:class:`WhiteBalanceStage`, …,
all listed in :data:`STAGES`), validated on construction: every stage takes
``enabled`` (bool) besides its own parameters, which have defaults, checks and a
help text in one place, the stage's dataclass field. An :class:`IspConfig` holds
the stages in order and rejects orders that cannot work; it reads TOML
(:meth:`IspConfig.load`), writes it (:meth:`IspConfig.to_toml`, what ``rawsim isp
show`` prints) and takes the CLI's flags (:meth:`IspConfig.override`). Errors say
what is valid.

:func:`resolve` is the one step from a config to a particular raw: the stages
that act on it and the values they take from it (white level in DN, white-balance
gains, camera → output matrix, exposure stops), recorded as the sidecar shows
them. The torch reference (:func:`rawsim.isp.pipeline.build_isp`) and the
compiled engine (:func:`rawsim.pipelines.process.engine_plan`) both build from
that :class:`ResolvedIsp`.

No torch here: the compiled engine and ``rawsim process`` start without it.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import InitVar, dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from rawsim.cameras import spectra
from rawsim.color import SRGB_TO_XYZ, XYZ_D65, srgb_from_camera
from rawsim.colorspaces import OUTPUT_SPACES as COLOR_SPACES
from rawsim.colorspaces import space_from_srgb, space_transfer
from rawsim.errors import ParameterError
from rawsim.io.lensfun import CORRECTIONS as LENS_CORRECTIONS
from rawsim.io.lensfun import DEFAULT_DISTANCE, without_tca
from rawsim.isp.curves import TransferSpec
from rawsim.spectral.fit import aces_from_camera

if TYPE_CHECKING:
    from rawsim.io.raw import RawImage

#: Unprocessing's inverse white balance, ``safe`` mode: the grey level above which it
#: blends the gains towards 1 (:func:`rawsim.isp.white_balance.safe_invert_white_balance`).
SAFE_WB_THRESHOLD = 0.9
#: The radial lens-shading model's coefficients (:func:`rawsim.isp.lens_shading.radial_gain`),
#: the vignetting that ``unprocess --vignetting`` adds.
DEFAULT_K = (0.3, 0.15, 0.05)
DEMOSAIC_METHODS = ("wcd", "learned", "menon", "malvar", "bilinear")
#: What each demosaic method becomes on an X-Trans (6×6) mosaic: ``bilinear`` stays
#: LibRaw's same-colour average; the Bayer interpolations all become ``icd``
#: (:mod:`rawsim.isp.xtrans`).
XTRANS_METHOD = {m: "bilinear" if m == "bilinear" else "icd" for m in DEMOSAIC_METHODS}
#: The demosaic stage's ``half``: no interpolation, one pixel per 2×2 block of any
#: mosaic (:mod:`rawsim.isp.half_size`; ``rawsim process --half-size``).
HALF_SIZE = "half"
#: What the interpolation works on: ``sqrt``, the odd root sign(v)·(√(|v| + ε) − √ε)
#: of each linear value, squared back after (v ↦ sign(v)·((|v| + √ε)² − ε)), so that
#: its errors are spread as a display's gamma spreads them (on the Kodak photos made
#: linear, 40.1 dB CPSNR instead of 35.0), or ``linear``, the values as they are (as
#: LibRaw). ε keeps the slope at 0 finite (50 per unit of white).
DEMOSAIC_DOMAINS = ("sqrt", "linear")
DEMOSAIC_ROOT_EPS = 1e-4
#: Where each colour saturates (the black level stage's ``saturation``): where its sites
#: pile up in the data below the white level, if they do, or the white level.
SATURATION_SOURCES = ("data", "white")
#: ``clip`` at white (LibRaw -H 0); ``unclip``: none (-H 1), but a clipped site is only
#: a lower bound, raised to the largest value its block's unclipped colours measured
#: (neutral where every colour clipped), on the mosaic; ``blend``: dcraw's blend (-H 2,
#: on RGB); ``reconstruct``: clipped sites rebuilt from the unclipped colours and the
#: hue around them, on the mosaic (:mod:`rawsim.isp.highlights`).
HIGHLIGHT_MODES = ("clip", "blend", "reconstruct", "unclip")
#: The highlight modes that work on RGB only: after the demosaic.
RGB_HIGHLIGHT_MODES = ("blend",)
#: ``reconstruct``: a site is clipped at this share of its colour's clip level (the
#: white-balance gain: white = 1 before it).
HIGHLIGHT_CLIPPED = 0.99
#: ``unclip``: a site is clipped at this share of its colour's clip level. Lower than
#: ``reconstruct``'s: a camera's codec can spread a saturated colour around its level
#: (the GoPro HERO6 crop of tests/data/highlights: ±150 DN, about ±4 %), and a block
#: whose green saturated below 0.99 of its level kept it while red and blue were
#: raised: 0.39 % of its white pixels magenta at 0.99, none at 0.95.
HIGHLIGHT_UNCLIP_CLIPPED = 0.95
#: ``reconstruct``: half-widths (in blocks) of the boxes whose normalised sum carries
#: the hue of unclipped blocks into clipped ones, nearest first; the largest bounds
#: how far a region's border reaches into it. Each box's mean counts this much less
#: than the one before it, so the nearest unclipped blocks give the hue where there are
#: any and farther ones only fill in where there are none.
HIGHLIGHT_SCALES = (1, 4, 16, 64)
HIGHLIGHT_SCALE_WEIGHT = 0.25
#: ``reconstruct``: the hue is read from unclipped blocks within this many blocks of a
#: clipped one (and not next to one, where the mean of a colour may hold a clipped
#: site's neighbour): the border of a clipped region, as darktable reads it.
HIGHLIGHT_BORDER = 4
#: ``reconstruct``: each border block's hue counts by its brightness (its brightest
#: colour over its clip level, at most 1) to this power, so the blocks just below the
#: clip (the same sky or lamp, a step darker) outweigh darker things beside the
#: region (branches across a sky).
HIGHLIGHT_BORDER_POWER = 3
#: ``reconstruct``: where exactly two colours clip, white light would put the third at
#: least at their clip levels. The lower it lies, the surer the light is coloured: at
#: (1 − this) of their highest clip level or below, the border's hue is kept whole at
#: any depth (a blue sky whose green and blue clipped stays blue).
HIGHLIGHT_WHITE_MARGIN = 0.5
#: ``reconstruct``: where one colour clips, the other two's ratio tests the border's
#: hue against white light (equal shares): each is trusted by how well it predicts
#: that ratio, a Gaussian of this width in the log of the ratio.
HIGHLIGHT_HUE_SIGMA = 0.2
#: ``reconstruct``: where one colour clips, the log odds of the border's hue over white
#: light before that test: where both predict the ratio alike (a sky whose hue differs
#: from white in the clipped colour alone), the hue the border measured is kept
#: (e^4 ≈ 55 to 1), not blended half-way to white.
HIGHLIGHT_HUE_PRIOR = 4.0
#: ``reconstruct``: where one colour clips, the border's hue is kept whole while it gives
#: that colour at most the first of these times what white light gives it (the other
#: two's mean, at least its clipped mean), and not at all from the second: further, it
#: comes from the border, not from the light the other two measured.
HIGHLIGHT_HUE_REACH = (1.5, 2.5)
#: ``reconstruct``: where two colours clip and the border's hue gives green
#: the least share, that hue is kept by 1 − (its spread over the border / this), the
#: spread being the root of the summed variances of the border blocks' shares: brown
#: branches and a blue sky around a blown sky average to a purple no border block has,
#: which the block would take (magenta); a border of one hue keeps it.
HIGHLIGHT_HUE_SPREAD = 0.15
#: ``reconstruct``: a rebuilt value is at most this many times its colour's clip level.
HIGHLIGHT_HEADROOM = 4.0
#: ``reconstruct``: no colour's share of a block's sum is taken below this.
HIGHLIGHT_RATIO_FLOOR = 0.01
#: ``reconstruct``'s magenta guard (:mod:`rawsim.isp.magenta_guard`): the CIELAB hues
#: (degrees, D65) it keeps rebuilt light out of, where green clipped: magenta and
#: purple, the hues a green rebuilt too low beside red and blue takes.
HIGHLIGHT_MAGENTA = (290.0, 345.0)
#: The guard takes hues this many degrees beyond the band's edges, so that rounding
#: (float32 values, 16-bit codes, another reader's D65) leaves none inside it.
HIGHLIGHT_GUARD_MARGIN = 1.0
#: The guard leaves greys alone: a colour is in the band only where its chroma C*ab
#: exceeds this share of 116 f(Y) (its lightness before CIELAB's offset), 2 units of
#: chroma at L* = 100; the hue of a near-neutral white is noise.
HIGHLIGHT_GUARD_CHROMA = 0.02
#: The guard's search for the least green raise: halvings of [0, this × the pixel's
#: largest value].
HIGHLIGHT_GUARD_REACH = 4.0
HIGHLIGHT_GUARD_STEPS = 20

TONE_CURVES = ("none", "smoothstep", "reinhard", "aces", "hable")
#: The filmic curves' white point W: the least and the most (in each curve's units).
TONE_WHITE_RANGE = (0.25, 12.0)
ANTI_ALIAS_METHODS = ("none", "weighted_average", "gaussian")
DENOISE_METHODS = ("none", "gaussian", "bilateral")
#: Denoising of the raw mosaic driven by its noise model (:mod:`rawsim.denoise`).
RAW_DENOISE_METHODS = ("profiled", "learned")
#: ``rawsim process --denoise``: the filters of the denoise stage, or a raw method.
DENOISE_CHOICES = (*DENOISE_METHODS, *RAW_DENOISE_METHODS)


def highlight_block(colors: tuple[int, ...], period: tuple[int, int]) -> int:
    """``reconstruct``'s block side: the smallest b dividing the CFA period whose every
    aligned b × b block holds all three colours (2 for Bayer, 3 for X-Trans), else the
    least common multiple of the period's sides (whole periods); 1 without a CFA."""
    if not colors:
        return 1
    ph, pw = period
    tile = [colors[r * pw : (r + 1) * pw] for r in range(ph)]
    for b in range(2, max(ph, pw) + 1):
        if ph % b or pw % b:
            continue
        blocks = (
            {tile[r][c] for r in range(i, i + b) for c in range(j, j + b)}
            for i in range(0, ph, b)
            for j in range(0, pw, b)
        )
        if all(block == {0, 1, 2} for block in blocks):
            return b
    return math.lcm(ph, pw)


def magenta_edges() -> tuple[tuple[float, float], tuple[float, float]]:
    """The unit vectors (a, b) of the hues the magenta guard clears: ``HIGHLIGHT_MAGENTA``
    widened by ``HIGHLIGHT_GUARD_MARGIN`` on each side."""
    lo, hi = HIGHLIGHT_MAGENTA
    lo, hi = math.radians(lo - HIGHLIGHT_GUARD_MARGIN), math.radians(hi + HIGHLIGHT_GUARD_MARGIN)
    return (math.cos(lo), math.sin(lo)), (math.cos(hi), math.sin(hi))


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

#: ``--output-space``: the RGB spaces of :mod:`rawsim.colorspaces`, CIE XYZ, camera RGB.
OUTPUT_SPACES = COLOR_SPACES


# ------------------------------------------------------------------ value checks
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
    if value == "auto":
        return value
    try:
        return str(TransferSpec.parse(value))
    except ParameterError as err:
        raise ParameterError(f"{err}, or auto (the output space's own)") from None


def _shading_k(value):
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ParameterError(f"expected a list of 3 numbers, got {value!r}")
    return tuple(_number()(v) for v in value)


def _lens_name(value):
    if not isinstance(value, str) or not value.strip():
        raise ParameterError(f"expected auto or a lens name, got {value!r}")
    return " ".join(value.split())


def _corrections(value):
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",")]
    if not isinstance(value, (list, tuple)) or not all(v in LENS_CORRECTIONS for v in value):
        raise ParameterError(f"{value!r}; valid: a list of {', '.join(LENS_CORRECTIONS)}")
    return tuple(c for c in LENS_CORRECTIONS if c in value)


def _param(default: Any, check: Callable[[Any], Any], help: str):
    """A stage parameter: its default, its check (returns the value as stored) and help."""
    return field(default=default, metadata={"check": check, "help": help})


# ------------------------------------------------------------------ stages
@dataclass(frozen=True)
class Stage:
    """One stage's description: ``enabled`` and its parameters, checked on construction.

    Subclasses set ``name`` (the TOML ``name``) and where the stage may run, and
    declare their parameters with :func:`_param`. Stages that take values from
    the raw being processed record them in :meth:`resolve`.
    """

    name: ClassVar[str]
    #: Enabled in :meth:`IspConfig.default`.
    on_by_default: ClassVar[bool] = True
    #: Acts on the mosaic (before ``demosaic``); skipped for raws without a CFA.
    mosaic_only: ClassVar[bool] = False
    #: Needs RGB: comes after ``demosaic``.
    rgb_only: ClassVar[bool] = False
    #: Needs colour channels: skipped for monochrome data.
    colour_only: ClassVar[bool] = False

    enabled: bool = True

    def __post_init__(self) -> None:
        for f in fields(self):
            check = f.metadata.get("check", _flag)
            try:
                object.__setattr__(self, f.name, check(getattr(self, f.name)))
            except ParameterError as err:
                raise ParameterError(f"{self.name}.{f.name}: {err}") from None
        self._check()

    def _check(self) -> None:
        """Checks across parameters, after each one's own."""

    @classmethod
    def params(cls) -> dict[str, Any]:
        """Parameter name → its dataclass field (default, ``check`` and ``help`` metadata)."""
        return {f.name: f for f in fields(cls) if f.name != "enabled"}

    @classmethod
    def from_table(cls, table: dict) -> Stage:
        """The stage of a TOML table (its ``name`` already matched); defaults fill the rest."""
        params = cls.params()
        unknown = sorted(set(table) - set(params) - {"name", "enabled"})
        if unknown:
            valid = ", ".join(["enabled", *params])
            raise ParameterError(f"{cls.name}: unknown key {unknown[0]!r}; valid: {valid}")
        return cls(**{k: v for k, v in table.items() if k != "name"})

    def to_table(self) -> dict:
        """The TOML table: ``name``, ``enabled``, then every parameter (lists as lists)."""
        table = {"name": self.name, "enabled": self.enabled}
        for key in self.params():
            value = getattr(self, key)
            table[key] = list(value) if isinstance(value, tuple) else value
        return table

    def acts_on(self, raw: RawImage) -> bool:
        """Whether the stage runs on ``raw``: mosaic stages need a CFA, colour stages colour."""
        return self.idle_reason(raw) is None

    def idle_reason(self, raw: RawImage) -> str | None:
        """Why the stage cannot act on ``raw``, a clause (``"acts on a CFA mosaic; this
        LinearRaw DNG has none"``), or None where it acts."""
        if raw.cfa is None and self.mosaic_only:
            return f"acts on a CFA mosaic; {raw_kind(raw)} has none"
        if monochrome(raw) and self.colour_only:
            return f"acts on colour; {raw_kind(raw)} has one channel"
        return None

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> str | None:
        """Record in ``info`` the values this stage takes from ``raw`` (most take none).
        Returns why the stage, though it runs, changes nothing on ``raw`` (a clause),
        else None."""


@dataclass(frozen=True)
class BlackLevelStage(Stage):
    """Black level subtraction and scaling to white = 1."""

    name: ClassVar[str] = "black_level"
    white_level: str = _param(
        "file", _choice(("file", "auto")), "file, or auto (LibRaw's adjust_maximum_thr=0.75)"
    )
    saturation: str = _param(
        "data",
        _choice(SATURATION_SOURCES),
        "data: each colour saturates where its sites pile up below the white level, if they "
        "do (rawsim.engine.saturation); white: every colour at the white level",
    )

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> None:
        """``info["white_level"]``: the file's white level (DN), or with ``white_level =
        "auto"`` the image's maximum where that lies between 75 % of the file's and the
        file's (LibRaw's default render: the brightest value becomes white).

        ``info["saturation"]``: where each colour (R, G, B) saturates, ``levels`` (DN, at
        most the white level) and ``found`` (how, in words): with ``saturation =
        "data"`` where its sites pile up (:func:`rawsim.engine.saturation.find_saturation`),
        else the white level. None for monochrome data."""
        level = float(raw.white_level)
        if self.white_level == "auto":
            top = float(raw.data.max())
            if ADJUST_MAXIMUM * level < top < level:
                level = top
        info["white_level"] = level
        info["saturation"] = None if monochrome(raw) else _saturation(raw, level, self.saturation)


def _noise_profile(value):
    if not isinstance(value, str) or not value.strip():
        raise ParameterError(f"expected auto, a profile name or a profile file, got {value!r}")
    return value.strip()


@dataclass(frozen=True)
class RawDenoiseStage(Stage):
    """Noise removal on the raw mosaic, driven by the raw's noise model; it must come
    right after ``black_level``, while the mosaic is as the sensor gave it."""

    name: ClassVar[str] = "raw_denoise"
    on_by_default: ClassVar[bool] = False
    mosaic_only: ClassVar[bool] = True
    method: str = _param(
        "profiled",
        _choice(RAW_DENOISE_METHODS),
        "profiled: variance-stabilised two-pass DCT shrinkage (rawsim.denoise.profiled); "
        "learned: a network refines that (rawsim.denoise.learned; Bayer and X-Trans)",
    )
    strength: float = _param(
        1.0, _number(0.05, 10.0), "scales the noise σ the method removes (1 = the model's)"
    )
    noise_profile: str = _param(
        "auto",
        _noise_profile,
        "auto (the camera's bundled profile, else the DNG NoiseProfile, else an estimate "
        "from the raw), or a profile name or JSON file",
    )

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> None:
        """``info["noise_model"]``: the raw's noise model (:mod:`rawsim.denoise.noise_model`),
        its source said, and its warnings in ``info["warnings"]``; ``info["raw_denoise"]``:
        the method both backends run (``learned`` has weights for Bayer and X-Trans
        mosaics: other CFAs get ``profiled``, warned)."""
        from rawsim.denoise.layout import weights_kind
        from rawsim.denoise.noise_model import noise_model_for

        given = None if self.noise_profile == "auto" else self.noise_profile
        model = noise_model_for(raw, given)
        info["noise_model"] = model.to_dict()
        info["warnings"].extend(model.warnings)
        info["raw_denoise"] = self.method
        if self.method == "learned" and weights_kind(raw.cfa) is None:
            info["raw_denoise"] = "profiled"
            info["warnings"].append(
                f"--denoise learned has weights for Bayer and X-Trans mosaics only; this "
                f"{raw.cfa.name} mosaic is denoised with --denoise profiled"
            )


@dataclass(frozen=True)
class DeadPixelStage(Stage):
    """Soft correction of pixels far from their same-colour neighbours (any CFA)."""

    name: ClassVar[str] = "dead_pixel"
    on_by_default: ClassVar[bool] = False
    mosaic_only: ClassVar[bool] = True
    threshold: float = _param(
        0.1, _number(1e-6), "deviation from the same-colour neighbours' median (white = 1)"
    )
    kernel: int = _param(3, _choice((3, 5)), "window in plane pixels (2 mosaic pixels), any CFA")
    temperature: float = _param(0.01, _number(1e-6), "width of the soft decision")


@dataclass(frozen=True)
class LensShadingStage(Stage):
    """Radial vignetting correction."""

    name: ClassVar[str] = "lens_shading"
    on_by_default: ClassVar[bool] = False
    k: tuple[float, float, float] = _param(
        (0.3, 0.15, 0.05), _shading_k, "V(r) = 1 + k1 r² + k2 r⁴ + k3 r⁶"
    )
    strength: float = _param(1.0, _number(0), "0 = off, 1 = the full model")


@dataclass(frozen=True)
class AntiAliasingStage(Stage):
    """Blur of the mosaic, each colour with its own sites (any CFA)."""

    name: ClassVar[str] = "anti_aliasing"
    on_by_default: ClassVar[bool] = False
    mosaic_only: ClassVar[bool] = True
    method: str = _param("weighted_average", _choice(ANTI_ALIAS_METHODS[1:]), "blur kernel")
    sigma: float = _param(0.5, _number(1e-3), "Gaussian σ in plane pixels")


@dataclass(frozen=True)
class WhiteBalanceStage(Stage):
    """Per-channel gains."""

    name: ClassVar[str] = "white_balance"
    colour_only: ClassVar[bool] = True
    mode: str = _param("camera", _wb_mode, "camera, daylight, auto (LibRaw's grey world) or R,G,B")

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> None:
        """``info["white_balance"]``: gains (R, G, B) for ``raw``, as LibRaw chooses them,
        and ``info["white_balance_source"]``: which gains were used and why.

        ``camera``: the camera's multipliers where LibRaw uses them; where they are
        missing or marked unusable (a first multiplier ≤ 0, e.g. −1 or ``[0, 1, 0, 0]``)
        LibRaw's automatic white balance, and where only the blue one is missing the
        daylight multipliers (which LibRaw then keeps). ``daylight``: the multipliers
        LibRaw starts from. ``auto``: :func:`auto_white_balance`. A fallback is warned
        in ``info["warnings"]``.

        With highlights reconstructed (the default) or clipped (LibRaw's default) the
        gains are scaled so that the colour that saturates lowest after them
        (``info["saturation"]``: each colour c clips at gain × its saturation share
        σ_c, :func:`saturation_fractions`) clips at 1, as LibRaw scales the smallest
        multiplier to 1 for its clip: no colour clips below white, clipped highlights
        stay neutral, and the two modes render what did not clip alike. With blend and
        unclip they keep G = 1: each colour then clips at its own gain × σ_c.
        """
        mode, source = self.mode, self.mode
        if mode == "camera" and raw.as_shot_wb is None:
            mode = raw.camera_wb_fallback
            why = f"the camera's multipliers are unusable ({raw.camera_wb_note})"
            source = f"{mode}: {why}, as LibRaw does"
            info["warnings"].append(f"camera white balance: {why}; using {mode}, as LibRaw does")
        if mode == "daylight" and raw.daylight_wb is None:
            mode, source = "auto", "auto: no daylight multipliers"
            info["warnings"].append("daylight white balance unknown: using auto (grey world)")
        if mode == "camera":
            gains = raw.as_shot_wb
        elif mode == "daylight":
            gains = raw.daylight_wb
        elif mode == "auto":
            gains = auto_white_balance(raw)
        else:
            gains, source = parse_gains(mode), "user"
        highlights = config.enabled_stage(HighlightsStage)
        if highlights is not None and highlights.mode in ("clip", "reconstruct"):
            sat = saturation_fractions(raw, info)
            low = min(g * s for g, s in zip(gains, sat, strict=True))
            gains = tuple(float(g / low) for g in gains)
        info["white_balance"] = list(gains)
        info["white_balance_source"] = source


@dataclass(frozen=True)
class HighlightsStage(Stage):
    """Reconstruction of clipped colours (the default), clipping at white, none, or
    dcraw's blend of clipped channels."""

    name: ClassVar[str] = "highlights"
    colour_only: ClassVar[bool] = True
    mode: str = _param(
        "reconstruct",
        _choice(HIGHLIGHT_MODES),
        "reconstruct (before demosaic; the default), clip, unclip (none, but a clipped site "
        "is raised to what its block's unclipped colours measured: neutral where every "
        "colour clipped; before demosaic) or blend (after demosaic)",
    )


@dataclass(frozen=True)
class DemosaicStage(Stage):
    """Mosaic → RGB."""

    name: ClassVar[str] = "demosaic"
    mosaic_only: ClassVar[bool] = True
    method: str = _param(
        "wcd",
        _choice((*DEMOSAIC_METHODS, HALF_SIZE)),
        "interpolation method, or half: a half-size image without interpolation",
    )
    domain: str = _param(
        "sqrt",
        _choice(DEMOSAIC_DOMAINS),
        "values interpolated: sqrt (square roots, squared back: fewer dark fringes once "
        "encoded) or linear (as LibRaw); half ignores it",
    )


@dataclass(frozen=True)
class DenoiseStage(Stage):
    """Edge-preserving smoothing, on the mosaic's planes or on RGB."""

    name: ClassVar[str] = "denoise"
    on_by_default: ClassVar[bool] = False
    method: str = _param("bilateral", _choice(DENOISE_METHODS[1:]), "filter")
    kernel: int = _param(5, _number(3, 15, integer=True), "window size (odd)")
    sigma: float = _param(1.0, _number(1e-3), "spatial σ (pixels)")
    sigma_color: float = _param(0.05, _number(1e-6), "range σ (linear units)")


@dataclass(frozen=True)
class LensCorrectionStage(Stage):
    """The lens's distortion, lateral chromatic aberration and vignetting, from lensfun."""

    name: ClassVar[str] = "lens_correction"
    on_by_default: ClassVar[bool] = False
    rgb_only: ClassVar[bool] = True
    lens: str = _param(
        "auto", _lens_name, "auto (the raw's LensModel), or the lens's name as lensfun lists it"
    )
    focal_length: float | str = _param(
        "auto", _auto_or(_number(1e-3, 1e5), "mm"), "mm, or auto (the raw's FocalLength)"
    )
    aperture: float | str = _param(
        "auto",
        _auto_or(_number(0.5, 1000), "an f-number"),
        "f-number, or auto (the raw's FNumber); without one, vignetting stays",
    )
    distance: float | str = _param(
        "auto",
        _auto_or(_number(1e-3, 1e6), "metres"),
        f"focus distance in m, or auto (the raw's SubjectDistance, else {DEFAULT_DISTANCE:g})",
    )
    corrections: tuple[str, ...] = _param(
        LENS_CORRECTIONS, _corrections, "which to correct: distortion, tca, vignetting"
    )

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> str | None:
        """``info["lens"]``: the lens and its settings (:class:`~rawsim.io.lensfun.LensParams`
        as a dict) from lensfun's database for the raw's camera and metadata (values not
        ``auto`` replace the metadata's), or None where the raw cannot be corrected, with
        a warning in ``info["warnings"]`` saying why and what to pass (also returned: the
        stage then corrects nothing). A lens named here that lensfun does not know is an
        error."""
        from pathlib import Path

        from rawsim.io.lensfun import raw_lens
        from rawsim.io.metadata import PhotoMetadata, read_metadata

        meta = read_metadata(raw.path) if Path(raw.path).is_file() else PhotoMetadata()
        params, warnings = raw_lens(
            raw.make,
            raw.model,
            meta,
            self.lens,
            self.focal_length,
            self.aperture,
            self.distance,
            self.corrections,
        )
        info["warnings"].extend(warnings)
        info["lens"] = None if params is None else params.to_dict()
        if params is None:  # the warning says why ("lens correction: …: not corrected; …")
            return warnings[0].removeprefix("lens correction: ")
        return None


@dataclass(frozen=True)
class ColorMatrixStage(Stage):
    """Camera RGB (white-balanced) → the output space."""

    name: ClassVar[str] = "color_matrix"
    rgb_only: ClassVar[bool] = True
    colour_only: ClassVar[bool] = True
    output_space: str = _param(
        "srgb",
        _choice(OUTPUT_SPACES),
        "srgb, display-p3, adobe-rgb, rec2020, prophoto (linear primaries), xyz (CIE XYZ, "
        "D65), or camera RGB",
    )
    dng_matrices: str = _param(
        "interpolate",
        _choice(("interpolate", "libraw")),
        "a DNG with two colour matrices: interpolate them by the white balance used, as "
        "the DNG specification does, or take LibRaw's one",
    )

    def matrix(self, raw: RawImage, xyz_to_camera: np.ndarray | None = None) -> np.ndarray:
        """(3, 3) float64 camera (white-balanced) → output-space matrix for ``raw``: to
        linear sRGB as LibRaw does (from ``xyz_to_camera`` where given), then
        :func:`rawsim.colorspaces.space_from_srgb` (through XYZ; Bradford-adapted to D50
        for ProPhoto)."""
        if self.output_space == "camera":
            return np.eye(3)
        if xyz_to_camera is None:
            to_srgb = camera_to_srgb(raw)
        else:
            to_srgb = srgb_from_camera(xyz_to_camera)
        if self.output_space == "srgb":
            return to_srgb
        return space_from_srgb(self.output_space) @ to_srgb

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> None:
        """``info["color_matrix"]``: :meth:`matrix` as nested lists, for a DNG with two
        colour matrices (``dng_matrices = "interpolate"``) from their interpolation by
        the white balance used (:meth:`rawsim.io.dng_colour.DngColour.interpolated`;
        ``info["dng_matrices"]`` records it); into an ACES space, where the raw's
        camera has measured spectral sensitivities, the spectral input transform
        instead (:func:`rawsim.spectral.fit.aces_from_camera`, for the white balance
        used). ``info["aces_idt"]`` says which and from what."""
        if self.output_space.startswith("aces"):
            curves = spectra.of_make_model(raw.make, raw.model)
            # rawtoaces' transform wants a camera's measured curves; estimated ones come
            # from the colour matrix, which the matrix transform already uses
            if curves is not None and curves.kind == "measured" and "white_balance" in info:
                matrix, used = aces_from_camera(
                    curves.rgb, info["white_balance"], self.output_space
                )
                info["color_matrix"] = matrix.tolist()
                info["aces_idt"] = {
                    "kind": "spectral",
                    "how": "rawtoaces' procedure: B fitted from the spectral sensitivities "
                    "on the 190 training patches (CIELAB, CAT02 to the ACES white) under "
                    "the candidate light whose white balance is nearest the one used, "
                    "which stays (b: rawtoaces' own for that light)",
                    "curves": curves.source,
                    **used,
                }
                return
            info["aces_idt"] = {
                "kind": "matrix",
                "how": "from the colour matrix (matrix_source): camera → XYZ (D65), then "
                "Bradford's adaptation to the ACES white; "
                + (
                    "no spectral sensitivities are published for this camera"
                    if curves is None or curves.kind != "measured"
                    else "no white balance was applied"
                ),
            }
        xyz = None
        if self.dng_matrices == "interpolate" and raw.dng_colour and "white_balance" in info:
            found = raw.dng_colour.interpolated(info["white_balance"])
            if found is not None:
                xyz, how = found
                info["dng_matrices"] = {
                    "interpolated": "the DNG's two colour matrices, weighted in inverse "
                    "temperature by the white balance used (DNG specification, chapter 6)",
                    **how,
                }
        info["color_matrix"] = self.matrix(raw, xyz).tolist()


def camera_to_srgb(raw: RawImage) -> np.ndarray:
    """(3, 3) float64 white-balanced camera RGB → linear sRGB, as LibRaw does: from the
    raw's XYZ → camera matrix, else its own camera → sRGB matrix, else the identity."""
    if raw.xyz_to_camera is not None:
        return srgb_from_camera(raw.xyz_to_camera)
    if raw.camera_to_srgb is not None:
        return np.asarray(raw.camera_to_srgb, dtype=np.float64)
    return np.eye(3)


@dataclass(frozen=True)
class ExposureStage(Stage):
    """A gain of 2^stops."""

    name: ClassVar[str] = "exposure"
    ev: float | str = _param(
        0.0,
        _auto_or(_number(-20, 20), "stops in [-20, 20]"),
        "stops (0 maps the white level to 1), or auto: the 99th percentile to 1 (LibRaw's "
        "auto-brightness)",
    )
    baseline: str = _param(
        "apply",
        _choice(("apply", "ignore")),
        "the DNG's BaselineExposure: apply (as Adobe's DNG SDK) or ignore (as LibRaw)",
    )

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> None:
        """``info["exposure_stops"]``: ``ev``, plus the file's DNG BaselineExposure unless
        ``baseline = "ignore"``; for ``auto`` :func:`auto_exposure_stops` (the baseline is
        then moot), which reads the values the stages before it recorded."""
        if self.ev == "auto":
            stops = auto_exposure_stops(raw, info)
        else:
            stops = self.ev + (raw.baseline_exposure if self.baseline == "apply" else 0.0)
        info["exposure_stops"] = stops


@dataclass(frozen=True)
class ToneStage(Stage):
    """A tone curve on linear values."""

    name: ClassVar[str] = "tone"
    curve: str = _param("none", _choice(TONE_CURVES), "tone curve")
    exposure: float = _param(
        0.0, _number(0, 4), "filmic curves: stops of gain before the curve (1 reached at 2^-ev)"
    )
    white: float | str = _param(
        "auto",
        _auto_or(_number(*TONE_WHITE_RANGE)),
        "filmic curves: white point in the curve's units (auto: reinhard 4, aces 7.24, "
        "hable 11.2); larger compresses highlights more",
    )

    def _check(self) -> None:
        shapes = self.exposure != 0 or self.white != "auto"
        if shapes and self.curve in ("none", "smoothstep"):
            raise ParameterError(
                f"{self.name}: exposure and white shape the filmic curves (reinhard, aces, "
                f"hable), not {self.curve!r}; choose one with --tone"
            )

    @property
    def white_point(self) -> float | None:
        """``white`` as a number, or None for the curve's own."""
        return None if self.white == "auto" else self.white


@dataclass(frozen=True)
class TransferStage(Stage):
    """The output transfer function (OETF)."""

    name: ClassVar[str] = "transfer"
    function: str = _param(
        "auto",
        _transfer,
        "auto (the output space's own: srgb for srgb, display-p3, xyz and camera; "
        "gamma:563/256 for adobe-rgb; bt2020 for rec2020; romm for prophoto), srgb, "
        "bt2020, romm, gamma:G or linear",
    )

    def spec_for(self, output_space: str) -> TransferSpec:
        """The function for an output in ``output_space``: ``auto`` is the space's own."""
        if self.function == "auto":
            return space_transfer(output_space)
        return TransferSpec.parse(self.function)

    def resolve(self, raw: RawImage, config: IspConfig, info: dict) -> None:
        """``info["transfer"]``: the function used (``auto`` resolved for the config's
        output space; without a colour matrix stage the output is camera RGB)."""
        matrix = config.enabled_stage(ColorMatrixStage)
        info["transfer"] = str(self.spec_for(matrix.output_space if matrix else "camera"))


@dataclass(frozen=True)
class YCbCrStage(Stage):
    """RGB → YCbCr (BT.601)."""

    name: ClassVar[str] = "ycbcr"
    on_by_default: ClassVar[bool] = False
    rgb_only: ClassVar[bool] = True
    colour_only: ClassVar[bool] = True


@dataclass(frozen=True)
class OrientationStage(Stage):
    """The raw's EXIF orientation, applied last."""

    name: ClassVar[str] = "orientation"
    rgb_only: ClassVar[bool] = True


#: Stage name → its type, in the default processing order.
STAGES: dict[str, type[Stage]] = {
    cls.name: cls
    for cls in (
        BlackLevelStage,
        RawDenoiseStage,
        DeadPixelStage,
        LensShadingStage,
        AntiAliasingStage,
        WhiteBalanceStage,
        HighlightsStage,
        DemosaicStage,
        DenoiseStage,
        LensCorrectionStage,
        ColorMatrixStage,
        ExposureStage,
        ToneStage,
        TransferStage,
        YCbCrStage,
        OrientationStage,
    )
}

#: ``rawsim process`` flag → the stage and parameter it sets.
_FLAGS: dict[str, tuple[type[Stage], str]] = {
    "wb": (WhiteBalanceStage, "mode"),
    "white_level": (BlackLevelStage, "white_level"),
    "saturation": (BlackLevelStage, "saturation"),
    "baseline_exposure": (ExposureStage, "baseline"),
    "demosaic": (DemosaicStage, "method"),
    "demosaic_domain": (DemosaicStage, "domain"),
    "highlights": (HighlightsStage, "mode"),
    "tone": (ToneStage, "curve"),
    "tone_exposure": (ToneStage, "exposure"),
    "tone_white": (ToneStage, "white"),
    "exposure": (ExposureStage, "ev"),
    "denoise_strength": (RawDenoiseStage, "strength"),
    "noise_profile": (RawDenoiseStage, "noise_profile"),
    "output_space": (ColorMatrixStage, "output_space"),
    "dng_matrices": (ColorMatrixStage, "dng_matrices"),
    "transfer": (TransferStage, "function"),
    "lens": (LensCorrectionStage, "lens"),
    "focal_length": (LensCorrectionStage, "focal_length"),
    "aperture": (LensCorrectionStage, "aperture"),
}


# ------------------------------------------------------------------ the config
@dataclass(frozen=True)
class IspConfig:
    """Stages in processing order, each at most once, in an order that can work.

    ``origin`` names the config in errors (a file, ``options``); it is not kept.
    ``asked``: (stage name, the flag that set it as typed, e.g. ``--denoise profiled``)
    for each stage a flag of :meth:`override` set, first flag first: a stage asked for
    that cannot act on a raw is warned in the flag's words (:func:`resolve`). Not part
    of the config's value (equality, TOML).
    """

    stages: tuple[Stage, ...]
    origin: InitVar[str] = "config"
    asked: tuple[tuple[str, str], ...] = field(default=(), compare=False)

    def __post_init__(self, origin: str) -> None:
        object.__setattr__(self, "stages", tuple(self.stages))
        seen: set[type[Stage]] = set()
        for i, stage in enumerate(self.stages):
            if type(stage) in seen:
                raise ParameterError(f"{origin}: stage {i + 1}: stage {stage.name!r} appears twice")
            seen.add(type(stage))
        _check_order(self.enabled, origin)

    @classmethod
    def default(cls) -> IspConfig:
        """Every stage with its defaults, in the default order."""
        return cls(tuple(stage(enabled=stage.on_by_default) for stage in STAGES.values()))

    @classmethod
    def of(cls, config: IspConfig | list[dict]) -> IspConfig:
        """``config`` itself, or its TOML form (a list of stage tables) parsed."""
        return config if isinstance(config, IspConfig) else cls.from_tables(config)

    @classmethod
    def from_tables(cls, tables: Any, origin: str = "config") -> IspConfig:
        """Parse the TOML form, a list of ``[[stage]]`` tables; defaults fill the rest."""
        if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
            raise ParameterError(f"{origin}: expected a list of [[stage]] tables")
        stages = []
        for i, table in enumerate(tables):
            name = table.get("name")
            where = f"{origin}: stage {i + 1}"
            if name not in STAGES:
                raise ParameterError(f"{where}: unknown stage {name!r}; valid: {', '.join(STAGES)}")
            try:
                stages.append(STAGES[name].from_table(table))
            except ParameterError as err:  # "name.key: why" → "where (name).key: why"
                raise ParameterError(f"{where} ({name}){str(err).removeprefix(name)}") from None
        return cls(tuple(stages), origin)

    @classmethod
    def from_toml(cls, text: str, origin: str = "config") -> IspConfig:
        """Parse TOML text (see :meth:`load`)."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise ParameterError(f"{origin}: not valid TOML ({err})") from None
        unknown = sorted(set(data) - {"stage"})
        if unknown:
            raise ParameterError(f"{origin}: unknown top-level key {unknown[0]!r}; valid: stage")
        return cls.from_tables(data.get("stage", []), origin)

    @classmethod
    def load(cls, path) -> IspConfig:
        """Read and validate a TOML config file."""
        try:
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
        except (OSError, UnicodeDecodeError) as err:
            reason = getattr(err, "strerror", None) or str(err)
            raise ParameterError(f"{path}: cannot read config ({reason})") from None
        return cls.from_toml(text, str(path))

    def to_tables(self) -> list[dict]:
        """The TOML form: one table per stage, every parameter filled in."""
        return [stage.to_table() for stage in self.stages]

    def to_toml(self) -> str:
        """TOML text with a comment per parameter; :meth:`load` reads it back."""
        lines = ["# rawsim ISP config: stages run in this order; set enabled = false to skip one."]
        for stage in self.stages:
            lines += ["", "[[stage]]"]
            params = stage.params()
            for key, value in stage.to_table().items():
                comment = f"  # {params[key].metadata['help']}" if key in params else ""
                lines.append(f"{key} = {_toml_value(value)}{comment}")
        return "\n".join(lines) + "\n"

    def override(self, **flags) -> IspConfig:
        """The config with the CLI's flags applied (``wb``, ``white_level``, ``saturation``,
        ``demosaic``,
        ``demosaic_domain``, ``highlights``, ``tone``, ``tone_exposure``, ``tone_white``,
        ``exposure``, ``baseline_exposure``, ``output_space``, ``dng_matrices``,
        ``transfer``, ``lens``,
        ``focal_length``, ``aperture``, ``lens_correction``); None leaves a value as it is.
        A flag enables its stage (adding it, if missing, where the default order has it);
        ``highlights blend`` moves the stage to just after demosaic, ``reconstruct`` and
        ``unclip`` to just before; ``lens_correction`` ``auto`` enables the lens
        stage, ``off`` disables it (then no other lens flag may be given); ``denoise``
        enables the ``raw_denoise`` stage for a raw method (``profiled``) or the
        ``denoise`` stage for a filter (``gaussian``, ``bilateral``), and disables the
        other (``none``: both). Errors name the flag."""
        tables = self.to_tables()
        asked = dict(self.asked)
        denoise = flags.pop("denoise", None)
        if denoise is not None:
            _choice(DENOISE_CHOICES)(denoise)
            given = [f for f in ("denoise_strength", "noise_profile") if flags.get(f) is not None]
            if denoise not in RAW_DENOISE_METHODS and given:
                flag = "--" + given[0].replace("_", "-")
                raise ParameterError(
                    f"{flag} sets --denoise profiled or learned, not {denoise}; drop one"
                )
            raw_table = _table_of(tables, RawDenoiseStage)
            raw_table["enabled"] = denoise in RAW_DENOISE_METHODS
            rgb_table = _table_of(tables, DenoiseStage)
            rgb_table["enabled"] = denoise in DENOISE_METHODS[1:]
            (raw_table if denoise in RAW_DENOISE_METHODS else rgb_table)["method"] = (
                denoise if denoise != "none" else rgb_table.get("method", "bilateral")
            )
            if denoise != "none":
                stage = RawDenoiseStage if denoise in RAW_DENOISE_METHODS else DenoiseStage
                asked.setdefault(stage.name, f"--denoise {denoise}")
        switch = flags.pop("lens_correction", None)
        if switch is not None:
            _choice(("auto", "off"))(switch)
            given = [f for f in ("lens", "focal_length", "aperture") if flags.get(f) is not None]
            if switch == "off" and given:
                flag = "--" + given[0].replace("_", "-")
                raise ParameterError(f"--lens-correction off: {flag} corrects the lens; drop one")
            table = _table_of(tables, LensCorrectionStage)
            table["enabled"] = switch == "auto"
            if switch == "auto":
                asked.setdefault(LensCorrectionStage.name, "--lens-correction auto")
        for flag, value in flags.items():
            if value is None:
                continue
            stage, key = _FLAGS[flag]
            try:  # in the user's terms: the flag and what they typed
                value = stage.params()[key].metadata["check"](value)
            except ParameterError as err:
                why = str(err).removeprefix(f"{value!r}; ")  # the value is said once
                raise ParameterError(f"--{flag.replace('_', '-')} {value!r}: {why}") from None
            table = _table_of(tables, stage)
            table[key] = value
            table["enabled"] = True
            typed = f"--{flag.replace('_', '-')} {value}"
            asked.setdefault(stage.name, "--half-size" if value == HALF_SIZE else typed)
            if stage is HighlightsStage and value in ("blend", "unclip", "reconstruct"):
                # Blending needs RGB: move the stage to just after demosaic;
                # reconstruction and unclip read the mosaic: just before it.
                tables.remove(table)
                at = next(i for i, t in enumerate(tables) if t["name"] == DemosaicStage.name)
                tables.insert(at + (value in RGB_HIGHLIGHT_MODES), table)
        config = IspConfig.from_tables(tables, "options")
        return replace(config, asked=tuple(asked.items()))

    def with_disabled(self, *kinds: type[Stage]) -> IspConfig:
        """The config with the stages of these types disabled (kept, for the record)."""
        return IspConfig(
            tuple(replace(s, enabled=False) if isinstance(s, kinds) else s for s in self.stages),
            asked=self.asked,
        )

    def asked_as(self, stage: Stage) -> str | None:
        """How the user asked for ``stage`` (enabled), in messages: the flag that set it
        (:attr:`asked`), else ``the config's 'name' stage`` where the config turns it on
        against the default or changes its values; None where it is as by default."""
        flag = dict(self.asked).get(stage.name)
        if flag is not None:
            return flag
        if not stage.on_by_default or stage != type(stage)():
            return f"the config's {stage.name!r} stage"
        return None

    @property
    def enabled(self) -> tuple[Stage, ...]:
        """The enabled stages, in order."""
        return tuple(s for s in self.stages if s.enabled)

    def enabled_stage(self, kind: type[Stage]) -> Stage | None:
        """The enabled stage of this type, or None."""
        return next((s for s in self.stages if s.enabled and isinstance(s, kind)), None)

    def before_demosaic(self, stage: Stage) -> bool:
        """Whether ``stage`` comes before the demosaic: it acts on the mosaic."""
        kinds = [type(s) for s in self.stages]
        return kinds.index(type(stage)) < kinds.index(DemosaicStage)


def _table_of(tables: list[dict], stage: type[Stage]) -> dict:
    """The table of ``stage`` in ``tables``, added (as ``{"name": …}``) where it is
    missing: before the first stage that follows it in the default order."""
    table = next((t for t in tables if t["name"] == stage.name), None)
    if table is None:
        order = list(STAGES)
        later = order[order.index(stage.name) + 1 :]
        at = next((i for i, t in enumerate(tables) if t["name"] in later), len(tables))
        table = {"name": stage.name}
        tables.insert(at, table)
    return table


def _check_order(enabled: tuple[Stage, ...], origin: str) -> None:
    kinds = [type(s) for s in enabled]
    for required in (BlackLevelStage, DemosaicStage):
        if required not in kinds:
            raise ParameterError(f"{origin}: the ISP needs an enabled {required.name!r} stage")
    split = kinds.index(DemosaicStage)
    late = [s.name for s in enabled[split + 1 :] if s.mosaic_only]
    early = [s.name for s in enabled[:split] if s.rgb_only]
    if late or early:
        bad = (late or early)[0]
        where = "before" if late else "after"
        raise ParameterError(f"{origin}: stage {bad!r} must come {where} 'demosaic'")
    if kinds.index(BlackLevelStage) > split:
        raise ParameterError(f"{origin}: 'black_level' must come before 'demosaic'")
    first = kinds.index(BlackLevelStage) + 1
    if RawDenoiseStage in kinds and kinds.index(RawDenoiseStage) != first:
        raise ParameterError(
            f"{origin}: 'raw_denoise' must come right after 'black_level' (the noise model "
            "describes the mosaic as the sensor gave it)"
        )
    if OrientationStage in kinds and kinds[-1] is not OrientationStage:
        raise ParameterError(f"{origin}: 'orientation' must be the last enabled stage")
    for i, stage in enumerate(enabled):
        if isinstance(stage, HighlightsStage) and stage.mode in RGB_HIGHLIGHT_MODES and i < split:
            raise ParameterError(
                f"{origin}: highlights mode {stage.mode!r} needs RGB: put it after 'demosaic'"
            )


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


# ------------------------------------------------------------------ the TOML form
# The same operations on a config's TOML form (a list of stage tables, what the
# sidecar records), for callers that edit configs as data.


def default_config() -> list[dict]:
    """Every stage with its defaults, in the default order, as tables."""
    return IspConfig.default().to_tables()


def validate_config(config: Any, origin: str = "config") -> list[dict]:
    """Check a list of stage tables; fill defaults. Errors say what is valid."""
    return IspConfig.from_tables(config, origin).to_tables()


def load_config(path) -> list[dict]:
    """Read and validate a TOML config file, as tables."""
    return IspConfig.load(path).to_tables()


def load_config_text(text: str, origin: str = "config") -> list[dict]:
    """Validate TOML text, as tables (see :func:`load_config`)."""
    return IspConfig.from_toml(text, origin).to_tables()


def config_to_toml(config: IspConfig | list[dict]) -> str:
    """TOML text for a config (see :meth:`IspConfig.to_toml`)."""
    return IspConfig.of(config).to_toml()


def override(config: IspConfig | list[dict], **flags) -> list[dict]:
    """The CLI's flags applied to a config, as tables (see :meth:`IspConfig.override`)."""
    return IspConfig.of(config).override(**flags).to_tables()


# ------------------------------------------------------------------ one raw
@dataclass(frozen=True)
class ResolvedIsp:
    """A config resolved for one raw: what the torch reference and the engine build from.

    ``stages``: the enabled stages that act on ``raw`` (:meth:`Stage.acts_on`), in
    order. ``info``: ``warnings`` and ``monochrome``, then what the stages took from
    the raw, in stage order, as the sidecar records it: ``white_level`` (DN),
    ``white_balance`` (R, G, B gains) and ``white_balance_source``, ``color_matrix``
    (3 × 3, camera → output), ``exposure_stops``; last ``stages``: one record per
    enabled stage, in order, ``{"name", "ran"}`` and, where it did not run (or changed
    nothing), ``"why"``.
    """

    config: IspConfig
    raw: RawImage
    stages: tuple[Stage, ...]
    info: dict

    @property
    def white_level(self) -> float:
        """The white level used (DN)."""
        return self.info["white_level"]

    @property
    def white_balance(self) -> tuple[float, float, float]:
        """Gains (R, G, B)."""
        return tuple(self.info["white_balance"])

    @property
    def clip_levels(self) -> tuple[float, float, float]:
        """Where each colour (R, G, B) clips after the stages before the highlights:
        its white-balance gain × the share of its span where it saturates
        (:func:`saturation_fractions`), white = 1 before the gains."""
        gains = self.info.get("white_balance", (1.0, 1.0, 1.0))
        sat = saturation_fractions(self.raw, self.info)
        return tuple(float(g * s) for g, s in zip(gains, sat, strict=True))

    @property
    def color_matrix(self) -> np.ndarray:
        """(3, 3) float64 camera → output-space matrix."""
        return np.array(self.info["color_matrix"])

    @property
    def exposure_stops(self) -> float:
        return self.info["exposure_stops"]

    @property
    def tca_on_mosaic(self) -> bool:
        """Whether the lens stage's lateral CA is taken out of the mosaic just before
        the demosaic (:class:`~rawsim.isp.lens.MosaicTca`), so that the demosaic sees
        red and blue where green is, and the lens stage corrects the rest: a Bayer raw
        at full size and a lens with TCA to correct. Elsewhere (X-Trans, whose red and
        blue sites lie on no grid; half size) the lens stage corrects TCA on RGB."""
        lens = self.info.get("lens")
        if lens is None or "tca" not in lens["corrections"]:
            return False
        if self.raw.cfa is None or not self.raw.cfa.is_bayer:
            return False
        demosaic = next((s for s in self.stages if isinstance(s, DemosaicStage)), None)
        return demosaic is not None and demosaic.method != HALF_SIZE

    @property
    def magenta_guard(self) -> np.ndarray | None:
        """The (3, 3) float64 matrix from white-balanced camera RGB to CIE XYZ over the
        D65 white (each row divided by the white's X, Y, Z) that ``reconstruct``'s
        magenta guard (:mod:`rawsim.isp.magenta_guard`) tests hues with, or None where
        there is no guard: it runs on the full-size demosaic of a mosaic that comes
        straight from ``reconstruct`` (the stage just before it; the lens's mosaic
        TCA, which moves no green site, may come between)."""
        kinds = [type(s) for s in self.stages]
        if self.raw.cfa is None or DemosaicStage not in kinds or HighlightsStage not in kinds:
            return None
        at = kinds.index(DemosaicStage)
        highlights = self.stages[kinds.index(HighlightsStage)]
        if kinds.index(HighlightsStage) != at - 1 or highlights.mode != "reconstruct":
            return None
        if self.stages[at].method == HALF_SIZE:
            return None
        return (SRGB_TO_XYZ / XYZ_D65[:, None]) @ camera_to_srgb(self.raw)

    @property
    def rgb_lens(self) -> dict | None:
        """What the lens stage corrects on RGB: ``info["lens"]``, without its TCA where
        :attr:`tca_on_mosaic`; None where no lens is corrected."""
        lens = self.info.get("lens")
        return without_tca(lens).to_dict() if self.tca_on_mosaic else lens


def monochrome(raw: RawImage) -> bool:
    """Grey data: no CFA and one channel (no colour stages)."""
    return raw.cfa is None and raw.data.shape[-1] == 1


def raw_kind(raw: RawImage) -> str:
    """``raw`` as messages name it where it lacks a CFA or colour: ``this monochrome
    raw``, ``this LinearRaw DNG`` (3-channel data from a DNG), ``this full-colour raw``
    (other 3-channel data), else ``this raw``."""
    if monochrome(raw):
        return "this monochrome raw"
    if raw.cfa is None:
        dng = str(raw.path).lower().endswith(".dng")
        return "this LinearRaw DNG" if dng else "this full-colour raw"
    return "this raw"


#: What a stage that cannot act on a raw leaves undone, and what to use instead where
#: there is something (:func:`idle_warning`); other stages: "not applied".
_IDLE_OUTCOMES: dict[type[Stage], str] = {
    RawDenoiseStage: "not denoised (--denoise bilateral smooths its pixels instead)",
    DeadPixelStage: "no pixel corrected",
    AntiAliasingStage: "not blurred",
    WhiteBalanceStage: "no gains applied",
    DemosaicStage: "its pixels hold every colour already",
    ColorMatrixStage: "not converted",
    YCbCrStage: "not converted",
}


def idle_warning(stage: Stage, asked: str, why: str) -> str:
    """The one-line warning for ``stage``, asked for as ``asked`` (a flag, or the
    config's stage), which cannot act on a raw because ``why`` (:meth:`Stage.idle_reason`)::

        --denoise profiled acts on a CFA mosaic; this LinearRaw DNG has none: not
        denoised (--denoise bilateral smooths its pixels instead)
    """
    if isinstance(stage, DemosaicStage) and stage.method == HALF_SIZE:
        outcome = "rendered at full size (--resize scales it down)"
    else:
        outcome = _IDLE_OUTCOMES.get(type(stage), "not applied")
    return f"{asked} {why}: {outcome}"


def resolve(config: IspConfig | list[dict], raw: RawImage) -> ResolvedIsp:
    """``config`` (typed, or its tables) for ``raw``: each stage that acts on it
    records, in order, what it takes from it. An enabled stage that cannot act on
    ``raw`` is left out, recorded in ``info["stages"]`` with why, and warned where the
    user asked for it (:meth:`IspConfig.asked_as`): a stage on by default that cannot
    act (the demosaic of a LinearRaw DNG) is no news."""
    config = IspConfig.of(config)
    info: dict = {"warnings": list(raw.warnings), "monochrome": monochrome(raw)}
    idle = {s.name: s.idle_reason(raw) for s in config.enabled}
    stages = tuple(s for s in config.enabled if idle[s.name] is None)
    for stage in config.enabled:
        asked = config.asked_as(stage)
        if idle[stage.name] is not None and asked is not None:
            info["warnings"].append(idle_warning(stage, asked, idle[stage.name]))
    for stage in stages:
        idle[stage.name] = stage.resolve(raw, config, info)
    info["stages"] = [
        {"name": name, "ran": why is None} | ({} if why is None else {"why": why})
        for name, why in idle.items()
    ]
    return ResolvedIsp(config, raw, stages, info)


def auto_white_balance(raw: RawImage) -> tuple[float, float, float]:
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
        ph, pw = raw.cfa.period
        reps = (-(-h // ph), -(-w // pw))
        black = np.tile(np.asarray(raw.black_level, np.float64).reshape(ph, pw), reps)[:h, :w]
        above = np.maximum(data - black, 0.0)
        colors = np.tile(np.asarray(raw.cfa.colors).reshape(ph, pw), reps)[:h, :w]
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


def black_per_colour(raw: RawImage) -> np.ndarray:
    """(3,) float64: each colour's black level (DN, R, G, B), the mean over its sites
    of one CFA period, or the channels' for 3-channel data."""
    black = np.asarray(raw.black_level, dtype=np.float64)
    if raw.cfa is None:
        return np.resize(black.ravel(), 3)
    colours = np.asarray(raw.cfa.colors).reshape(raw.cfa.period)
    black = np.broadcast_to(black.reshape(-1), (colours.size,)).reshape(colours.shape)
    return np.array([black[colours == c].mean() for c in range(3)])


def _saturation(raw: RawImage, white: float, source: str) -> dict:
    """``info["saturation"]`` (:meth:`BlackLevelStage.resolve`)."""
    if source == "white":
        levels, found = [white] * 3, ["the white level (saturation = white)"] * 3
    else:
        from rawsim.engine.saturation import find_saturation

        colours = None if raw.cfa is None else np.reshape(raw.cfa.colors, raw.cfa.period)
        sat = find_saturation(raw.data, colours, black_per_colour(raw), white)
        levels, found = list(sat.levels), list(sat.notes)
    return {"levels": levels, "found": found}


def saturation_fractions(raw: RawImage, info: dict) -> tuple[float, float, float]:
    """Where each colour saturates as a share of its span, (level − black) / (white −
    black), at most 1 (white = 1 after the levels): from ``info["saturation"]``, 1
    for each colour where there is none."""
    found = info.get("saturation")
    if not found:
        return (1.0, 1.0, 1.0)
    white = float(info["white_level"])
    return tuple(
        float(min((lv - b) / (white - b), 1.0))
        for lv, b in zip(found["levels"], black_per_colour(raw), strict=True)
    )


#: ``ev = "auto"``: the share of pixels allowed to clip (LibRaw's ``auto_bright_thr``),
#: and the most it brightens (stops).
AUTO_CLIP = 0.01
AUTO_MAX_STOPS = 8.0


def auto_exposure_stops(raw: RawImage, info: dict) -> float:
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
    elif raw.cfa.is_bayer:
        h, w = data.shape[0] // 2 * 2, data.shape[1] // 2 * 2
        black = np.broadcast_to(black, (2, 2))
        planes = [(data[i:h:2, j:w:2] - black[i, j]) / span for i, j in raw.cfa.packed_sites]
        rgb = np.stack([planes[0], (planes[1] + planes[2]) / 2, planes[3]], axis=-1)
    else:  # each colour's mean over every whole period of the pattern
        ph, pw = raw.cfa.period
        h, w = data.shape[0] // ph * ph, data.shape[1] // pw * pw
        above = (data[:h, :w] - np.tile(black.reshape(ph, pw), (h // ph, w // pw))) / span
        periods = above.reshape(h // ph, ph, w // pw, pw).transpose(0, 2, 1, 3)
        colors = np.asarray(raw.cfa.colors).reshape(ph, pw)
        rgb = np.stack([periods[:, :, colors == c].mean(axis=2) for c in range(3)], axis=-1)
    rgb = np.maximum(rgb, 0.0)
    if rgb.shape[-1] == 3 and "white_balance" in info:
        rgb = np.minimum(rgb * np.asarray(info["white_balance"], dtype=np.float32), 1.0)
    if rgb.shape[-1] == 3 and "color_matrix" in info:
        rgb = rgb @ np.asarray(info["color_matrix"], dtype=np.float32).T
    top = float(np.percentile(rgb.reshape(-1, rgb.shape[-1]), 100 * (1 - AUTO_CLIP), axis=0).max())
    return float(np.clip(-np.log2(top), 0.0, AUTO_MAX_STOPS)) if top > 0 else AUTO_MAX_STOPS
