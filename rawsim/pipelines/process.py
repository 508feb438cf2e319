"""Processing: a camera raw file → an RGB image file, through the configurable ISP.

Two forms of one ISP: the compiled engine (:mod:`rawsim.engine.process`) renders
on the CPU whenever it covers the config (every stage but dead-pixel
correction, anti-aliasing, the denoise stage's filters and YCbCr, for Bayer
raws; raw denoising first denoises the mosaic, :mod:`rawsim.engine.denoise`);
otherwise, and on CUDA, the torch reference (:mod:`rawsim.isp.pipeline`) does.
The engine path imports no torch (``--denoise learned``'s network aside). Both
build from one :func:`~rawsim.isp.config.resolve` of the typed config for the
raw (white level, white balance, matrix, exposure), so their sidecars are
identical and their pixels agree to rounding
(``tests/test_engine_process.py``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rawsim._version import __version__
from rawsim.colorspaces import Encoding
from rawsim.denoise.noise_model import stage_model
from rawsim.device import resolve_device
from rawsim.errors import ParameterError, RawsimError
from rawsim.io.images import OUTPUT_FORMATS, resize_samples, write_image
from rawsim.io.metadata import Output, PhotoMetadata, embed_jpeg, read_metadata
from rawsim.io.outputs import atomic_outputs
from rawsim.io.raw import RawFacts, RawImage, read_raw
from rawsim.io.readahead import ReadAhead
from rawsim.io.spare import Spare
from rawsim.io.task import Task
from rawsim.io.thumbnail import read_thumbnail
from rawsim.isp.config import (
    HALF_SIZE,
    HIGHLIGHT_TRANSFORM,
    ORIENTATION_OPS,
    TONE_WHITE_RANGE,
    XTRANS_METHOD,
    BlackLevelStage,
    ColorMatrixStage,
    DemosaicStage,
    ExposureStage,
    HighlightsStage,
    IspConfig,
    LensCorrectionStage,
    LensShadingStage,
    OrientationStage,
    RawDenoiseStage,
    ResolvedIsp,
    Stage,
    ToneStage,
    TransferStage,
    WhiteBalanceStage,
    YCbCrStage,
    resolve,
)
from rawsim.isp.curves import TransferSpec, filmic
from rawsim.isp.xtrans_stencils import min_size


@dataclass(frozen=True)
class ProcessOptions:
    """Options of the files job.

    Attributes:
        config: the ISP config (see :mod:`rawsim.isp.config`); its TOML form (a
            list of stage tables) is parsed on construction.
        fmt: output format, one of :data:`FORMATS`: ``dng`` writes the raw's mosaic
            back as a raw (:mod:`rawsim.pipelines.process_dng`).
        bits: 8 or 16 (PNG/TIFF/JPEG), 16 (half) or 32 (float) for EXR, 16 for DNG.
        device: ``cpu``, ``cuda`` or ``auto``.
        strip_metadata: write none of the raw's metadata (EXIF, GPS, XMP) into the
            image, only rawsim's own tags.
        resize: the output's longer side in pixels (scaled down, antialiased;
            renders at half size first when that is still at least as large).
        thumbnail: write the raw's embedded preview (a JPEG) instead of rendering.
        dng: with ``fmt`` ``dng``, the kind of DNG (:data:`DNG_KINDS`): ``mosaic``, the
            CFA mosaic, or ``linear``, demosaicked camera RGB (LinearRaw); None: the
            raw's own kind (mosaic where it has a CFA, else linear).
    """

    config: IspConfig = field(default_factory=IspConfig.default)
    fmt: str = "png"
    bits: int = 8
    device: str = "cpu"
    strip_metadata: bool = False
    resize: int | None = None
    thumbnail: bool = False
    dng: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "config", IspConfig.of(self.config))
        if self.resize is not None and self.resize < 1:
            raise ParameterError(f"resize must be at least 1 pixel, got {self.resize}")
        if self.thumbnail and self.fmt != "jpg":
            raise ParameterError(f"a thumbnail is the raw's embedded JPEG: use jpg, not {self.fmt}")
        asked = [a for a in map(self.config.asked_as, self.config.enabled) if a is not None]
        if self.thumbnail and asked:
            raise ParameterError(
                f"--thumbnail writes the raw's embedded JPEG, not a render: {asked[0]} "
                "does not apply; drop one of them"
            )
        if self.dng is not None and (self.fmt != "dng" or self.dng not in DNG_KINDS):
            raise ParameterError(
                f"--dng {self.dng}: give --format dng, and one of {', '.join(DNG_KINDS)}"
            )
        if self.fmt == "dng":
            self.check_dng()

    def check_dng(self) -> None:
        """Refuse what ``--format dng`` cannot do: the DNG is the raw, for an editor to
        render, so only the stages before the editor's act on it: raw denoising, and
        for the ``linear`` kind the demosaic and lens correction too; a stage that
        shapes a render (white balance, highlights, colour, exposure, tone, transfer,
        …), ``--resize`` and ``--thumbnail`` are refused."""
        if self.resize is not None or self.thumbnail:
            flag = "--resize" if self.resize is not None else "--thumbnail"
            raise ParameterError(f"--format dng writes the whole raw: drop {flag}")
        if self.bits != 16:
            raise ParameterError(f"--format dng writes 16-bit samples, not {self.bits}")
        kept = (RawDenoiseStage,) + (_LINEAR_DNG_STAGES if self.dng == "linear" else ())
        for stage in self.config.enabled:
            asked = self.config.asked_as(stage)
            if asked is not None and not isinstance(stage, kept):
                acts = (
                    "--denoise, --demosaic and --lens-correction act"
                    if self.dng == "linear"
                    else "only --denoise acts"
                )
                raise ParameterError(
                    f"--format dng writes the raw for an editor to render: {asked} shapes "
                    f"a render and does not apply; drop it ({acts} on the raw)"
                )

    def output_suffixes(self) -> dict[str, str]:
        return {"image": FORMATS[self.fmt], "json": ".process.json"}

    def effective_config(self) -> IspConfig:
        """EXR is scene-linear: its renders skip the tone curve, transfer and YCbCr."""
        if self.fmt != "exr":
            return self.config
        return self.config.with_disabled(*EXR_LEAVES_OUT)

    def left_out(self) -> list[tuple[str, str]]:
        """(stage name, one-line warning) for each stage the user asked for
        (:meth:`~rawsim.isp.config.IspConfig.asked_as`) that the output format leaves
        out (:meth:`effective_config`), in order."""
        if self.fmt != "exr":
            return []
        return [
            (
                s.name,
                f"{self.config.asked_as(s)} shapes display-referred output; --format exr "
                "writes scene-linear light: left out (--format tiff --bits 16 keeps it)",
            )
            for s in self.config.enabled
            if isinstance(s, EXR_LEAVES_OUT) and self.config.asked_as(s) is not None
        ]


#: Output formats and their suffixes: the images', and the raw DNG.
FORMATS = {**OUTPUT_FORMATS, "dng": ".dng"}
#: The kinds of ``--format dng``: the CFA mosaic, or demosaicked camera RGB (LinearRaw).
DNG_KINDS = ("mosaic", "linear")
#: The stages that act on a ``linear`` DNG besides raw denoising: the editor renders
#: the rest.
_LINEAR_DNG_STAGES = (DemosaicStage, LensCorrectionStage)
#: The stages an EXR render leaves out: its samples are scene-linear light.
EXR_LEAVES_OUT = (ToneStage, TransferStage, YCbCrStage)


def raw_tensor(raw: RawImage, device):
    """The raw's data as float32 DN, (1, 1, H, W) for a mosaic or (1, 3, H, W)."""
    import torch

    data = torch.from_numpy(raw.data.astype(np.float32)).to(device)
    return data[None, None] if raw.cfa is not None else data.permute(2, 0, 1)[None]


