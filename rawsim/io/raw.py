"""Reading camera raw files with rawpy (LibRaw) into a :class:`RawImage`.

Everything is copied out of LibRaw before the file closes. The quirks seen on
real files are handled here, the way LibRaw handles them:

* colour matrices: ``rgb_xyz_matrix`` when set, else LibRaw's ``color_matrix``
  (camera → sRGB), else the matrix LibRaw has built in for the camera, measured
  through LibRaw (:func:`_measured_rgb_cam`), else the identity (warned);
  ``RawImage.matrix_source`` says which;
* white balance: the camera's multipliers where LibRaw would use them, else
  what LibRaw falls back to (``RawImage.camera_wb_fallback``, applied by the
  ISP's :meth:`~rawsim.isp.config.WhiteBalanceStage.resolve`);
* files without a CFA (LinearRaw DNGs): read as 3-channel linear data and
  rendered without demosaicking;
* monochrome files (one colour, no filter): read as (H, W, 1) grey data and
  rendered without demosaicking or colour stages;
* mosaics of any periodic R/G/B pattern (2×2 Bayer, 6×6 X-Trans): read with
  their CFA and per-site black levels; four-colour filters (CMYG, RGBE): refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rawsim.cfa import CFA
from rawsim.errors import ParameterError, UnsupportedInputError
from rawsim.io.clibs import collected_stderr, openable_name

# LibRaw's flip code → EXIF/TIFF orientation.
_FLIP_TO_ORIENTATION = {0: 1, 3: 3, 5: 8, 6: 6}


@dataclass(frozen=True)
class RawImage:
    """A camera raw, decoded.

    Attributes:
        data: (H, W) mosaic in DN for a CFA sensor, or (H, W, C) linear data when
            the file has no CFA (``cfa`` is None): C = 3, or 1 for a monochrome
            sensor. uint16.
        cfa: the Bayer pattern, None for 3-channel or monochrome data.
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


def _camera_names(path: Path) -> tuple[str, str]:
    """Make and Model from TIFF-based raws (DNG, CR2, NEF, ARW, …), else "unknown"."""
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
            return make or "unknown", model or "unknown"
    except Exception:  # not TIFF-based: rawpy does not expose the names
        return "unknown", "unknown"


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
    """``"; it is a PNG image: use 'rawsim unprocess'"`` for an image named as a raw."""
    from rawsim.io.images import image_format

    with open(path, "rb") as fh:
        kind = image_format(fh.read(16))
    if kind is None or kind[0] == "TIFF":  # raws are TIFFs too
        return ""
    return f"; it is a {kind[0]} image: use 'rawsim unprocess'"


def read_raw(path: str | Path) -> RawImage:
    """Decode a camera raw with rawpy. Raises :class:`UnsupportedInputError` with the reason."""
    import rawpy

    path = Path(path)
    if not path.is_file():
        raise UnsupportedInputError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise UnsupportedInputError(f"{path}: empty file (0 bytes)")
    warnings: list[str] = []
    libraw_said: list[str] = []
    try:
        with (
            collected_stderr(libraw_said),
            openable_name(path) as name,
            rawpy.imread(name) as raw,
        ):
            pattern = raw.raw_pattern
            mono = int(raw.num_colors) == 1 and raw.raw_image_visible.ndim == 2
            if mono:
                pattern = None
            if pattern is not None:
                # The colours of the visible area's first period (its origin may be
                # anywhere in the pattern).
                ph, pw = np.asarray(pattern).shape
                pattern = raw.raw_colors_visible[:ph, :pw]
            desc = raw.color_desc.decode(errors="replace")
            visible = raw.raw_image_visible
            data = np.array(visible, dtype=np.uint16, copy=True)
            black = np.asarray(raw.black_level_per_channel, dtype=np.float64)
            white = float(raw.white_level)
            pattern = None if pattern is None else np.array(pattern, copy=True)
            camera_wb = np.array(raw.camera_whitebalance, dtype=np.float64)
            daylight_wb = np.array(raw.daylight_whitebalance, dtype=np.float64)
            xyz = np.array(raw.rgb_xyz_matrix[:3], dtype=np.float64)
            cam_srgb = np.array(raw.color_matrix[:, :3], dtype=np.float64)
            flip = int(raw.sizes.flip)
            iso = float(raw.other.iso_speed)
            colors = int(raw.num_colors)
            measured = None
            no_matrix = np.allclose(xyz, 0) and np.allclose(cam_srgb, 0)
            # Measured on a mosaic only: LibRaw has no raw_colors for other data
            # ("RAW image is not flat", e.g. 3-sample LinearRaw, Kodak C330).
            if no_matrix and colors == 3 and not mono and pattern is not None:
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

    if mono:
        data = data[:, :, None]
        cfa = None
        black_level = black[:1].copy()
    elif pattern is None:
        if data.ndim != 3 or data.shape[2] < 3 or colors != 3:
            raise UnsupportedInputError(f"{path}: no CFA and not 3-channel data")
        data = np.ascontiguousarray(data[:, :, :3])
        cfa = None
        black_level = black[:3].copy()
        warnings.append("no CFA (linear DNG): rendered as 3-channel linear data")
    else:
        if colors != 3 or sorted(set(desc[int(i)] for i in pattern.flatten())) != ["B", "G", "R"]:
            raise UnsupportedInputError(
                f"{path}: colour filter {desc!r} with pattern {pattern.tolist()} is not "
                "an R, G, B mosaic (four-colour filters are not supported)"
            )
        try:
            cfa = CFA.from_rawpy(pattern, desc)
        except ParameterError as err:
            raise UnsupportedInputError(f"{path}: {err}") from None
        h, w = data.shape
        ph, pw = cfa.period
        if h < 2 * ph or w < 2 * pw:
            raise UnsupportedInputError(f"{path}: image is too small ({w}×{h})")
        if cfa.is_bayer:  # LibRaw's visible area may start on any site: whole 2×2 tiles
            data = np.ascontiguousarray(data[: h - h % 2, : w - w % 2])
        black_level = black[pattern.astype(int)]  # per site of one period
    if not np.isfinite(white) or not np.isfinite(black_level).all():
        raise UnsupportedInputError(f"{path}: black or white level is not a number")
    if not white > float(np.max(black_level)):
        raise UnsupportedInputError(f"{path}: white level {white:g} is not above black")

    if mono:  # no colour: no matrix, no white balance
        xyz_out = cam_srgb_out = None
        source = "none (monochrome)"
    elif not np.allclose(xyz, 0):
        xyz_out, cam_srgb_out = xyz, None if np.allclose(cam_srgb, 0) else cam_srgb
        source = "the file's or LibRaw's table (rgb_xyz_matrix)"
    elif not np.allclose(cam_srgb, 0):
        xyz_out, cam_srgb_out = None, cam_srgb
        source = "the file (LibRaw's color_matrix)"
    elif measured is not None:
        xyz_out, cam_srgb_out = None, measured
        source = "LibRaw's built-in camera matrix (measured through LibRaw)"
    else:
        xyz_out = cam_srgb_out = None
        source = "none: camera RGB treated as sRGB"
        warnings.append("no colour matrix for this camera: camera RGB is treated as sRGB")
    as_shot, fallback = (None, "auto") if mono else _multipliers(camera_wb)
    daylight = None if mono else _multipliers(daylight_wb)[0]
    make, model = _camera_names(path)
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
        baseline_exposure=_baseline_exposure(path),
    )
