"""Baseline TIFF (and DNG) writing around exiv2's EXIF block: uncompressed 8/16-bit strips.

A TIFF's metadata and its image share one directory (IFD0), so adding EXIF to a
written TIFF means rewriting the file (exiv2 does: 0.3 s for a 144 MB 24 MP
render). Here the file is laid out once: it starts with the EXIF block that
exiv2 encodes (:func:`rawsim.io.metadata.exif_block`: a TIFF header, IFD0 and
the Exif and GPS IFDs, offsets from the file's first byte), followed by a new
IFD0 (exiv2's entries, the image's own and the XMP and ICC tags, sorted), to
which the header then points, and the pixels, written straight from the array
(in 1 MiB pieces: :mod:`rawsim.io.pieces`).
The old IFD0 stays behind unreferenced (a few hundred bytes).

DNGs are written the same way, their tags added to IFD0 (:mod:`rawsim.io.dng`).
Uncompressed, as ``dcraw -T`` writes (deflate costs seconds per 24 MP image);
classic TIFF, so files stop at 4 GiB.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from rawsim.errors import UnsupportedInputError
from rawsim.io.pieces import open_empty, write_pieces

#: TIFF field types this writer packs, and their struct codes.
BYTE, ASCII, SHORT, LONG, RATIONAL, SBYTE, UNDEFINED = 1, 2, 3, 4, 5, 6, 7
SSHORT, SLONG, SRATIONAL, FLOAT, DOUBLE = 8, 9, 10, 11, 12
_CODES = {
    SHORT: "H",
    LONG: "I",
    RATIONAL: "I",
    SSHORT: "h",
    SLONG: "i",
    SRATIONAL: "i",
    FLOAT: "f",
    DOUBLE: "d",
}
#: Bytes per strip (about): small enough for any reader, few enough offsets.
STRIP_BYTES = 1 << 18
#: Tags this writer sets itself (image structure, XMP, ICC); exiv2's copies are dropped.
_OWN_TAGS = {256, 257, 258, 259, 262, 273, 274, 277, 278, 279, 284, 338, 339, 700, 34675}


def write_tiff(
    path: str | Path,
    data: np.ndarray,
    exif: bytes,
    xmp: str = "",
    icc: bytes | None = None,
    tags: dict[int, tuple[int, object]] | None = None,
    previews: tuple[tuple[np.ndarray | bytes, dict], ...] = (),
) -> None:
    """Write (H, W, C) uint8/uint16 samples (C = 1 grey, 3 RGB; 2 and 4 with alpha)
    as a TIFF whose metadata is the EXIF block ``exif``, with the ``xmp`` packet and
    ``icc`` profile if given.

    ``tags``: more IFD0 entries, code → (field type, values), which replace the
    writer's own and exiv2's (a DNG's tags, :mod:`rawsim.io.dng`). Values are a
    ``str`` for ASCII, bytes for BYTE/UNDEFINED, else a sequence of numbers;
    RATIONAL and SRATIONAL take numerator, denominator pairs, flattened.
    ``previews``: images and their own tags, written after the pixels as IFD1, IFD2, …
    (reduced-resolution images, NewSubfileType 1: a DNG's previews), each an (h, w, 3)
    uint8 RGB array (uncompressed) or the bytes of a baseline JPEG (Compression 7,
    YCbCr, as DNG previews are stored)."""
    h, w, c = data.shape
    if data.dtype not in (np.uint8, np.uint16) or not 1 <= c <= 4:
        raise UnsupportedInputError(f"tiff output cannot hold {data.dtype} × {c} samples")
    order = "<" if exif[:2] == b"II" else ">"
    (ifd0,) = struct.unpack(order + "I", exif[4:8])
    (count,) = struct.unpack(order + "H", exif[ifd0 : ifd0 + 2])
    entries = {}  # tag → its 12 bytes, values beyond 4 bytes still at their offsets in exif
    for k in range(count):
        raw = exif[ifd0 + 2 + 12 * k : ifd0 + 14 + 12 * k]
        tag = struct.unpack(order + "H", raw[:2])[0]
        if tag not in _OWN_TAGS and tag not in (tags or {}):
            entries[tag] = raw
    bits = 8 * data.dtype.itemsize
    row_bytes = w * c * data.dtype.itemsize
    rows = max(1, STRIP_BYTES // row_bytes)
    strips = -(-h // rows)
    own: dict[int, tuple[int, object]] = {
        256: (LONG, [w]),
        257: (LONG, [h]),
        258: (SHORT, [bits] * c),
        259: (SHORT, [1]),
        262: (SHORT, [2 if c >= 3 else 1]),
        273: (LONG, [0] * strips),  # filled in below, once the layout is known
        274: (SHORT, [1]),
        277: (SHORT, [c]),
        278: (LONG, [rows]),
        279: (LONG, [min(rows, h - s * rows) * row_bytes for s in range(strips)]),
        284: (SHORT, [1]),
    }
    if c in (2, 4):
        own[338] = (SHORT, [2])  # unassociated alpha
    if xmp:
        own[700] = (BYTE, xmp.encode())
    if icc:
        own[34675] = (UNDEFINED, bytes(icc))
    own.update(tags or {})
    start = len(exif) + len(exif) % 2
    values_at = start + 2 + 12 * len({*entries, *own}) + 4
    layout = _values_layout(own, values_at)
    pixels_at = max(layout.values(), default=values_at) + 16
    pixels_at += -pixels_at % 16
    end = pixels_at + h * row_bytes
    tail = b""
    for k, (image, own_tags) in enumerate(previews):
        at = end + end % 2 + len(tail)
        tail += _reduced_ifd(order, at, image, own_tags, last=k == len(previews) - 1)
        tail += b"\0" * (len(tail) % 2)
    if end + len(tail) >= 2**32:
        raise UnsupportedInputError(
            f"{path}: a {w}×{h} TIFF of {bits}-bit samples is over 4 GiB; write EXR or PNG"
        )
    own[273] = (LONG, [pixels_at + s * rows * row_bytes for s in range(strips)])
    ifd, extra = _ifd(order, own, values_at, entries)
    ifd += struct.pack(order + "I", end + end % 2 if tail else 0)  # the previews' IFDs
    header = exif[:4] + struct.pack(order + "I", start)
    head = header + exif[8:] + b"\0" * (start - len(exif)) + bytes(ifd) + bytes(extra)
    head += b"\0" * (pixels_at - len(head))
    samples = np.ascontiguousarray(data, dtype=data.dtype.newbyteorder(order))
    with open_empty(path) as f:
        write_pieces(f, head, samples, b"\0" * (end % 2 if tail else 0), tail)


def _reduced_ifd(order: str, at: int, image, tags: dict, last: bool) -> bytes:
    """An IFD at file offset ``at`` for ``image`` (NewSubfileType 1: reduced resolution;
    one strip): an (h, w, 3) uint8 array, uncompressed RGB, or the bytes of a baseline
    JPEG (Compression 7, YCbCr), with ``tags`` added; its values and the image after
    it. The next IFD follows it, unless ``last``."""
    if isinstance(image, bytes | bytearray):
        import io

        from PIL import Image

        with Image.open(io.BytesIO(image)) as jpeg:
            w, h = jpeg.size
        c, data, compression, photometric = 3, bytes(image), 7, 6
    else:
        h, w, c = image.shape
        data, compression, photometric = np.ascontiguousarray(image, np.uint8).tobytes(), 1, 2
    own = {
        254: (LONG, [1]),
        256: (LONG, [w]),
        257: (LONG, [h]),
        258: (SHORT, [8] * c),
        259: (SHORT, [compression]),
        262: (SHORT, [photometric]),
        273: (LONG, [0]),
        277: (SHORT, [c]),
        278: (LONG, [h]),
        279: (LONG, [len(data)]),
        284: (SHORT, [1]),
        **tags,
    }
    values_at = at + 2 + 12 * len(own) + 4
    data_at = max(_values_layout(own, values_at).values(), default=values_at)
    own[273] = (LONG, [data_at])
    ifd, extra = _ifd(order, own, values_at)
    after = data_at + len(data)
    ifd += struct.pack(order + "I", 0 if last else after + after % 2)
    return bytes(ifd) + bytes(extra) + data


def _ifd(order: str, own: dict, values_at: int, entries: dict | None = None):
    """An IFD's entry count and entries, without the next IFD's offset, and its
    out-of-line values, which start at file offset ``values_at``: ``own`` (code →
    (field type, values)) packed, and ``entries`` (code → 12 bytes as exiv2 wrote
    them) as they are, in tag order."""
    entries = entries or {}
    codes = sorted([*entries, *own])
    ifd = bytearray(struct.pack(order + "H", len(codes)))
    extra = bytearray()
    for tag in codes:
        if tag in entries:
            ifd += entries[tag]
            continue
        kind, values = own[tag]
        payload, n = _pack(order, kind, values)
        if len(payload) <= 4:
            ifd += struct.pack(order + "HHI", tag, kind, n) + payload.ljust(4, b"\0")
        else:
            ifd += struct.pack(order + "HHII", tag, kind, n, values_at + len(extra))
            extra += payload + b"\0" * (len(payload) % 2)
    return ifd, extra


def _values_layout(own: dict, values_at: int) -> dict[int, int]:
    """Where each out-of-line value ends, for sizing the head (tag → end offset)."""
    ends, at = {}, values_at
    for tag in sorted(own):
        size = len(_pack("<", *own[tag])[0])
        if size > 4:
            at += size + size % 2
            ends[tag] = at
    return ends


def _pack(order: str, kind: int, values) -> tuple[bytes, int]:
    """A field's value bytes and its count (characters with the NUL for ASCII,
    pairs for rationals)."""
    if kind == ASCII:
        text = values.encode("ascii", "replace") + b"\0"
        return text, len(text)
    if kind in (BYTE, SBYTE, UNDEFINED):
        return bytes(v & 0xFF for v in values) if kind == SBYTE else bytes(values), len(values)
    packed = struct.pack(f"{order}{len(values)}{_CODES[kind]}", *values)
    return packed, len(values) // (2 if kind in (RATIONAL, SRATIONAL) else 1)