def render(raw: RawImage, config: IspConfig | list[dict], device="cpu"):
    """The torch reference ISP of ``config`` on ``raw``: (1, 3, H, W) and the resolved values."""
    return _render(resolve(config, raw), device)


def _render(resolved: ResolvedIsp, device):
    import torch

    from rawsim.isp.pipeline import isp_for

    isp = isp_for(resolved).to(device)
    with torch.no_grad():
        out = isp(raw_tensor(resolved.raw, device))
    return out, isp.info


# ------------------------------------------------------------------ engine
#: The stages the output table evaluates, after every other pointwise stage.
_TAIL_STAGES = (ToneStage, TransferStage)
#: The highlight modes the engine runs as a pre-pass on the mosaic
#: (:mod:`rawsim.engine.highlights`), not as a pointwise op.
MOSAIC_HIGHLIGHTS = ("reconstruct", "unclip")
#: The engine's smallest Bayer image: every tile's halo must mirror inside the image.
ENGINE_MIN_SIZE = 16


def _engine_min_size(cfa) -> int:
    """The engine's smallest image side for ``cfa``: X-Trans as its reference demosaic."""
    return ENGINE_MIN_SIZE if cfa.is_bayer else min_size(cfa, "icd")


@dataclass
class EnginePlan:
    """A config resolved for one raw into the compiled kernel's arguments."""

    method: str  # the demosaic: a Bayer method, or the X-Trans one it maps to
    pre_ops: np.ndarray
    pre_f: np.ndarray
    post_ops: np.ndarray
    post_f: np.ndarray
    out_mode: int
    lut: np.ndarray
    gamma: float
    orientation: int
    info: dict
    #: The lens stage's lens (:meth:`~rawsim.io.lensfun.LensParams.to_dict`; without
    #: its TCA where ``tca`` takes that out of the mosaic), or None: then the kernel
    #: renders in two passes, the post ops before ``lens_at`` first.
    lens: dict | None = None
    lens_at: int = 0
    #: The raw denoise stage's (gain, offset, strength, learned) (see
    #: :func:`rawsim.engine.denoise.denoise_mosaic`; learned: then refined by
    #: :func:`rawsim.denoise.learned.refine_mosaic`), or None: the kernels render the
    #: mosaic it gives.
    denoise: tuple | None = None
    #: ``highlights reconstruct`` or ``unclip`` on the mosaic: (the mode, the colours'
    #: clip levels, the count of mosaic ops before the stage) for the pre-pass of
    #: :mod:`rawsim.engine.highlights` (:func:`~rawsim.engine.highlights.reconstruct_mosaic`,
    #: :func:`~rawsim.engine.highlights.unclip_mosaic`), or None.
    highlights: tuple | None = None
    #: The lens whose lateral CA :func:`rawsim.engine.lens.correct_mosaic_tca` takes out
    #: of the mosaic before the kernels (:attr:`~rawsim.isp.config.ResolvedIsp.tca_on_mosaic`;
    #: the lens pass then moves every colour as green), or None.
    tca: dict | None = None
    #: ``reconstruct``'s magenta guard: camera → XYZ over the white (3, 3)
    #: (:attr:`~rawsim.isp.config.ResolvedIsp.magenta_guard`), or None; and once the
    #: highlight pre-pass has run, the pixels it looks at
    #: and their rows (:func:`rawsim.engine.highlights.reconstruct_mosaic`'s; None
    #: where none).
    guard: np.ndarray | None = None
    near: tuple | None = None


def _levels_op(ep, stage: BlackLevelStage, r: ResolvedIsp):
    """Black and white − black per slot: the 4 Bayer sites, or for other patterns the
    colours R, G, B (:func:`_black_per_colour`)."""
    black = np.asarray(r.raw.black_level, dtype=np.float64)
    black = black.reshape(4) if r.raw.cfa.is_bayer else _black_per_colour(r.raw)
    if np.allclose(black, black[0]):  # the reference's scalar black level
        divisor = np.full(black.size, np.float32(r.white_level - black[0]))
    else:  # its per-site tile, in float32
        divisor = np.float32(r.white_level) - black.astype(np.float32)
    return ep.OP_LEVELS, [*black, *np.zeros(4 - black.size), *divisor]


def _black_per_colour(raw: RawImage) -> np.ndarray | None:
    """The black level of each colour (R, G, B) of a non-Bayer mosaic, or None when
    sites of one colour differ (the engine keeps one level per colour)."""
    black = np.asarray(raw.black_level, dtype=np.float64).ravel()
    colors = np.asarray(raw.cfa.colors)
    levels = [black[colors == c] for c in range(3)]
    if any(not np.all(v == v[0]) for v in levels):
        return None
    return np.array([v[0] for v in levels])


def _highlights_op(ep, stage: HighlightsStage, r: ResolvedIsp):
    """``clip`` at the least clip level; ``blend`` (RGB): dcraw's, above the least.
    (``unclip`` and ``reconstruct`` are pre-passes on the mosaic: :data:`MOSAIC_HIGHLIGHTS`.)"""
    levels = np.asarray(r.clip_levels, dtype=np.float64)
    if stage.mode == "clip":
        return ep.OP_CLIP, [levels.min()]
    trans = np.array(HIGHLIGHT_TRANSFORM)
    return ep.OP_BLEND, [*trans.ravel(), *np.linalg.inv(trans).ravel(), levels.min()]


@dataclass(frozen=True)
class _EngineOp:
    """A stage's pointwise op in the kernel: where it may run and its (code, numbers)."""

    on_mosaic: bool
    on_rgb: bool
    build: Callable[..., tuple[int, list]]


