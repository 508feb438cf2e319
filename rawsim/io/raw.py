"""Reading camera raw files with rawpy (LibRaw) into a :class:`RawImage`.

Everything is copied out of LibRaw before the file closes. The quirks seen on
real files are handled here, the way LibRaw handles them:

* colour matrices: ``rgb_xyz_matrix`` when set (LibRaw's table for the camera), else
  a DNG's own ColorMatrix (the one LibRaw renders it with:
  :meth:`rawsim.io.dng_colour.DngColour.chosen`),
  else LibRaw's ``color_matrix`` (camera → sRGB), else the matrix LibRaw has built in
  for the camera, measured through LibRaw (:func:`_measured_rgb_cam`), else the
  identity (warned); ``RawImage.matrix_source`` says which;
* white balance: the camera's multipliers where LibRaw would use them, else
  what LibRaw falls back to (``RawImage.camera_wb_fallback``, applied by the
  ISP's :meth:`~rawsim.isp.config.WhiteBalanceStage.resolve`);
* files without a CFA (LinearRaw DNGs): read as 3-channel linear data and
  rendered without demosaicking;
* monochrome files (one colour, no filter): read as (H, W, 1) grey data and
  rendered without demosaicking or colour stages;
* mosaics of any periodic R/G/B pattern (2×2 Bayer, 6×6 X-Trans): read with
  their CFA and per-site black levels. A DNG whose CFA LibRaw misreads (it holds
  2×2, 8×2 and 6×6 layouts: a 3×3 or 2×4 pattern comes out scrambled) is read
  with the file's own CFAPattern, warned.

What rawsim cannot render is refused with :class:`UnrenderableRawError`, one
line naming the file, the camera, the reason and the way out, carrying the
:class:`RawFacts` that were read (``rawsim info`` shows them): filters of other
colours (CMYG, RGBE, RGBW, a mosaic without one of R, G, B), raws LibRaw gives
as full images of another number of colours (a 4-sample LinearRaw), layouts
LibRaw describes in ways rawpy cannot pass on (Fujifilm SuperCCD's 45° rows,
unknown filter codes), images too small for their CFA and unusable levels.
A Sigma X3F (Foveon) file that this LibRaw cannot decode is named as such.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rawsim.cfa import CFA
from rawsim.color import xyz_to_camera_from_ccm
from rawsim.errors import ParameterError, UnsupportedInputError
from rawsim.io.clibs import collected_stderr, openable_name
from rawsim.io.dng_colour import DngColour, libraw_matrix, read_dng_colour
from rawsim.io.spare import Spare

# LibRaw's flip code → EXIF/TIFF orientation.
_FLIP_TO_ORIENTATION = {0: 1, 3: 3, 5: 8, 6: 6}


@dataclass(frozen=True)
class RawImage:
    """A camera raw, decoded.

    Attributes:
        data: (H, W) mosaic in DN for a CFA sensor, or (H, W, C) linear data when
            the file has no CFA (``cfa`` is None): C = 3, or 1 for a monochrome
            sensor. uint16.
        cfa: the CFA pattern (any periodic R/G/B layout), None for 3-channel or
            monochrome data.
        black_level: (ph, pw) black per site of one CFA period (DN; 2×2 Bayer, 6×6
            X-Trans), or (C,) per channel.
        white_level: saturation level (DN).
        as_shot_wb: camera white-balance gains (R, G, B), G = 1, or None where LibRaw
            would not use the camera's multipliers.
        daylight_wb: daylight gains (R, G, B), G = 1 (LibRaw's starting
            multipliers), or None if unknown.
        xyz_to_camera: (3, 3) D65 XYZ → camera matrix, or None.
        camera_to_srgb: (3, 3) LibRaw's camera → linear sRGB matrix, or None.
        orientation: EXIF orientation 1–8.
        iso: ISO speed (0 if unknown).
        make, model: camera names ("unknown" when the file does not say).
        path: the file.
        warnings: fallbacks taken while reading.
        camera_wb_fallback: what LibRaw uses instead of unusable camera multipliers:
            ``auto``, or ``daylight`` (when only the blue multiplier is missing).
        camera_wb_note: the camera's multipliers as the file gives them, for messages.
        matrix_source: where ``xyz_to_camera`` / ``camera_to_srgb`` come from.
        dng_colour: a DNG's own colour tags (both matrices, for the DNG
            specification's interpolation by white balance), or None.
        baseline_exposure: the DNG BaselineExposure tag (stops), 0 if absent.
    """

    data: np.ndarray
    cfa: CFA | None
    black_level: np.ndarray
    white_level: float
    as_shot_wb: tuple[float, float, float] | None
    daylight_wb: tuple[float, float, float] | None
    xyz_to_camera: np.ndarray | None
    camera_to_srgb: np.ndarray | None
    orientation: int
    iso: float
    make: str
    model: str
    path: str
    warnings: tuple[str, ...] = field(default_factory=tuple)
    baseline_exposure: float = 0.0
    camera_wb_fallback: str = "auto"
    camera_wb_note: str = ""
    matrix_source: str = ""
    dng_colour: DngColour | None = None


#: LibRaw's smallest multiplier taken as set.
_SET = 0.00001


def _multipliers(values) -> tuple[tuple[float, float, float] | None, str]:
    """LibRaw's rule for a file's multipliers (R, G, B, G2): (gains with G = 1, or None
    where LibRaw would not use them; what LibRaw falls back to then).

    LibRaw uses them when R and B are set (> 1e-5); a missing G counts as 1. A first
    multiplier ≤ 1e-5 (−1 "use auto", or 0 "not recorded") means automatic WB;
    R set but B missing keeps the daylight multipliers.
    """
    v = np.nan_to_num(np.asarray(values, dtype=np.float64)[:4], nan=0.0)
    if v[0] > _SET and v[2] > _SET:
        g = v[1] if v[1] > _SET else 1.0
        return (float(v[0] / g), 1.0, float(v[2] / g)), ""
    return None, "auto" if v[0] <= _SET else "daylight"


#: TIFF/EP's CFA colour codes (CFAPattern, CFAPlaneColor), as letters.
_TIFF_EP_LETTERS = "RGBCMYW"
#: The letters' names, for messages (LibRaw's "E" is Sony's emerald).
_COLOUR_NAMES = {
    "R": "red",
    "G": "green",
    "B": "blue",
    "C": "cyan",
    "M": "magenta",
    "Y": "yellow",
    "W": "white",
    "E": "emerald",
}
#: Where to turn for what rawsim does not render.
RENDER_WITH_LIBRAW = "render it with LibRaw instead (dcraw_emu -T, or rawpy's postprocess)"


@dataclass(frozen=True)
class RawFacts:
    """What LibRaw reads from a raw that rawsim cannot render, and why it cannot.

    Attributes:
        path: the file.
        make, model: camera names ("unknown" when the file does not say).
        reason: why rawsim cannot render it, a clause ("its CFA has filters of four
            colours, …").
        remedy: the way out, e.g. :data:`RENDER_WITH_LIBRAW`.
        width, height: the visible image in pixels (None if not read).
        samples: values per pixel: 1 for a mosaic, 3 or 4 for a full image.
        colors: LibRaw's number of colours (``num_colors``).
        color_desc: LibRaw's colour letters (``color_desc``), e.g. "RGBG", "GMCY".
        cfa_pattern: the mosaic's colours, rows of one period joined by ``/`` in
            the colours' letters (C, M, Y, W, E besides R, G, B), or None.
        black_level: LibRaw's black per colour (DN), white_level: its white (DN).
    """

    path: str
    make: str
    model: str
    reason: str
    remedy: str = RENDER_WITH_LIBRAW
    width: int | None = None
    height: int | None = None
    samples: int | None = None
    colors: int | None = None
    color_desc: str | None = None
    cfa_pattern: str | None = None
    black_level: tuple[float, ...] | None = None
    white_level: float | None = None

    @property
    def camera(self) -> str:
        """The camera as messages name it: the make (once) and the model, or
        "unknown camera"."""
        return _camera_text(self.make, self.model)

    @property
    def message(self) -> str:
        """One line: the file, the camera, the reason and the way out."""
        return f"{self.path}: {self.camera}: cannot be rendered: {self.reason}; {self.remedy}"

    def summary(self) -> dict:
        """The facts as ``rawsim info`` shows them (JSON-ready; unread ones left out)."""
        out = {
            "file": self.path,
            "make": self.make,
            "model": self.model,
            "renderable": False,
            "reason": f"{self.reason}; {self.remedy}",
            "cfa_pattern": self.cfa_pattern,
            "colors": self.color_desc[: self.colors] if self.color_desc and self.colors else None,
            "samples_per_pixel": self.samples,
            "width": self.width,
            "height": self.height,
            "black_level": None if self.black_level is None else list(self.black_level),
            "white_level": self.white_level,
        }
        return {k: v for k, v in out.items() if v is not None}


class UnrenderableRawError(UnsupportedInputError):
    """A raw LibRaw reads but rawsim cannot render; ``facts`` holds what was read."""

    def __init__(self, facts: RawFacts) -> None:
        super().__init__(facts.message)
        self.facts = facts

    def __reduce__(self):  # pickled (worker processes) with its facts, not its message
        return type(self), (self.facts,)


def _camera_text(make: str, model: str) -> str:
    if make == "unknown" and model == "unknown":
        return "unknown camera"
    if model.lower().startswith(make.lower()) or make == "unknown":
        return model
    return f"{make} {model}" if model != "unknown" else make


@dataclass(frozen=True)
class _TiffFacts:
    """What a TIFF-based raw's own tags say: the camera, and for a DNG its CFA (the
    raw IFD's CFARepeatPatternDim and CFAPattern as TIFF/EP colour letters) and its
    colour tags (:class:`DngColour`)."""

    make: str = "unknown"
    model: str = "unknown"
    cfa_rows: tuple[str, ...] | None = None
    dng: bool = False
    colour: DngColour | None = None


def _tiff_facts(path: Path) -> _TiffFacts:
    """Make, Model (or UniqueCameraModel) and a DNG's CFA, from TIFF-based raws (DNG,
    CR2, NEF, ARW, …); for other formats the camera as exiv2 reads it; "unknown"
    where neither says."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            tags = tif.pages.first.tags
            make = str(tags["Make"].value).strip() if "Make" in tags else ""
            model = ""
            for key in ("Model", "UniqueCameraModel"):
                if key in tags:
                    model = str(tags[key].value).strip()
                    break
            try:
                cfa_rows = _dng_cfa(tif)
            except Exception:  # a tag we cannot parse: LibRaw's reading stands
                cfa_rows = None
            dng = "DNGVersion" in tags
            try:
                colour = read_dng_colour(tags) if dng else None
            except Exception:  # likewise: LibRaw's matrix stands
                colour = None
            return _TiffFacts(make or "unknown", model or "unknown", cfa_rows, dng, colour)
    except Exception:  # not TIFF-based: rawpy does not expose the names; exiv2 may
        return _TiffFacts(*_exiv2_camera(path))


