"""Reading images with OpenImageIO into arrays ready for unprocessing.

Handles 8/16-bit integer files (PNG, JPEG, TIFF, …: display-referred codes) and
float files (EXR half/float, scanline or tiled, Radiance HDR, float TIFF:
scene-linear). Alpha and extra channels are dropped, grey is replicated to RGB,
odd sizes are cropped to even (the crop is reported).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rawsim.colorspaces import SRGB, Encoding
from rawsim.errors import UnsupportedInputError
from rawsim.io.clibs import collected_stderr, openable_name
from rawsim.io.icc import icc_profile
from rawsim.io.metadata import Output, PhotoMetadata, embed_jpeg, exif_block, exr_attributes
from rawsim.io.png import write_png
from rawsim.io.progress import DecodeProgress
from rawsim.io.spare import Spare
from rawsim.io.tiff import write_tiff

#: Extensions picked up when scanning folders (files named explicitly are always tried).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr", ".bmp", ".webp")
#: Camera raw extensions: these go through ``rawsim process``, not here.
RAW_EXTENSIONS = tuple(
    "." + e
    for e in (
        "3fr ari arw bay cap cr2 cr3 crw cs1 dc2 dcr dng drf eip erf fff gpr iiq k25 kdc mdc "
        "mef mos mrw nef nrw orf pef ptx pxn qtk raf raw rw2 rwl rwz sr2 srf srw sti x3f"
    ).split()
)
"""Camera raw extensions (the formats LibRaw reads): these go through ``rawsim process``."""

#: Leading bytes of the image formats read here, with their extensions.
_SIGNATURES = (
    (b"\x89PNG\r\n\x1a\n", "PNG", (".png",)),
    (b"\xff\xd8\xff", "JPEG", (".jpg", ".jpeg")),
    (b"II*\x00", "TIFF", (".tif", ".tiff")),
    (b"MM\x00*", "TIFF", (".tif", ".tiff")),
    (b"v/1\x01", "OpenEXR", (".exr",)),
    (b"#?RADIANCE", "Radiance HDR", (".hdr",)),
    (b"#?RGBE", "Radiance HDR", (".hdr",)),
    (b"BM", "BMP", (".bmp",)),
)


def image_format(head: bytes) -> tuple[str, tuple[str, ...]] | None:
    """(format name, its extensions) of an image by its first 16 bytes, or None."""
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WebP", (".webp",)
    return next(((name, exts) for sig, name, exts in _SIGNATURES if head.startswith(sig)), None)


def sniff(path: Path) -> tuple[str | None, str | None]:
    """What ``path`` holds by its first bytes: (format name or None, a warning or None).

    Raises :class:`UnsupportedInputError` for a camera raw (by any name): a DNG or
    CR2 (TIFF-based, by their tags), or any file of no image format that LibRaw
    reads. The warning says when the content does not match the extension.
    TIFFs are asked to LibRaw only when their tags say camera (LibRaw also reads
    plain grey TIFFs).
    """
    with open(path, "rb") as fh:
        head = fh.read(16)
    kind = image_format(head)
    if kind is None or (kind[0] == "TIFF" and _tiff_raw(path, head)):
        if _libraw_reads(path):
            raise UnsupportedInputError(
                f"{path}: this is a camera raw file (LibRaw reads it), not an image: "
                "use 'rawsim process'"
            )
        return None, None
    name, exts = kind
    if path.suffix.lower() not in exts:
        return name, f"the file holds a {name} image, not what its extension {path.suffix!r} says"
    return name, None


def _tiff_raw(path: Path, head: bytes) -> bool:
    """Whether a TIFF-structured file may be a camera raw: Canon's CR2 marker, or a
    DNGVersion or camera Make tag in its first directory (LibRaw then decides)."""
    if head[8:10] == b"CR":
        return True
    try:
        import tifffile

        with tifffile.TiffFile(path) as tif:
            tags = tif.pages.first.tags
            return 50706 in tags or 271 in tags
    except Exception:  # not a readable TIFF: OpenImageIO will say why
        return False


def _libraw_reads(path: Path) -> bool:
    import rawpy

    try:
        with collected_stderr([]), openable_name(path) as name, rawpy.imread(name):
            return True
    except Exception:
        return False


#: Full-scale code of each integer sample type that images decode to.
CODE_MAX = {np.dtype(np.uint8): 255, np.dtype(np.uint16): 65535}


@dataclass(frozen=True)
class DecodedImage:
    """An image ready for unprocessing.

    Attributes:
        pixels: (H, W, 3) array, H and W even; uint8/uint16 codes or float32 values.
        code_max: full-scale code of integer pixels (255 or 65535), None for float.
        orientation: EXIF/TIFF orientation (1–8) of the file, 1 if absent.
        source_size: (width, height) of the file before cropping.
        dropped_channels: names of channels that were not used (alpha, …).
        format_name: OpenImageIO's name of the file format.
        warnings: what the user should know (e.g. content not matching the extension).
        datetime: the capture time from the file's EXIF (``"YYYY:MM:DD HH:MM:SS"``),
            or None.
    """

    pixels: np.ndarray
    code_max: int | None
    orientation: int
    source_size: tuple[int, int]
    dropped_channels: tuple[str, ...]
    format_name: str
    warnings: tuple[str, ...] = ()
    datetime: str | None = None

    @property
    def is_float(self) -> bool:
        return self.code_max is None

    @property
    def crop(self) -> dict:
        """The kept region of the source, in pixels (cropping only removes odd edges)."""
        h, w = self.pixels.shape[:2]
        return {
            "x": 0,
            "y": 0,
            "width": w,
            "height": h,
            "source_width": self.source_size[0],
            "source_height": self.source_size[1],
        }


def _decode(path: Path, spare: Spare | None, progress: DecodeProgress | None):
    """OpenImageIO's decode: (pixels or None, spec, format name, reasons it failed).
    ``progress`` follows the rows of an image whose decoded samples are what
    unprocessing takes as they are (8/16-bit RGB, even width and height, by scanlines)."""
    import OpenImageIO as oiio

    with openable_name(path) as name:
        inp = oiio.ImageInput.open(name)
    if inp is None:
        reason = oiio.geterror().strip().splitlines()
        if any("imagesize_MB" in line for line in reason):
            limit = oiio.get_int_attribute("limits:imagesize_MB", 32768)
            return (
                None,
                None,
                None,
                [
                    f"declared image size is over the {limit // 1024} GB rawsim decodes "
                    "(a corrupt header?)"
                ],
            )
        return None, None, None, [f"not a readable image ({reason[-1] if reason else '?'})"]
    try:
        spec = inp.spec()
        base = spec.format.basetype
        if base not in (oiio.UINT8, oiio.UINT16, oiio.HALF, oiio.FLOAT, oiio.DOUBLE):
            return (
                None,
                spec,
                None,
                [f"unsupported sample type {spec.format} (need 8/16-bit or float)"],
            )
        fmt = base if base in (oiio.UINT8, oiio.UINT16) else oiio.FLOAT
        size_mb = (
            spec.width * spec.height * spec.nchannels * (4 if fmt == oiio.FLOAT else 2) / 2**20
        )
        limit = oiio.get_int_attribute("limits:imagesize_MB", 32768)
        if size_mb > limit:
            return (
                None,
                spec,
                None,
                [
                    f"declared size {spec.width}×{spec.height} would take {size_mb / 1024:.0f} GB "
                    f"to decode, over the {limit // 1024} GB limit (a corrupt header?)"
                ],
            )
        whole = spec.nchannels == 3 and spec.width % 2 == 0 and spec.height % 2 == 0
        rows = progress if whole and fmt in (oiio.UINT8, oiio.UINT16) else None
        pixels = read_pixels(inp, spec, fmt, spare, rows)
        error = inp.geterror().strip()
        if pixels is None or error:
            return None, spec, None, [f"cannot decode pixels ({error or 'truncated?'})"]
        return pixels, spec, inp.format_name(), []
    finally:
        inp.close()


#: Bytes per read of a scanline file: under glibc's mmap threshold (128 KiB), so
#: the strip OpenImageIO returns is recycled by malloc, not mapped and page-faulted
#: anew (a 24 MP JPEG: 0.06 s by strips of 96 KiB, 0.10–0.12 s by strips of 256
#: rows, 0.088 s by ``read_image``, which decodes into a buffer of its own and copies it).
STRIP_BYTES = 96 * 1024


def read_pixels(
    inp, spec, fmt, spare: Spare | None = None, progress: DecodeProgress | None = None
) -> np.ndarray | None:
    """All samples of the open image ``inp`` (``spec``), (H, W, C) of OpenImageIO
    type ``fmt``, or None if a read failed: a scanline file a strip of
    :data:`STRIP_BYTES` at a time into one array (the one ``spare`` keeps under
    its shape and dtype, if any: a batch's last decode, given back by
    :meth:`~rawsim.io.spare.Spare.keep_array`), each strip's rows reported to
    ``progress``; a tiled file in one read."""
    if spec.tile_width:
        return inp.read_image(0, 0, 0, spec.nchannels, fmt)
    import OpenImageIO as oiio

    dtype = np.dtype({oiio.UINT8: np.uint8, oiio.UINT16: np.uint16}.get(fmt, np.float32))
    rows = max(1, STRIP_BYTES // (spec.width * spec.nchannels * dtype.itemsize))
    top, bottom = spec.y, spec.y + spec.height
    shape = (spec.height, spec.width, spec.nchannels)
    pixels = np.empty(shape, dtype) if spare is None else spare.array(shape, dtype)
    if progress is not None:
        progress.begin(pixels)
    for y in range(top, bottom, rows):
        end = min(y + rows, bottom)
        strip = inp.read_scanlines(0, 0, y, end, 0, 0, spec.nchannels, fmt)
        if strip is None:
            return None
        pixels[y - top : end - top] = strip.reshape(end - y, spec.width, spec.nchannels)
        if progress is not None:
            progress.advance(end - top)
    return pixels


def _capture_time(spec) -> str | None:
    """EXIF DateTimeOriginal (else DateTime) of an image, if it is a valid EXIF time."""
    for name in ("Exif:DateTimeOriginal", "DateTime"):
        value = str(spec.getattribute(name) or "").strip()
        if re.fullmatch(r"\d{4}:\d{2}:\d{2} \d{2}:\d{2}:\d{2}", value):
            return value
    return None


def even_rgb(pixels: np.ndarray) -> np.ndarray:
    """Decoded samples (H, W) or (H, W, C) → the (H', W', 3) array unprocessing takes:
    the first three channels (grey, with or without alpha, repeated), cropped to an
    even H' and W' (whole CFA cells)."""
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    rgb = pixels[:, :, :3] if pixels.shape[2] >= 3 else np.repeat(pixels[:, :, :1], 3, axis=2)
    height, width = rgb.shape[:2]
    return np.ascontiguousarray(rgb[: height - height % 2, : width - width % 2])


def read_image(
    path: str | Path, spare: Spare | None = None, progress: DecodeProgress | None = None
) -> DecodedImage:
    """Decode ``path`` with OpenImageIO. Raises :class:`UnsupportedInputError` with the reason.

    A scanline image is decoded into the array ``spare`` keeps for its shape and
    dtype, if it keeps one (a batch's last image, given back once used). Where
    the decoded samples are the returned ``pixels`` themselves (8/16-bit RGB of
    even size, by scanlines), ``progress`` is given that array and its rows as
    they are written, for a consumer in another thread; it is ended however the
    decode ends.
    """
    try:
        return _read_image(Path(path), spare, progress)
    finally:
        if progress is not None:
            progress.end()


def _read_image(path: Path, spare: Spare | None, progress: DecodeProgress | None) -> DecodedImage:
    if path.suffix.lower() in RAW_EXTENSIONS:
        raise UnsupportedInputError(
            f"{path}: camera raw files are not unprocessing inputs (use 'rawsim process')"
        )
    if not path.is_file():
        raise UnsupportedInputError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise UnsupportedInputError(f"{path}: empty file (0 bytes)")
    _, mismatch = sniff(path)
    said: list[str] = []
    with collected_stderr(said):
        pixels, spec, format_name, error = _decode(path, spare, progress)
    if pixels is None:
        reason = "; ".join([*error, *said]) or "truncated?"
        raise UnsupportedInputError(f"{path}: {reason}")
    pixels = np.asarray(pixels)
    code_max = CODE_MAX.get(pixels.dtype)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    names = tuple(spec.channelnames) or tuple(f"ch{i}" for i in range(spec.nchannels))
    dropped = names[3:] if spec.nchannels >= 3 else names[1:]
    height, width = pixels.shape[:2]
    if height < 2 or width < 2:
        raise UnsupportedInputError(f"{path}: image is too small ({width}×{height})")
    rgb = even_rgb(pixels)
    if code_max is None:
        rgb = rgb.astype(np.float32, copy=False)
        if not np.isfinite(rgb).all():
            raise UnsupportedInputError(f"{path}: image contains NaN or infinite values")
    return DecodedImage(
        pixels=rgb,
        code_max=code_max,
        orientation=int(spec.get_int_attribute("Orientation", 1)),
        source_size=(width, height),
        dropped_channels=tuple(dropped),
        format_name=format_name,
        warnings=tuple(w for w in (mismatch, *(f"decoder: {line}" for line in said)) if w),
        datetime=_capture_time(spec),
    )


#: Output formats of ``rawsim process`` → file extension.
OUTPUT_FORMATS = {"png": ".png", "tiff": ".tif", "jpg": ".jpg", "exr": ".exr"}


def to_samples(image, fmt: str, bits: int) -> np.ndarray:
    """A (C, H, W) float tensor → (H, W, C) samples for :func:`write_image`.

    PNG/TIFF/JPEG: display-referred values clipped to [0, 1] and rounded (half to
    even) to ``bits`` (8 or 16) codes. EXR: float (``bits`` 32) or half (16),
    unclipped. The compiled engine quantises the same way (``rawsim.engine.process``).
    """
    import torch

    from rawsim import memory

    if fmt == "jpg" and bits != 8:
        raise UnsupportedInputError("JPEG output is 8-bit only (use --bits 8)")
    valid = (16, 32) if fmt == "exr" else (8, 16)
    if bits not in valid:
        raise UnsupportedInputError(f"{fmt} output cannot hold {bits}-bit samples")
    c, h, w = image.shape
    if fmt == "exr":
        data = image.float().permute(1, 2, 0).contiguous().cpu().numpy()
        return data.astype(np.float16) if bits == 16 else data
    # A block of rows at a time straight into the integer array: no full-size float copy.
    dtype = torch.uint8 if bits == 8 else torch.uint16
    out = memory.empty((h, w, c), dtype)
    for top in range(0, h, 256):
        block = image[:, top : top + 256].clamp(0.0, 1.0).mul_(2**bits - 1).round_()
        out[top : top + 256] = block.to(dtype).permute(1, 2, 0).cpu()
    return out.numpy()


def resize_samples(data: np.ndarray, long_edge: int) -> np.ndarray:
    """(H, W, C) samples scaled down so that their longer side is ``long_edge`` pixels
    (the other in proportion, rounded), antialiased (OpenImageIO's resize with a
    Blackman–Harris filter, widened by the reduction), in the samples' own
    encoding and type. An image already that small is returned as is."""
    import OpenImageIO as oiio

    h, w, c = data.shape
    if max(h, w) <= long_edge:
        return data
    scale = long_edge / max(h, w)
    nh, nw = max(1, round(h * scale)), max(1, round(w * scale))
    source = oiio.ImageBuf(np.ascontiguousarray(data))
    roi = oiio.ROI(0, nw, 0, nh, 0, 1, 0, c)
    out = oiio.ImageBufAlgo.resize(source, filtername="blackman-harris", roi=roi)
    if out.has_error:
        raise UnsupportedInputError(f"cannot resize to {nw}×{nh}: {out.geterror()}")
    kind = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16}.get(data.dtype)
    pixels = out.get_pixels(kind if kind is not None else oiio.FLOAT)
    return pixels.astype(data.dtype, copy=False)


def write_image(
    path: str | Path,
    data: np.ndarray,
    fmt: str,
    color: Encoding | None = SRGB,
    attributes: dict | None = None,
    metadata: PhotoMetadata | None = None,
) -> None:
    """Write (H, W, C) samples: PNG with :mod:`rawsim.io.png`, TIFF with
    :mod:`rawsim.io.tiff`, JPEG and EXR with OpenImageIO.

    PNG/TIFF/JPEG take uint8 or uint16 codes (JPEG 8-bit only); TIFF is uncompressed,
    PNG Average-filtered and deflated Huffman-only on several threads
    (:mod:`rawsim.io.png`; a 24 MP 8-bit render: 25.6 MB, two thirds of the time of zlib
    level 1 with the Sub filter, which wrote 32.1 MB; libpng's defaults, level 6 and
    adaptive filters, 9.2 s for 27 MB). EXR takes float32 (scene-linear, written as
    float) or float16 (half), zip-compressed. ``color``: what the samples are
    (:class:`~rawsim.colorspaces.Encoding`: space and transfer), tagged as each format
    can (:func:`_color_tags`); None writes no colour tags (camera RGB, YCbCr).
    ``metadata``: the photo's EXIF, GPS and XMP (:mod:`rawsim.io.metadata`: PNG ``eXIf``
    and ``iTXt``, TIFF tags, JPEG APP1, EXR header attributes), with the ``Software`` of
    ``attributes``; None writes ``attributes`` alone (PNG text, OpenImageIO attributes).
    No DateTime is written unless given: the same pixels make the same bytes.
    """
    software = (attributes or {}).get("Software", "rawsim")
    srgb = color is not None and color.is_srgb
    output = Output(software, fmt, data.shape[1], data.shape[0], srgb)
    profile, cicp = _color_tags(color, fmt, data.shape[2])
    if fmt == "png":
        if data.dtype not in (np.uint8, np.uint16):
            raise UnsupportedInputError(f"png output cannot hold {data.dtype} samples")
        if metadata is None:
            write_png(path, data, srgb, attributes, icc=profile, cicp=cicp)
        else:
            exif = exif_block(metadata, output)
            write_png(path, data, srgb, exif=exif, xmp=metadata.xmp, icc=profile, cicp=cicp)
        return
    if fmt == "tiff" and metadata is not None:
        icc = profile[1] if profile else None
        write_tiff(path, data, exif_block(metadata, output), metadata.xmp, icc)
        return
    import OpenImageIO as oiio

    h, w, c = data.shape
    kind = {
        np.dtype(np.uint8): oiio.UINT8,
        np.dtype(np.uint16): oiio.UINT16,
        np.dtype(np.float16): oiio.HALF,
        np.dtype(np.float32): oiio.FLOAT,
    }.get(data.dtype)
    valid = {"exr": (oiio.HALF, oiio.FLOAT), "jpg": (oiio.UINT8,)}.get(
        fmt, (oiio.UINT8, oiio.UINT16)
    )
    if kind not in valid:
        raise UnsupportedInputError(f"{fmt} output cannot hold {data.dtype} samples")
    spec = oiio.ImageSpec(w, h, c, kind)
    if fmt == "exr":
        # ACES2065-1 in half floats, uncompressed, is the ACES container (SMPTE ST 2065-4)
        container = color is not None and color.space == "aces2065-1" and kind == oiio.HALF
        container = container and c == 3 and color.transfer.kind == "linear"
        spec.attribute("compression", "none" if container else "zip")
        # OpenImageIO's names of the linear spaces it knows (it checks the container's)
        known = {"srgb": "lin_rec709", "aces2065-1": "lin_ap0_scene", "acescg": "lin_ap1_scene"}
        name = known.get(color.space) if color is not None else None
        spec.attribute("oiio:ColorSpace", name or "Linear")
        if color is not None and c >= 3:  # OpenEXR's primaries and white (xy)
            spec.attribute("chromaticities", oiio.TypeDesc("float[8]"), color.chromaticities)
            if color.rgb_space is None or color.space.startswith("aces"):  # the neutral
                spec.attribute("adoptedNeutral", oiio.TypeDesc("float[2]"), color.neutral_xy)
        if container:
            spec.attribute("acesImageContainerFlag", 1)
    elif srgb:
        spec.attribute("oiio:ColorSpace", "sRGB")
    if profile is not None:
        icc = np.frombuffer(profile[1], np.uint8)
        spec.attribute("ICCProfile", oiio.TypeDesc(f"uint8[{icc.size}]"), icc)
    if fmt == "jpg":
        spec.attribute("Compression", "jpeg:95")
    elif fmt == "tiff":
        spec.attribute("compression", "none")  # as dcraw -T: deflate costs seconds per image
    # OpenImageIO stamps TIFF and EXR with the time of writing unless DateTime is
    # set; an empty one writes none, so a rerun reproduces the file byte for byte.
    spec.attribute("DateTime", "")
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    if fmt == "exr" and metadata is not None:
        for key, value in exr_attributes(metadata, software).items():
            spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise UnsupportedInputError(f"{path}: OpenImageIO cannot write {fmt} ({oiio.geterror()})")
    try:
        if not out.open(str(path), spec) or not out.write_image(np.ascontiguousarray(data)):
            raise UnsupportedInputError(f"{path}: cannot write image ({out.geterror()})")
    finally:
        out.close()
    if fmt == "jpg" and metadata is not None:
        embed_jpeg(path, metadata, output)


def _color_tags(
    color: Encoding | None, fmt: str, channels: int
) -> tuple[tuple[str, bytes] | None, tuple[int, int, int, int] | None]:
    """(ICC profile as (name, bytes), H.273 code points) that tag ``channels``-channel
    samples of ``color`` in ``fmt``, either None where not written.

    TIFF and JPEG embed the profile (:func:`rawsim.io.icc.icc_profile`; grey
    samples a grey one), sRGB included. PNG embeds it (``iCCP``) but for sRGB,
    which its own ``sRGB`` chunk names, and adds ``cICP`` where the space and
    transfer have code points (RGB only). EXR says its primaries instead
    (``chromaticities``, in :func:`write_image`).
    """
    if color is None or fmt == "exr":
        return None, None
    grey = channels < 3
    cicp = None if grey or fmt != "png" else color.cicp
    if fmt == "png" and color.is_srgb:
        return None, cicp
    return (color.describe(), icc_profile(color, grey)), cicp