#: Stage type → its pointwise op (``build(ep, stage, resolved)``). Demosaic, orientation
#: and the tone/transfer table are the kernel's fixed steps; other stages are the
#: reference's only.
_ENGINE_OPS: dict[type[Stage], _EngineOp] = {
    BlackLevelStage: _EngineOp(True, False, _levels_op),
    LensShadingStage: _EngineOp(True, True, lambda ep, s, r: (ep.OP_SHADING, [*s.k, s.strength])),
    WhiteBalanceStage: _EngineOp(True, True, lambda ep, s, r: (ep.OP_WB, r.white_balance)),
    HighlightsStage: _EngineOp(True, True, _highlights_op),
    ColorMatrixStage: _EngineOp(
        False, True, lambda ep, s, r: (ep.OP_MATRIX, r.color_matrix.ravel())
    ),
    ExposureStage: _EngineOp(
        False, True, lambda ep, s, r: (ep.OP_EXPOSURE, [2.0**r.exposure_stops])
    ),
}


def engine_plan(raw: RawImage, config: IspConfig | list[dict], fmt: str) -> EnginePlan | None:
    """The engine's arguments for ``config`` on ``raw``, or None where only the reference can.

    Builds from the same :func:`~rawsim.isp.config.resolve` as
    :func:`rawsim.isp.pipeline.build_isp` (same values, same ``info``).
    """
    return _engine_plan(resolve(config, raw), fmt)


def _engine_plan(resolved: ResolvedIsp, fmt: str) -> EnginePlan | None:
    from rawsim.engine import process as ep

    raw = resolved.raw
    if raw.cfa is None or min(raw.data.shape[:2]) < _engine_min_size(raw.cfa):
        return None  # the torch reference renders these
    if not raw.cfa.is_bayer and _black_per_colour(raw) is None:
        return None
    pre, post = [], []
    tail: list[Stage] = []
    orientation = 1
    method = "bilinear"
    lens, lens_at = None, 0
    denoise = highlights = guard = None
    tca = resolved.info["lens"] if resolved.tca_on_mosaic else None
    for stage in resolved.stages:
        if isinstance(stage, RawDenoiseStage):
            learned = resolved.info["raw_denoise"] == "learned"
            denoise = (*stage_model(resolved), stage.strength, learned)
            continue
        if isinstance(stage, HighlightsStage) and stage.mode in MOSAIC_HIGHLIGHTS:
            codes = [op for op, _ in pre]
            if not resolved.config.before_demosaic(stage) or codes not in (
                [ep.OP_LEVELS],
                [ep.OP_LEVELS, ep.OP_WB],
            ):
                # the pre-pass reads levels and white balance only; unclip after the
                # demosaic (per pixel, as a config may place it) is the reference's
                return None
            highlights = (stage.mode, resolved.clip_levels, len(pre))
            guard = resolved.magenta_guard
            continue
        if isinstance(stage, LensCorrectionStage):
            if tail:
                return None  # after tone/transfer: the reference's order
            lens, lens_at = resolved.rgb_lens, len(post)
            continue
        if isinstance(stage, DemosaicStage):
            bayer = raw.cfa.is_bayer or stage.method == HALF_SIZE
            method = stage.method if bayer else XTRANS_METHOD[stage.method]
            if method != HALF_SIZE and stage.domain == "sqrt":
                pre.append((ep.OP_ROOT, []))  # the kernel interpolates the roots
                post.append((ep.OP_SQUARE, []))
            continue
        if isinstance(stage, OrientationStage):
            orientation = raw.orientation
            continue
        if isinstance(stage, _TAIL_STAGES):
            tail.append(stage)
            continue
        op = _ENGINE_OPS.get(type(stage))
        mosaic = resolved.config.before_demosaic(stage)
        if tail or op is None or not (op.on_mosaic if mosaic else op.on_rgb):
            return None  # a stage the engine lacks, or an RGB stage after tone/transfer
        (pre if mosaic else post).append(op.build(ep, stage, resolved))
    if tail and isinstance(tail[0], ToneStage) and tail[0].exposure:
        # A filmic curve's gain runs before the table, which then keeps f(1) = 1.
        post.append((ep.OP_EXPOSURE, [2.0 ** tail[0].exposure]))
        tail = [replace(tail[0], exposure=0.0), *tail[1:]]
    elif any(isinstance(s, ToneStage) and s.exposure for s in tail):
        return None  # a filmic gain after the transfer: the reference's order
    out_mode, lut, gamma = _output_table(tail, fmt, resolved.info.get("transfer"))
    if out_mode is None:
        return None
    return EnginePlan(
        method,
        *_op_arrays(pre),
        *_op_arrays(post),
        out_mode,
        lut,
        gamma,
        orientation,
        resolved.info,
        lens,
        lens_at,
        denoise,
        highlights,
        tca,
        guard,
    )


def _op_arrays(ops) -> tuple[np.ndarray, np.ndarray]:
    codes = np.array([op for op, _ in ops], dtype=np.int64)
    from rawsim.engine.process import OP_NUMBERS

    numbers = np.zeros((max(len(ops), 1), OP_NUMBERS), dtype=np.float64)
    for k, (_, values) in enumerate(ops):
        numbers[k, : len(values)] = values
    return codes, numbers


def _output_table(tail: list[Stage], fmt: str, transfer: str | None):
    """(mode, table, gamma) for the tone/transfer stages, or Nones.

    The table is tone ∘ transfer on [0, 1] in float64, in the config's order;
    ``transfer`` is the transfer stage's function as resolved (``info["transfer"]``:
    ``auto`` is the output space's own). A power-law transfer (infinite slope at 0:
    ``gamma:G``, Adobe RGB's) must come last and is left to the kernel; the toe
    curves (sRGB, BT.2020, ROMM) are tabulated. EXR output has no tone or transfer
    (see ``effective_config``).
    """
    from rawsim.engine import process as ep

    x = np.linspace(0.0, 1.0, ep.LUT_SIZE)
    if fmt == "exr":
        return (ep.OUT_FLOAT, x.astype(np.float32), 1.0) if not tail else (None,) * 3
    curve = _tail_curve(tail, x, transfer)
    if curve is None:
        return (None,) * 3
    x, gamma = curve
    mode = ep.OUT_GAMMA if gamma != 1.0 else ep.OUT_TABLE
    return mode, x.astype(np.float32), gamma


def _tail_curve(
    tail: list[Stage], x: np.ndarray, transfer: str | None
) -> tuple[np.ndarray, float] | None:
    """Tone and transfer stages on linear values ``x`` in [0, 1]: (values, gamma) with a
    power-law transfer left as its exponent (it must come last; None otherwise).
    ``transfer``: the transfer stage's resolved function (``info["transfer"]``)."""
    gamma = 1.0
    for at, stage in enumerate(tail):
        if isinstance(stage, ToneStage):
            if stage.curve == "smoothstep":
                x = x * x * (3 - 2 * x)
            elif stage.curve != "none":
                x = filmic(x, stage.curve, stage.exposure, stage.white_point)
            continue
        spec = TransferSpec.parse(transfer)
        if spec.curve is not None:  # the torch reference's formula (rawsim.colorspaces)
            x = spec.curve.encode(x)
        elif spec.kind == "gamma":
            if at != len(tail) - 1:
                return None
            gamma = 1.0 / spec.gamma
    return x, gamma