def _dng_cfa(tif) -> tuple[str, ...] | None:
    """The CFA of a DNG's raw image (the full-size CFA IFD, top level or SubIFD), rows
    of TIFF/EP colour letters; None for other files or codes beyond TIFF/EP's."""
    tags = tif.pages.first.tags
    if "DNGVersion" not in tags:
        return None
    pages = [page for top in tif.pages for page in (top, *(top.pages or ()))]
    for page in pages:
        found = page.tags
        if page.photometric != 32803 or page.subfiletype != 0 or 33422 not in found:
            continue
        rows, cols = (int(v) for v in found[33421].value) if 33421 in found else (2, 2)
        codes = bytes(found[33422].value)
        if rows * cols != len(codes) or max(codes) >= len(_TIFF_EP_LETTERS):
            return None
        letters = "".join(_TIFF_EP_LETTERS[c] for c in codes)
        return tuple(letters[r * cols : (r + 1) * cols] for r in range(rows))
    return None


def _exiv2_camera(path: Path) -> tuple[str, str]:
    """Make and Model as exiv2 reads them (RAF, CR3, ORF, RW2, MRW, …)."""
    from rawsim.io.metadata import read_metadata

    try:
        meta = read_metadata(path)
    except Exception:  # exiv2 failing on an odd file only costs the names
        return "unknown", "unknown"
    return meta.get("Exif.Image.Make") or "unknown", meta.get("Exif.Image.Model") or "unknown"