#: The kernel's output of a batch's last file, once written (:func:`release`), for
#: the next file of its size and type to render into (``engine_render(reuse=True)``).
_spare = Spare()
#: Zeros the size of a batch's raw, through which ``reconstruct`` and ``unclip`` rebuild
#: its mosaic in place (they leave it zeros), for the next file's.
_patches = Spare()
#: Zeros for the magenta guard's pixels of a batch's raw (``reconstruct``), left zeros
#: again after its render, for the next file's.
_marks = Spare()


def _zeros(data: np.ndarray) -> np.ndarray:
    """Zeros of ``data``'s shape and dtype: the ones :data:`_patches` kept, else new."""
    return _patches.take((data.shape, data.dtype), lambda: np.zeros(data.shape, data.dtype))


def release(samples: np.ndarray) -> None:
    """Give back samples that :func:`engine_render` returned with ``reuse`` once they
    are written: the next render of that size and type writes over them. Samples
    that are not a kernel's output (8-bit codes, half floats) are not kept."""
    if samples.dtype in (np.uint16, np.float32) and samples.flags.c_contiguous:
        _spare.keep_array(samples)


def engine_render(
    raw: RawImage,
    plan: EnginePlan,
    fmt: str,
    bits: int,
    tile: tuple[int, int] | None = None,
    reuse: bool = False,
) -> np.ndarray:
    """Render ``raw`` with the compiled kernel: (H, W, 3) samples for :func:`write_image`.

    ``tile``: (rows, columns) of the kernel's tiles, even for Bayer, whole periods of
    other patterns (default: the engine's). ``reuse``: render into the array that
    :func:`release` gave back, if it fits (a batch's files, one after another); the
    caller gives the samples back once it no longer needs them, and gives ``raw.data``
    up: ``reconstruct`` and ``unclip`` rebuild the mosaic in place.
    """
    if plan.denoise is not None:
        raw, plan = denoised(raw, plan), replace(plan, denoise=None)
    marks = None
    if plan.highlights is not None:
        from rawsim.engine.highlights import new_marks, reconstruct_mosaic, unclip_mosaic

        mode, levels, at = plan.highlights
        ops, numbers = plan.pre_ops[:at], plan.pre_f[:at]
        # the batch gives the raw up: rebuilt in place, through a patch of zeros kept
        out, patch = (raw.data, _zeros(raw.data)) if reuse else (None, None)
        if mode == "reconstruct":
            guard = plan.guard is not None
            if guard and reuse:  # the guard's pixels marked in zeros kept, as the patch
                shape = raw.data.shape
                marks = _marks.take((shape, "marks"), lambda: new_marks(shape))
            data, numbers, near = reconstruct_mosaic(
                raw.data, raw.cfa, ops, numbers, levels, out, guard, patch, marks
            )
        else:
            data, numbers = unclip_mosaic(
                raw.data, raw.cfa, ops, numbers, levels, out=out, patch=patch
            )
            near = None
        if patch is not None:
            _patches.keep_array(patch)  # left zeros
        pre_f = plan.pre_f.copy()
        pre_f[:at] = numbers
        plan = replace(plan, pre_f=pre_f, highlights=None, near=near)
        raw = replace(raw, data=data)
    if plan.tca is not None:
        from rawsim.engine.lens import correct_mosaic_tca

        data, ops, numbers = correct_mosaic_tca(
            raw.data, raw.cfa.colors, plan.pre_ops, plan.pre_f, plan.tca
        )
        raw, plan = replace(raw, data=data), replace(plan, pre_ops=ops, pre_f=numbers, tca=None)
    samples = _kernels(raw, plan, fmt, bits, tile, reuse)
    if marks is not None:
        from rawsim.engine.highlights import unmark

        unmark(marks)
        _marks.keep((raw.data.shape, "marks"), marks)
    return samples


def denoised(raw: RawImage, plan: EnginePlan) -> RawImage:
    """``raw`` with its (H, W) uint16 mosaic denoised as ``plan.denoise`` says (a new
    array, DN; :func:`rawsim.engine.denoise.denoise_mosaic`, then for ``learned``
    :func:`rawsim.denoise.learned.refine_mosaic`), or ``raw`` itself without it."""
    if plan.denoise is None:
        return raw
    from rawsim.engine.denoise import denoise_mosaic

    black = np.asarray(raw.black_level, np.float64)
    *model, strength, learned = plan.denoise
    white = plan.info["white_level"]
    data = denoise_mosaic(raw.data, raw.cfa, black, white, *model, strength)
    if learned:
        from rawsim.denoise.learned import refine_mosaic

        data = refine_mosaic(raw.data, data, raw.cfa, black, white, *model)
    return replace(raw, data=data)


def _kernels(raw: RawImage, plan: EnginePlan, fmt: str, bits: int, tile, reuse: bool):
    """:func:`engine_render`'s kernels, once the mosaic's pre-passes are done."""
    import numba

    from rawsim.engine import process as ep

    transpose, flip_rows, flip_cols = ORIENTATION_OPS[plan.orientation]
    h, w = raw.data.shape
    half = plan.method == HALF_SIZE
    oh, ow = ((h + 1) // 2, (w + 1) // 2) if half else (h, w)
    shape = (ow, oh, 3) if transpose else (oh, ow, 3)
    # Codes go to uint16 even for 8 bits: one compiled signature fewer to build and cache.
    dtype = np.float32 if plan.out_mode == ep.OUT_FLOAT else np.uint16
    scale = 1.0 if plan.out_mode == ep.OUT_FLOAT else 2.0**bits - 1
    out = _spare.array(shape, dtype) if reuse else np.empty(shape, dtype)
    if plan.lens is not None:
        _render_with_lens(raw, plan, out, scale, tile)
        return _reused(out, fmt, bits, reuse)
    if raw.cfa.is_bayer:
        colors = np.array(raw.cfa.colors, dtype=np.int64)
    else:  # levels and white balance per colour: the table's rows are R, G, B
        colors = np.array([0, 1, 2, 1], dtype=np.int64)
    if (plan.pre_ops == ep.OP_SHADING).any():
        table = np.empty((0, 0), dtype=np.float32)
    else:
        table = ep.mosaic_table(colors, plan.pre_ops, plan.pre_f)
    stages = (plan.pre_ops, plan.pre_f, plan.post_ops, plan.post_f, plan.out_mode, plan.lut)
    guard = (  # the magenta guard's pixels, their rows, its matrix (none: an empty mask)
        (*plan.near, np.ascontiguousarray(plan.guard, dtype=np.float64))
        if plan.near is not None
        else (np.zeros((0, 0), np.uint8), np.zeros(0, np.uint8), np.zeros((3, 3)))
    )
    output = (plan.gamma, scale, np.array([transpose, flip_rows, flip_cols]), out)
    threads = numba.get_num_threads()
    data = np.ascontiguousarray(raw.data)
    if half:
        ph, pw = raw.cfa.period
        cmap = np.array(raw.cfa.colors, dtype=np.int64).reshape(ph, pw)
        classes = np.arange(4).reshape(2, 2) if raw.cfa.is_bayer else cmap
        tile = tile or (ep.TILE_ROWS, ep.TILE_COLS)
        ep.half_kernel(data, classes, cmap, table, *stages, *output, threads, *tile)
    elif raw.cfa.is_bayer:
        from rawsim.learned_demosaic.filters import REACH, site_filters

        method = ep.DEMOSAIC_CODES[plan.method]
        if plan.method == "learned":
            filters = site_filters(raw.cfa)
        else:  # unused; the kernel's one signature
            filters = np.zeros((2, 2, 2, 3, REACH + 1, REACH + 1), np.float32)
        tile = tile or (ep.TILE_ROWS, ep.TILE_COLS)
        kernel = ep.bayer_kernel(method)
        kernel(data, colors, method, filters, table, *guard, *stages, *output, threads, *tile)
    else:
        from rawsim.engine import xtrans

        geo = xtrans.Planes(raw.cfa, plan.method)
        tile = tile or geo.tile_shape()
        rows, cols = geo.index(h, 0, tile[0]), geo.index(w, 1, tile[1])
        ep.periodic_kernel(
            data, rows, cols, geo.args(), table, *guard, *stages, *output, threads, *tile, *geo.halo
        )
    return _reused(out, fmt, bits, reuse)


def _reused(out: np.ndarray, fmt: str, bits: int, reuse: bool) -> np.ndarray:
    """:func:`_samples` of ``out``; ``out`` given back at once if they are a copy."""
    samples = _samples(out, fmt, bits)
    if reuse and samples is not out:
        release(out)
    return samples


def _samples(out: np.ndarray, fmt: str, bits: int) -> np.ndarray:
    """The kernels' output (uint16 codes or float32) as the samples of ``fmt``/``bits``."""
    if fmt == "exr" and bits == 16:
        return out.astype(np.float16)
    return out.astype(np.uint8) if bits == 8 and out.dtype == np.uint16 else out


def _render_with_lens(raw: RawImage, plan: EnginePlan, out: np.ndarray, scale: float, tile):
    """The engine's two passes for a config that corrects the lens, into ``out``: the
    stages up to the lens stage as linear floats in the raw's orientation, then
    :func:`rawsim.engine.lens.lens_kernel` (the remap, the later RGB stages, the
    output) on them."""
    import numba

    from rawsim.engine import lens as el
    from rawsim.engine import process as ep
    from rawsim.io.lensfun import lens_field

    k = plan.lens_at  # the post ops before the lens stage, and after it
    early = plan.post_ops[:k], plan.post_f[: max(k, 1)]
    late_f = plan.post_f[k:] if len(plan.post_f) > k else np.zeros((1, plan.post_f.shape[1]))
    late = plan.post_ops[k:], late_f
    first = replace(plan, post_ops=early[0], post_f=early[1], out_mode=ep.OUT_FLOAT)
    first = replace(first, orientation=1, lens=None)
    linear = engine_render(raw, first, "exr", 32, tile)
    field = lens_field(plan.lens, *linear.shape[:2])
    orient = np.array(ORIENTATION_OPS[plan.orientation])
    tile = tile or (ep.TILE_ROWS, ep.TILE_COLS)
    el.lens_kernel(
        linear,
        *el.field_args(field),
        el.PADDING_CODES["zeros"],
        *late,
        plan.out_mode,
        plan.lut,
        plan.gamma,
        scale,
        orient,
        out,
        numba.get_num_threads(),
        *tile,
    )


def use_engine(device: str) -> bool:
    """Whether to render with the compiled engine (CPU, numba, not disabled by RAWSIM_ENGINE=0)."""
    from rawsim import engine

    return device == "cpu" and engine.available() and os.environ.get("RAWSIM_ENGINE", "1") != "0"


#: Stages the float path leaves to the torch reference after the engine's linear output.
_FLOAT_TAIL = (ToneStage, TransferStage, YCbCrStage)


def render_float(raw: RawImage, config: IspConfig | list[dict], device="cpu"):
    """``raw`` rendered to unquantised floats, (1, C, H, W), and the resolved values: what
    :func:`render` gives, without gradients.

    On the CPU the engine renders the stages up to tone/transfer (float32, unclipped,
    within 1e-5 of the reference) and the reference's own modules apply the rest,
    so curves are exact outside [0, 1] too. Elsewhere, or for a config the engine
    lacks, the reference renders it all.
    """
    import torch

    from rawsim.isp.pipeline import isp_for

    resolved = resolve(config, raw)
    stages = resolved.stages
    at = next((i for i, s in enumerate(stages) if isinstance(s, _FLOAT_TAIL)), len(stages))
    head, tail = replace(resolved, stages=stages[:at]), replace(resolved, stages=stages[at:])
    plan = _engine_plan(head, "exr") if use_engine(str(device)) else None
    if plan is None:
        return _render(resolved, device)
    linear = engine_render(raw, plan, "exr", 32)
    image = torch.from_numpy(linear).permute(2, 0, 1).unsqueeze(0)
    with torch.no_grad():  # orientation is in the engine's part or in the tail, not both
        out = isp_for(tail)(image)
    return out, plan.info


def render_samples(
    raw: RawImage,
    config: IspConfig | list[dict],
    fmt: str,
    bits: int,
    device="cpu",
    reuse: bool = False,
):
    """``raw`` rendered to (H, W, 3) samples for ``fmt``/``bits``, and the resolved
    values. ``reuse``: as :func:`engine_render`'s (the caller gives the samples back
    with :func:`release`)."""
    from rawsim.io.images import to_samples

    resolved = resolve(config, raw)
    plan = _engine_plan(resolved, fmt) if use_engine(str(device)) else None
    if plan is not None:
        return engine_render(raw, plan, fmt, bits, reuse=reuse), plan.info
    rgb, info = _render(resolved, device)
    return to_samples(rgb[0], fmt, bits), info


#: Reads the next file of a batch while this one renders (:func:`read_ahead`).
_reader = ReadAhead()
#: The raw samples of a batch's last file, once rendered, for a later raw of the same
#: size to be copied out of LibRaw into (:func:`~rawsim.io.raw.read_raw`).
_raws = Spare()


def read_ahead(task: Task, options: ProcessOptions) -> None:
    """Begin reading ``task``'s raw in a thread, for the :func:`process_file` call that
    follows this one's (a batch's next file): LibRaw decodes while the engine renders
    and the writer writes the file before."""
    if not options.thumbnail:
        _reader.start(task.source, read_raw, task.source, _raws)


def _read_while_loading_engine(path: Path, device) -> RawImage:
    """:func:`read_raw` of ``path``: read ahead already (:func:`read_ahead`), or now,
    in the reader thread while this process loads the engine the first time.

    A cold process spends about 0.4 s in numba's start-up (its import, its target
    initialisation and the cached kernels' load); LibRaw releases the GIL while
    it decodes, so the two overlap.
    """
    import sys

    if "rawsim.engine.process" not in sys.modules and use_engine(str(device)):
        from rawsim.engine import process as ep

        _reader.start(path, read_raw, path, _raws)
        ep.load()
    return _reader.take(path, read_raw, path, _raws)


def describe(raw: RawImage | RawFacts, config: IspConfig | list[dict]) -> dict:
    """What rawsim read from ``raw`` and what ``config`` will use on it (``rawsim info``):
    camera, ``renderable`` (true), CFA, levels, where each colour saturates and how
    that was found, the camera's and daylight multipliers,
    the white balance and matrix it will apply with where they come from,
    orientation, ISO, the DNG BaselineExposure and whether it is applied, the noise
    model ``--denoise profiled`` takes (:mod:`rawsim.denoise.noise_model`), the
    camera database's profile of the camera (:mod:`rawsim.cameras`, None if it has
    none), and the photo metadata (lens, exposure, time, GPS, …) that renders carry.

    For a raw rawsim cannot render (the :class:`~rawsim.io.raw.RawFacts` of an
    :class:`~rawsim.io.raw.UnrenderableRawError`): what LibRaw read (camera, CFA in
    its colour letters, colours, samples per pixel, size, levels), ``renderable``
    false, the ``reason`` with the way out, and the photo metadata."""
    if isinstance(raw, RawFacts):
        return {**raw.summary(), "metadata": read_metadata(raw.path).summary(), "warnings": []}
    resolved = resolve(config, raw)
    info = resolved.info
    out = {
        "file": raw.path,
        "make": raw.make,
        "model": raw.model,
        "renderable": True,
        "cfa_pattern": None if raw.cfa is None else raw.cfa.pattern,
        "width": int(raw.data.shape[1]),
        "height": int(raw.data.shape[0]),
        "black_level": np.asarray(raw.black_level).tolist(),
        "white_level": raw.white_level,
        "orientation": raw.orientation,
        "iso": raw.iso,
    }
    if "white_level" in info:
        out["white_level_used"] = info["white_level"]
    if info.get("saturation"):
        out["saturation"] = info["saturation"]
    exposure = resolved.config.enabled_stage(ExposureStage)
    out["baseline_exposure"] = raw.baseline_exposure
    out["baseline_exposure_applied"] = bool(
        exposure is not None and exposure.baseline == "apply" and exposure.ev != "auto"
    )
    if not info["monochrome"]:
        out["camera_multipliers"] = raw.camera_wb_note
        out["daylight_white_balance"] = raw.daylight_wb
        if "white_balance" in info:
            out["white_balance"] = info["white_balance"]
            out["white_balance_source"] = info["white_balance_source"]
        if "color_matrix" in info:
            out["color_matrix"] = np.round(resolved.color_matrix, 6).tolist()
            out["matrix_source"] = raw.matrix_source
            if "dng_matrices" in info:
                out["dng_matrices"] = info["dng_matrices"]
    if raw.cfa is not None:
        out["noise_model"] = info.get("noise_model") or _noise_model_record(raw)
        out["unprocess_profile"] = _camera_profile(raw)
    out["metadata"] = read_metadata(raw.path).summary()
    out["warnings"] = info["warnings"]
    return out


def _camera_profile(raw: RawImage) -> dict:
    """The profile ``unprocess --profile "MAKE MODEL"`` takes for the raw's camera (its
    name and whether its noise is measured or estimated), or None when the camera
    database does not hold it."""
    from rawsim import cameras

    cam = cameras.find_camera(raw.make, raw.model)
    if cam is None:
        return None
    return {"name": cam.bundled or cam.name, "camera": cam.label, "noise": cam.noise_kind}


def _noise_model_record(raw: RawImage) -> dict:
    """The noise model ``--denoise profiled`` would take by default (its record), or why
    there is none."""
    from rawsim.denoise.noise_model import noise_model_for
    from rawsim.errors import RawsimError

    try:
        return noise_model_for(raw).to_dict()
    except RawsimError as err:
        return {"source": "none", "detail": str(err)}


#: A render whose 99th percentile is below this share of full scale (linear) is dark.
DARK_RENDER = 1 / 8


def _warn_if_dark(samples: np.ndarray, bits: int, config: IspConfig, info: dict) -> None:
    """Add a warning to ``info`` when the render's 99th percentile (brightest channel, on
    the rows :func:`_sample_rows` takes) is below ``DARK_RENDER`` of full scale in linear light,
    i.e. below that level through the config's tone and transfer."""
    tail = [s for s in config.enabled if isinstance(s, _TAIL_STAGES)]
    curve = _tail_curve(tail, np.array([DARK_RENDER]), info.get("transfer"))
    if curve is None:
        return
    level = float(curve[0][0]) ** curve[1]
    sub = _sample_rows(samples)  # channel by channel: no copy of the strided rows
    full = 2.0**bits - 1
    if not any(_percentile_reaches(sub[..., c], full, level) for c in range(sub.shape[-1])):
        info["warnings"].append(
            f"dark render: its 99th percentile is below {DARK_RENDER:.3g} of full scale in "
            "linear light; --exposure auto brightens it (as LibRaw's auto-brightness)"
        )


#: A render with more than this share of its samples at or above ``BLOWN_LEVEL`` of full
#: scale (in code values: 250 of 255) is blown.
BLOWN_SHARE = 0.2
BLOWN_LEVEL = 250 / 255


def _warn_if_blown(samples: np.ndarray, bits: int, raw: RawImage, config: IspConfig, info: dict):
    """Add a warning to ``info`` when more than ``BLOWN_SHARE`` of the render's samples
    (on the rows :func:`_sample_rows` takes) reach ``BLOWN_LEVEL`` of full scale, naming
    what brightened it: the DNG's BaselineExposure where it was applied, and --exposure."""
    sub = _sample_rows(samples)
    full = 2.0**bits - 1
    at = int(np.ceil(BLOWN_LEVEL * full)) if sub.dtype.kind in "ui" else BLOWN_LEVEL * full
    share = float(np.count_nonzero(sub >= at)) / max(sub.size, 1)
    if share <= BLOWN_SHARE:
        return
    exposure = config.enabled_stage(ExposureStage)
    why = []
    if exposure is not None and exposure.baseline == "apply" and raw.baseline_exposure > 0:
        why.append(
            f"the DNG's BaselineExposure of {raw.baseline_exposure:+.2f} EV is applied "
            "(--baseline-exposure ignore leaves it out, as LibRaw does)"
        )
        tone = config.enabled_stage(ToneStage)
        if tone is None or tone.curve == "none":
            why.append(_kept_highlights_hint(raw.baseline_exposure))
    stops = info.get("exposure_stops", 0.0)
    why.append(f"--exposure sets the brightness (now {stops:+.2f} EV in all; lower keeps more)")
    info["warnings"].append(
        f"blown render: {100 * share:.0f} % of its samples are at or above "
        f"{BLOWN_LEVEL * 255:.0f}/255 of full scale; " + "; ".join(why)
    )


def _kept_highlights_hint(stops: float) -> str:
    """How to brighten as a BaselineExposure of ``stops`` > 0 does and keep the highlights.

    Reinhard's curve of white point W, f(x) = g(W·x) with g(W) = 1, lifts the shadows
    by W (its slope at 0), mid-grey by a quarter stop less, and maps the sensor's
    white to display white: with W = 2^stops it stands in for the baseline gain,
    which clips every value above 2^-stops of white (as the DNG SDK's render does)."""
    white = min(2.0**stops, TONE_WHITE_RANGE[1])
    return (
        f"--baseline-exposure ignore --tone reinhard --tone-white {white:.3g} lifts the "
        f"shadows {np.log2(white):.2f} EV and keeps the sensor's white at display white"
    )


def _sample_rows(samples: np.ndarray) -> np.ndarray:
    """The rows of an (H, W, C) render that its warnings' statistics read: every 16th
    (1.5 M samples of a 24 MP render), fewer apart below 4096 rows, keeping at least
    256 (all of a small render). Whole rows, read in order: 2.3 ms for both warnings
    on a 24 MP render against 12 ms for every 4th row and column (which reads every
    cache line of those rows)."""
    step = max(1, min(16, samples.shape[0] // 256))
    return samples[::step]


def _percentile_reaches(x: np.ndarray, full: float, level: float) -> bool:
    """Whether ``np.percentile(x, 99) / full >= level``, found for integer codes by
    counting the codes at or above the level (about 5× faster than the partition)
    where that settles it: the percentile lies between two order statistics, and
    only when the level falls between those two is it computed."""
    if x.dtype.kind not in "ui":
        return float(np.percentile(x, 99)) / full >= level
    first = max(0, int(np.ceil(level * full)) - 1)  # the smallest code at the level
    while first / full < level:
        first += 1
    above = int(np.count_nonzero(x >= first))  # sorted, x[k] reaches it from n - above
    n = x.size
    lo = int(np.floor(0.99 * (n - 1)))
    hi = min(n - 1, lo + 1)
    if lo >= n - above:
        return True
    if hi < n - above:
        return False
    return float(np.percentile(x, 99)) / full >= level


def output_encoding(config: IspConfig, info: dict) -> Encoding | None:
    """What a render's samples are, for the file's colour tags: the config's output
    space with the transfer used (``info["transfer"]``; linear light without a
    transfer stage, as in EXR). None, for no tags, where the samples have no fixed
    colorimetry: camera RGB (no colour matrix, or ``output_space = "camera"``) or
    YCbCr."""
    matrix = config.enabled_stage(ColorMatrixStage)
    if matrix is None or matrix.output_space == "camera" or config.enabled_stage(YCbCrStage):
        return None
    return Encoding(matrix.output_space, info.get("transfer", "linear"))


def process_file(task: Task, options: ProcessOptions) -> dict:
    """Render one raw file to ``task.outputs["image"]`` and its sidecar JSON."""
    if options.fmt not in FORMATS:
        raise ParameterError(f"unknown format {options.fmt!r}; valid: {', '.join(FORMATS)}")
    if options.fmt == "dng":
        return _process_dng(task, options)
    if options.thumbnail:
        return _write_thumbnail(task, options)
    config = options.effective_config()
    device = resolve_device(options.device)
    raw = _read_while_loading_engine(task.source, device)
    photo = PhotoMetadata() if options.strip_metadata else read_metadata(task.source)
    config = _preview_config(config, raw, options.resize)
    samples, info = render_samples(raw, config, options.fmt, options.bits, device, reuse=True)
    for name, warning in options.left_out():
        info["warnings"].append(warning)
        info["stages"].append({"name": name, "ran": False, "why": "--format exr is scene-linear"})
    rendered = samples
    if options.resize:
        samples = resize_samples(samples, options.resize)
    height, width = samples.shape[:2]
    exposure = config.enabled_stage(ExposureStage)
    if options.fmt != "exr" and (exposure is None or exposure.ev != "auto"):
        _warn_if_dark(samples, options.bits, config, info)
    if options.fmt != "exr":
        _warn_if_blown(samples, options.bits, raw, config, info)
    color = output_encoding(config, info)
    meta = {
        "rawsim_version": __version__,
        "input": task.key,
        "camera": {"make": raw.make, "model": raw.model},
        "cfa_pattern": None if raw.cfa is None else raw.cfa.pattern,
        "black_level": np.asarray(raw.black_level).tolist(),
        "white_level": raw.white_level,  # the file's; info's "white_level" is the one used
        "matrix_source": raw.matrix_source,
        "iso": raw.iso,
        "orientation": raw.orientation,
        "width": width,
        "height": height,
        "format": options.fmt,
        "bits": options.bits,
        "resize": options.resize,
        "config": config.to_tables(),
        "config_toml": config.to_toml(),
        **{k: v for k, v in info.items() if k != "white_level"},
        "white_level_used": info.get("white_level", raw.white_level),
    }
    if color is not None and color.space.startswith("aces"):
        meta["aces"] = {
            "idt": meta.pop("aces_idt", None),
            "container": "SMPTE ST 2065-4"
            if color.space == "aces2065-1" and options.fmt == "exr" and options.bits == 16
            else None,
        }
    with atomic_outputs(task.outputs) as tmp:
        software = {"Software": f"rawsim {__version__}"}
        write_image(tmp["image"], samples, options.fmt, color, software, photo)
        tmp["json"].write_text(json.dumps(meta, indent=2) + "\n")
    release(rendered)
    _raws.keep_array(raw.data)
    return meta


process_file.read_ahead = read_ahead  # type: ignore[attr-defined]


def _process_dng(task: Task, options: ProcessOptions) -> dict:
    """``process_file`` for ``--format dng``: ``task``'s raw, its mosaic denoised where
    the config asks (:func:`denoised`, on the engine), written back as a raw
    (:func:`rawsim.pipelines.process_dng.write_dng_of`): the mosaic, or for the
    ``linear`` kind camera RGB (:func:`_camera_rgb`)."""
    from rawsim.pipelines.process_dng import write_dng_of

    raw = _read_while_loading_engine(task.source, "cpu")
    kind = options.dng or ("mosaic" if raw.cfa is not None else "linear")
    if raw.data.ndim == 3 and raw.data.shape[2] != 3:
        raise RawsimError(
            f"{task.source}: a monochrome raw has no colour for a DNG's colour tags; "
            "render it with --format tiff --bits 16"
        )
    if kind == "mosaic" and raw.cfa is None:
        raise RawsimError(
            f"{task.source}: a LinearRaw raw holds no CFA mosaic; --dng linear writes "
            "its camera RGB (the default for it)"
        )
    resolved = resolve(options.config, raw)
    out = raw
    if resolved.info.get("raw_denoise") not in (None, "none") and raw.cfa is not None:
        plan = _engine_plan(resolved, "tiff")
        if plan is None:
            raise RawsimError(
                f"{task.source}: too small for the compiled engine's denoiser "
                f"({raw.data.shape[1]} × {raw.data.shape[0]}); drop --denoise"
            )
        out = denoised(raw, plan)
    rgb = _camera_rgb(out, options.config) if kind == "linear" else None
    meta = write_dng_of(task, options, raw, out, resolved.info, _dng_preview(out), rgb)
    if rgb is not None:
        release(rgb[0])
    _raws.keep_array(raw.data)
    return meta


def _camera_rgb(raw: RawImage, config: IspConfig) -> tuple[np.ndarray, dict]:
    """``raw`` demosaicked into camera RGB for a LinearRaw DNG: (H, W, 3) uint16, black 0,
    white 65535 (the raw's white level), and what was done (the render's record).

    A mosaic is white-balanced for the demosaic (its colour differences need it) and
    the balance taken out after: the samples are the camera's own, as the DNG says
    (the editor balances them by AsShotNeutral). Nothing is clipped before (no
    highlights stage), so a clipped colour stays at the white level; the lens
    correction runs where ``config`` asks. A raw without a CFA is its own camera RGB,
    scaled by its levels."""
    if raw.cfa is None:
        black = np.asarray(raw.black_level, np.float32).reshape(1, 1, -1)
        linear = raw.data.astype(np.float32) - black
        return _codes(linear, np.float32(65535) / (np.float32(raw.white_level) - black)), {}
    linear_config = config.override(output_space="camera").with_disabled(
        RawDenoiseStage,  # ``raw`` is denoised already
        HighlightsStage,
        ExposureStage,
        ToneStage,
        TransferStage,
        YCbCrStage,
        OrientationStage,
    )
    samples, info = render_samples(raw, linear_config, "exr", 32, reuse=True)
    scale = np.float32(65535) / np.asarray(info["white_balance"], np.float32)
    codes = _codes(samples, scale)
    release(samples)
    return codes, {"stages": info["stages"]}


def _codes(linear: np.ndarray, scale) -> np.ndarray:
    """Linear values (white = 1 / ``scale`` per channel, or one number) as uint16 codes,
    0–65535, rounded, in an array the batch keeps (:func:`release` it once written);
    ``linear`` (float32) is overwritten."""
    np.multiply(linear, scale, out=linear)
    np.clip(linear, 0, 65535, out=linear)
    np.rint(linear, out=linear)
    codes = _spare.array(linear.shape, np.uint16)
    np.copyto(codes, linear, casting="unsafe")
    return codes


#: The longer side (pixels) of the preview a ``--format dng`` file embeds, at most.
DNG_PREVIEW = 1024


def _dng_preview(raw: RawImage) -> np.ndarray:
    """The default render of ``raw`` at half size with clipped highlights (their
    rebuild would cost more than the render at this size), unrotated, scaled down by the least
    whole factor k that brings its longer side to :data:`DNG_PREVIEW` pixels or fewer
    (the mean of each k × k block, in the 8-bit codes; the last partial blocks are
    left out): (h, w, 3) uint8 sRGB. A whole factor because an antialiased resize
    (:func:`~rawsim.io.images.resize_samples`) of 24 MP takes 0.37 s, the render
    itself 0.08 s."""
    config = IspConfig.default().override(demosaic=HALF_SIZE, highlights="clip")
    samples, _ = render_samples(raw, config.with_disabled(OrientationStage), "png", 8)
    h, w, c = samples.shape
    k = -(-max(h, w) // DNG_PREVIEW)
    if k == 1:
        return samples
    blocks = samples[: h // k * k, : w // k * k].reshape(h // k, k, w // k, k, c)
    return np.rint(blocks.mean((1, 3), dtype=np.float32)).astype(np.uint8)


def _preview_config(config: IspConfig, raw: RawImage, resize: int | None) -> IspConfig:
    """``config``, rendering at half size when the output is to be scaled down to at
    most half the raw's longer side anyway (a mosaic, not already half size)."""
    demosaic = config.enabled_stage(DemosaicStage)
    if resize is None or raw.cfa is None or demosaic is None or demosaic.method == HALF_SIZE:
        return config
    return config.override(demosaic=HALF_SIZE) if 2 * resize <= max(raw.data.shape) else config


def _write_thumbnail(task: Task, options: ProcessOptions) -> dict:
    """``process_file`` for ``thumbnail``: the raw's embedded preview, its JPEG bytes
    as they are (decoded and encoded again only to resize it, or when it is a bitmap),
    with the raw's metadata and orientation; and the sidecar."""
    import OpenImageIO as oiio

    thumb = read_thumbnail(task.source)  # LibRaw first: it refuses what is no raw
    photo = PhotoMetadata() if options.strip_metadata else read_metadata(task.source)
    software = f"rawsim {__version__}"
    with atomic_outputs(task.outputs) as tmp:
        path = tmp["image"]
        if thumb.jpeg is not None:
            Path(path).write_bytes(thumb.jpeg)
        if thumb.jpeg is None or options.resize:
            pixels = thumb.bitmap if thumb.jpeg is None else oiio.ImageBuf(str(path)).get_pixels()
            pixels = resize_samples(pixels, options.resize) if options.resize else pixels
            write_image(path, np.ascontiguousarray(pixels, dtype=np.uint8), "jpg")
        spec = oiio.ImageInput.open(str(path)).spec()
        output = Output(software, "jpg", spec.width, spec.height, True, thumb.orientation)
        embed_jpeg(path, photo, output)
        meta = {
            "rawsim_version": __version__,
            "input": task.key,
            "thumbnail": True,
            "width": spec.width,
            "height": spec.height,
            "orientation": thumb.orientation,
            "format": "jpg",
            "resize": options.resize,
        }
        tmp["json"].write_text(json.dumps(meta, indent=2) + "\n")
    return meta