def _measured_rgb_cam(raw) -> np.ndarray | None:
    """LibRaw's camera → sRGB matrix for a camera it knows no published matrix of
    (rawpy shows none, yet LibRaw applies one of its own), measured through LibRaw.

    The raw data is replaced by four flat fields (grey at 25 % of the range, and
    grey plus 10 % in R, G or B), rendered by LibRaw without white balance in
    linear sRGB, and each matrix column read from its field's centre. Restored
    after. None if LibRaw cannot render it.
    """
    import rawpy

    data = raw.raw_image
    saved = data.copy()
    colors = raw.raw_colors
    black = np.asarray(raw.black_level_per_channel, np.float64)[colors]
    span = float(raw.white_level) - black
    h = data.shape[0]
    fields = np.minimum(np.arange(h) * 4 // h, 3)[:, None]  # 4 bands of rows
    level = black + span * (0.25 + 0.1 * ((colors % 3 == fields) & (colors != 3) & (fields < 3)))
    level += span * 0.1 * ((fields == 1) & (colors == 3))  # G2 is green too
    try:
        data[:] = np.rint(level).astype(data.dtype)
        out = raw.postprocess(
            output_color=rawpy.ColorSpace.sRGB,
            gamma=(1, 1),
            user_wb=[1.0, 1.0, 1.0, 1.0],
            no_auto_bright=True,
            adjust_maximum_thr=0.0,
            output_bps=16,
            half_size=True,
            user_flip=0,
        ).astype(np.float64)
    except Exception:
        return None
    finally:
        data[:] = saved
    n = out.shape[0]
    centres = [out[int((k + 0.5) * n / 4) - 2 : int((k + 0.5) * n / 4) + 2] for k in range(4)]
    means = [c.reshape(-1, 3).mean(axis=0) / 65535.0 for c in centres]
    matrix = np.stack([(means[c] - means[3]) / 0.1 for c in range(3)], axis=1)
    return matrix if np.all(np.isfinite(matrix)) and not np.allclose(matrix, 0) else None


def _baseline_exposure(path: Path) -> float:
    """The DNG BaselineExposure tag (50730) of a TIFF-based raw, in stops; 0 if none."""
    with open(path, "rb") as fh:
        if fh.read(4) not in (b"II*\0", b"MM\0*"):
            return 0.0
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            tag = tif.pages.first.tags.get(50730)
            value = tag.value if tag is not None else 0.0
    except Exception:  # LibRaw read it; a tag we cannot parse counts as absent
        return 0.0
    if isinstance(value, tuple):  # a rational
        value = value[0] / value[1] if value[1] else 0.0
    return float(value) if np.isfinite(value) else 0.0


def _image_hint(path: Path) -> str:
    """``"; it is a PNG image: use 'rawsim unprocess'"`` for an image named as a raw, and
    the way out for a Sigma X3F file this LibRaw cannot decode."""
    from rawsim.io.images import image_format

    with open(path, "rb") as fh:
        head = fh.read(16)
    if head.startswith(b"FOVb"):
        return (
            "; it is a Sigma X3F file (Foveon: stacked colour layers, no CFA): convert it to "
            "DNG with Sigma Photo Pro, or render it with a LibRaw built with X3F support"
        )
    kind = image_format(head)
    if kind is None or kind[0] == "TIFF":  # raws are TIFFs too
        return ""
    return f"; it is a {kind[0]} image: use 'rawsim unprocess'"


def _colour_list(letters) -> str:
    """ "cyan, yellow, green and magenta" for the distinct letters, in order of first use."""
    names = [_COLOUR_NAMES.get(c, repr(c)) for c in dict.fromkeys(letters)]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _matches(rows: tuple[str, ...], sites: np.ndarray) -> bool:
    """Whether the letters ``sites`` (H, W) are the pattern ``rows`` anchored at some
    site of its period (LibRaw may start the visible area on any phase)."""
    ph, pw = len(rows), len(rows[0])
    h, w = sites.shape
    tile = np.array([list(r) for r in rows])
    for dy in range(ph):
        for dx in range(pw):
            shifted = np.roll(tile, (-dy, -dx), axis=(0, 1))
            reps = (-(-h // ph), -(-w // pw))
            if np.array_equal(np.tile(shifted, reps)[:h, :w], sites):
                return True
    return False


def _mosaic_cfa(
    libraw_rows: tuple[str, ...], sites: np.ndarray, dng_rows: tuple[str, ...] | None
) -> tuple[CFA | None, str | None, list[str]]:
    """The CFA to render a mosaic with: (cfa, None, warnings), or (None, reason, []) when
    rawsim cannot render it.

    ``libraw_rows``: LibRaw's pattern in its colour letters (one period from the
    visible area's first site); ``sites``: LibRaw's letters over a window of the
    visible area; ``dng_rows``: a DNG's own CFAPattern (TIFF/EP letters), or None.
    LibRaw holds CFAs as 2×2 … 8×2 or 6×6 layouts: a DNG pattern of another shape
    comes out scrambled, and a three-colour C/M/Y one is named R, G, B.
    """
    warnings: list[str] = []
    rows = libraw_rows
    if dng_rows is not None and not _matches(dng_rows, sites):
        file_letters = set("".join(dng_rows))
        shape = f"{len(dng_rows)}×{len(dng_rows[0])}"
        if file_letters <= set("RGB"):  # LibRaw misread the layout: use the file's
            rows = dng_rows
            warnings.append(
                f"LibRaw reads the DNG's {shape} CFA pattern {'/'.join(dng_rows)} as "
                f"{'/'.join(libraw_rows)}; rendered with the file's pattern"
            )
        elif len(file_letters) == 3 and _same_structure(dng_rows, libraw_rows):
            warnings.append(
                f"the DNG's filters are {_colour_list(''.join(dng_rows))}: rendered as "
                "LibRaw renders them, as the camera's three channels through the file's "
                "colour matrix"
            )
        else:
            return None, _colours_reason(dng_rows, "the DNG's CFAPattern"), []
    if set("".join(rows)) != set("RGB"):
        return None, _colours_reason(rows, "LibRaw's colours"), []
    try:
        return CFA("/".join(rows)), None, warnings
    except ParameterError:  # a 2×2 layout that is not Bayer (greens side by side)
        return (
            None,
            f"its 2×2 CFA {'/'.join(rows)} is not a Bayer layout (the greens are not "
            "diagonal neighbours), and rawsim renders Bayer and other periodic R/G/B mosaics",
            [],
        )


def _same_structure(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    """Whether two patterns of one shape differ only in the names of their colours."""
    if len(a) != len(b) or len(a[0]) != len(b[0]):
        return False
    pairs = set(zip("".join(a), "".join(b), strict=True))
    return len(pairs) == len({x for x, _ in pairs}) == len({y for _, y in pairs})


def _colours_reason(rows: tuple[str, ...], source: str) -> str:
    """Why a mosaic of these colours is not rendered, naming them."""
    letters = "".join(rows)
    pattern = "/".join(rows)
    n = len(set(letters))
    if set(letters) <= set("RGB"):
        missing = _colour_list(c for c in "RGB" if c not in letters)
        return (
            f"its CFA ({pattern}, {source}) has no {missing} site, and rawsim renders "
            "red, green and blue mosaics only"
        )
    return (
        f"its CFA has filters of {n} colours, {_colour_list(letters)} ({pattern}, "
        f"{source}), and rawsim renders red, green and blue mosaics only"
    )


def _visible_colours(raw, pattern: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """``raw.raw_colors_visible[:rows, :cols]``, the colour index of the visible area's
    first sites, without the (H, W) map rawpy builds for it (``np.pad`` of
    ``raw_pattern`` over the whole raw, then the visible window: 20–75 ms for 24 MP,
    in every read): the same values, from the same padding of ``pattern``
    (rawpy pads by its first side on both axes)."""
    s = raw.sizes
    ph, pw = pattern.shape
    size = (s.raw_height - ph + ph, s.raw_width - ph + pw)  # raw_colors' shape
    rows = max(0, min(rows, s.height, size[0] - s.top_margin))
    cols = max(0, min(cols, s.width, size[1] - s.left_margin))
    i = (s.top_margin + np.arange(rows)) % ph
    j = (s.left_margin + np.arange(cols)) % pw
    return pattern[i[:, None], j[None, :]]


def read_raw(path: str | Path, spare: Spare | None = None) -> RawImage:
    """Decode a camera raw with rawpy.

    The visible samples are copied out of LibRaw into the array ``spare`` keeps
    for their shape, if it keeps one (a batch's last raw, given back once
    rendered), else into a new one.

    Raises :class:`UnsupportedInputError` with the reason when LibRaw cannot read
    the file, and its subclass :class:`UnrenderableRawError` (with the
    :class:`RawFacts` read) when rawsim cannot render what LibRaw reads.
    """
    import rawpy

    path = Path(path)
    if not path.is_file():
        raise UnsupportedInputError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise UnsupportedInputError(f"{path}: empty file (0 bytes)")
    tiff = _tiff_facts(path)
    make, model = tiff.make, tiff.model
    warnings: list[str] = []
    libraw_said: list[str] = []
    facts: dict = {}

    def refuse(reason: str, remedy: str = RENDER_WITH_LIBRAW) -> UnrenderableRawError:
        return UnrenderableRawError(RawFacts(str(path), make, model, reason, remedy, **facts))

    try:
        with (
            collected_stderr(libraw_said),
            openable_name(path) as name,
            rawpy.imread(name) as raw,
        ):
            desc = raw.color_desc.decode(errors="replace")
            colors = int(raw.num_colors)
            black = np.asarray(raw.black_level_per_channel, dtype=np.float64)
            white = float(raw.white_level)
            facts.update(
                colors=colors,
                color_desc=desc,
                black_level=tuple(black[: max(colors, 1)].tolist()),
                white_level=white,
            )
            try:
                pattern = raw.raw_pattern
                visible = raw.raw_image_visible
            except (NotImplementedError, RuntimeError) as err:  # rawpy's, not LibRaw's
                raise refuse(
                    f"LibRaw holds its image in a layout that rawpy cannot pass on ({err})"
                ) from None
            sizes = raw.sizes
            samples = 1 if visible.ndim == 2 else int(visible.shape[2])
            facts.update(width=int(sizes.width), height=int(sizes.height), samples=samples)
            if visible.shape[:2] != (sizes.height, sizes.width):
                raise refuse(
                    f"LibRaw's image ({sizes.width}×{sizes.height}) is not a window of its "
                    f"raw data ({sizes.raw_width}×{sizes.raw_height}; e.g. Fujifilm "
                    "SuperCCD's 45° rows, which LibRaw rotates while rendering)"
                )
            mono = colors == 1 and visible.ndim == 2
            cfa = None
            if pattern is not None and not mono:
                # The colours of the visible area's first period (its origin may be
                # anywhere in the pattern), and of a window to check a DNG's against.
                ph, pw = np.asarray(pattern).shape
                sites = _visible_colours(raw, np.asarray(pattern), 4 * ph, 4 * pw)
                pattern = np.array(sites[:ph, :pw], copy=True)
                letter = np.array(list(desc) + ["?"] * 4)
                libraw_rows = tuple("".join(letter[int(i)] for i in row) for row in pattern)
                facts["cfa_pattern"] = "/".join(libraw_rows)
                cfa, reason, notes = _mosaic_cfa(libraw_rows, letter[sites], tiff.cfa_rows)
                if reason is not None:
                    raise refuse(reason)
                warnings += notes
            elif not mono and (visible.ndim != 3 or samples < 3 or colors != 3):
                plural = "s" if samples > 1 else ""
                raise refuse(
                    f"LibRaw gives it as a full image of {samples} sample{plural} per pixel "
                    f"in {colors} colours ({desc[:colors]}), not a mosaic, and rawsim renders "
                    "such images in three colours only"
                )
            data = (Spare() if spare is None else spare).array(visible.shape, np.uint16)
            np.copyto(data, visible, casting="unsafe")
            camera_wb = np.array(raw.camera_whitebalance, dtype=np.float64)
            daylight_wb = np.array(raw.daylight_whitebalance, dtype=np.float64)
            xyz = np.array(raw.rgb_xyz_matrix[:3], dtype=np.float64)
            cam_srgb = np.array(raw.color_matrix[:, :3], dtype=np.float64)
            flip = int(raw.sizes.flip)
            aspect = float(raw.sizes.pixel_aspect)
            iso = float(raw.other.iso_speed)
            measured = None
            no_matrix = np.allclose(xyz, 0) and np.allclose(cam_srgb, 0)
            # Measured on a mosaic only: LibRaw has no raw_colors for other data
            # ("RAW image is not flat", e.g. 3-sample LinearRaw, Kodak C330).
            if no_matrix and colors == 3 and cfa is not None:
                measured = _measured_rgb_cam(raw)
    except UnsupportedInputError:
        raise
    except rawpy.LibRawFileUnsupportedError:
        raise UnsupportedInputError(
            f"{path}: not a raw file LibRaw can read{_image_hint(path)}"
        ) from None
    except (rawpy.LibRawError, OSError) as err:
        reason = "; ".join([" ".join(str(err).strip("b'\"").split()), *libraw_said])
        raise UnsupportedInputError(
            f"{path}: truncated or not a raw file (LibRaw: {reason}){_image_hint(path)}"
        ) from None
    warnings += [f"LibRaw: {line}" for line in libraw_said]
    if abs(aspect - 1) > 1e-3:
        warnings.append(
            f"the pixels are not square (aspect {aspect:g}); LibRaw stretches its render "
            "to square pixels, rawsim does not"
        )

    if mono:
        data = data[:, :, None]
        black_level = black[:1].copy()
    elif cfa is None:
        data = np.ascontiguousarray(data[:, :, :3])
        black_level = black[:3].copy()
        # a linear DNG, or another raw LibRaw gives as full colour (some old Kodaks)
        kind = "a linear DNG" if tiff.dng else "LibRaw gives it as full-colour pixels"
        warnings.append(f"no CFA ({kind}): rendered as 3-channel linear data")
    else:
        h, w = data.shape
        ph, pw = cfa.period
        if h < 2 * ph or w < 2 * pw:
            raise refuse(
                f"its image ({w}×{h}) is smaller than two periods of its "
                f"{ph}×{pw} CFA, too small to demosaic"
            )
        if cfa.is_bayer:  # LibRaw's visible area may start on any site: whole 2×2 tiles
            data = np.ascontiguousarray(data[: h - h % 2, : w - w % 2])
        # per site of one period; a G2 (index 3) has its own black
        site_colour = (
            pattern.astype(int)
            if pattern.shape == cfa.period
            else np.asarray(cfa.colors).reshape(cfa.period)
        )
        black_level = black[site_colour]
    levels = "correct its levels (a DNG's BlackLevel and WhiteLevel tags)"
    if not np.isfinite(white) or not np.isfinite(black_level).all():
        raise refuse("its black or white level is not a number", levels)
    if not white > float(np.max(black_level)):
        raise refuse(f"its white level {white:g} is not above its black level", levels)

    if mono:  # no colour: no matrix, no white balance
        xyz_out = cam_srgb_out = None
        source = "none (monochrome)"
    elif not np.allclose(xyz, 0):
        xyz_out, cam_srgb_out = xyz, None if np.allclose(cam_srgb, 0) else cam_srgb
        source = "LibRaw's table for the camera (rgb_xyz_matrix)"
    elif (dng := libraw_matrix(tiff.colour, cam_srgb)) is not None:
        (xyz_out, source), cam_srgb_out = dng, cam_srgb
    elif not np.allclose(cam_srgb, 0):
        xyz_out, cam_srgb_out = None, cam_srgb
        source = "the file (LibRaw's color_matrix)"
    elif measured is not None and not np.allclose(measured, np.eye(3), rtol=0, atol=1e-3):
        # (≈ the identity: LibRaw has no matrix either and renders camera RGB as sRGB)
        xyz_out, cam_srgb_out = None, measured
        source = "LibRaw's built-in camera matrix (measured through LibRaw)"
    else:
        xyz_out = cam_srgb_out = None
        source = "none: camera RGB treated as sRGB"
        warnings.append("no colour matrix for this camera: camera RGB is treated as sRGB")
    as_shot, fallback = (None, "auto") if mono else _multipliers(camera_wb)
    daylight = None if mono else _multipliers(daylight_wb)[0]
    return RawImage(
        data=data,
        cfa=cfa,
        black_level=black_level,
        white_level=white,
        as_shot_wb=as_shot,
        daylight_wb=daylight,
        xyz_to_camera=xyz_out,
        camera_to_srgb=cam_srgb_out,
        orientation=_FLIP_TO_ORIENTATION.get(flip, 1),
        iso=iso,
        make=make,
        model=model,
        path=str(path),
        warnings=tuple(warnings),
        camera_wb_fallback=fallback,
        camera_wb_note=str(np.round(np.asarray(camera_wb, np.float64)[:4], 4).tolist()),
        matrix_source=source,
        dng_colour=None if mono else tiff.colour,
        baseline_exposure=_baseline_exposure(path),
    )


def xyz_to_camera_of(raw: RawImage) -> tuple[np.ndarray | None, str]:
    """The XYZ → camera matrix a profile of ``raw``'s camera takes, and where it comes
    from: the one ``process`` renders ``raw`` with (:attr:`RawImage.xyz_to_camera`),
    else the XYZ → camera equivalent of its camera → sRGB matrix
    (:func:`~rawsim.color.xyz_to_camera_from_ccm`, rows scaled to its daylight gains as
    LibRaw scales them). (None, why) where ``process`` has no matrix for it."""
    if raw.xyz_to_camera is not None:
        return np.asarray(raw.xyz_to_camera, dtype=np.float64), raw.matrix_source
    if raw.camera_to_srgb is not None:
        m = xyz_to_camera_from_ccm(raw.camera_to_srgb, raw.daylight_wb)
        rows = (
            "its daylight white balance"
            if raw.daylight_wb is not None
            else "equal gains (it gives no daylight white balance)"
        )
        return m, f"{raw.matrix_source}, inverted to XYZ → camera, rows scaled to {rows}"
    return None, raw.matrix_source
