"""PNG writing with the deflate spread over threads.

A PNG's pixels are one zlib stream, and one zlib stream is deflated on one core:
for a 24 MP render that is over a second, more than the whole ISP. Here the
filtered rows are cut into bands of :data:`BAND_ROWS` rows, each band deflated
on its own (in a thread pool; zlib releases the GIL) and ended with a sync
flush, and the pieces are joined into one valid stream (RFC 1950/1951): a zlib
header, the bands' deflate blocks, the last band's final block, the Adler-32 of
all the data. The band size is fixed, so the bytes do not depend on the number
of threads or the machine.

Rows use PNG's Sub filter (each byte minus the one a pixel to its left), which
costs one vectorised pass and compresses photos nearly as well as adaptive
filtering. Colour: ``sRGB``, ``gAMA`` and ``cHRM`` chunks, as OpenImageIO writes
them, when the samples are sRGB-encoded, or an ICC profile (``iCCP``); a ``cICP``
chunk where the encoding has H.273 code points; text attributes as ``tEXt`` chunks.
"""

from __future__ import annotations

import os
import struct
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

#: zlib level: 1 is the fastest; higher levels cost 2–9× the time for 5–15% smaller files.
ZLIB_LEVEL = 1
#: Rows per independently deflated band.
BAND_ROWS = 128
_FILTER_SUB = 1
#: Deflate threads; batch workers set their share of the cores (:func:`set_threads`).
_threads = os.cpu_count() or 1
_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Channels → PNG colour type: grey, grey + alpha, RGB, RGBA.
_COLOUR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}
#: sRGB rendering intent, gamma 1/2.2 and the sRGB primaries and white (×100000).
_SRGB_CHUNKS = (
    (b"sRGB", bytes([0])),
    (b"gAMA", struct.pack(">I", 45455)),
    (b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000)),
)


def set_threads(threads: int) -> None:
    """Deflate with ``threads`` threads from now on (e.g. cores // jobs)."""
    global _threads
    _threads = max(1, int(threads))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def filtered_rows(data: np.ndarray) -> np.ndarray:
    """(H, W, C) uint8/uint16 samples → (H, 1 + W·C·bytes) uint8 rows, Sub-filtered."""
    h, w, c = data.shape
    raw = np.ascontiguousarray(data.astype(data.dtype.newbyteorder(">"), copy=False))
    raw = raw.view(np.uint8).reshape(h, -1)
    step = c * data.dtype.itemsize  # bytes per pixel
    rows = np.empty((h, raw.shape[1] + 1), np.uint8)
    rows[:, 0] = _FILTER_SUB
    rows[:, 1 : 1 + step] = raw[:, :step]
    np.subtract(raw[:, step:], raw[:, :-step], out=rows[:, 1 + step :])
    return rows


def _deflate_band(band: np.ndarray, last: bool) -> bytes:
    compressor = zlib.compressobj(ZLIB_LEVEL, zlib.DEFLATED, -15)
    return compressor.compress(band) + compressor.flush(
        zlib.Z_FINISH if last else zlib.Z_SYNC_FLUSH
    )


def write_png(
    path: str | Path,
    data: np.ndarray,
    srgb: bool = True,
    attributes: dict | None = None,
    threads: int | None = None,
    exif: bytes = b"",
    xmp: str = "",
    icc: tuple[str, bytes] | None = None,
    cicp: tuple[int, int, int, int] | None = None,
) -> None:
    """Write (H, W, C) uint8/uint16 samples as a PNG at ``path``: C = 1 grey,
    2 grey + alpha, 3 RGB, 4 RGBA.

    ``attributes``: text chunks (keyword → value, Latin-1); ``threads``: deflate
    threads (default: :func:`set_threads`' value, else the CPU count). The file's
    bytes do not depend on ``threads``. ``exif``: an EXIF block (a TIFF structure,
    :func:`rawsim.io.metadata.exif_block`) for an ``eXIf`` chunk; ``xmp``: an XMP
    packet for an ``iTXt`` chunk keyed ``XML:com.adobe.xmp``, both before the pixels.

    Colour: ``icc`` (name, profile bytes) writes an ``iCCP`` chunk (the profile
    deflated at level 9) and then no ``sRGB``, ``gAMA`` or ``cHRM``, which would
    contradict it; else ``srgb`` writes those three. ``cicp``: ITU-T H.273
    (primaries, transfer, matrix, full range) for a ``cICP`` chunk, which readers
    that know it (PNG 3rd edition) prefer to the others.
    """
    h, w, c = data.shape
    if data.dtype not in (np.uint8, np.uint16) or c not in _COLOUR_TYPES:
        raise ValueError(f"PNG takes (H, W, 1–4) uint8/uint16 samples, got {data.dtype} × {c}")
    rows = filtered_rows(data)
    bands = [rows[i : i + BAND_ROWS] for i in range(0, h, BAND_ROWS)]
    workers = max(1, min(len(bands), threads or _threads))
    with ThreadPoolExecutor(workers) as pool:
        pieces = list(
            pool.map(_deflate_band, bands, [i == len(bands) - 1 for i in range(len(bands))])
        )
    adler = 1
    for band in bands:
        adler = zlib.adler32(band, adler)
    header = struct.pack(">2IBBBBB", w, h, 8 * data.dtype.itemsize, _COLOUR_TYPES[c], 0, 0, 0)
    parts = [_SIGNATURE, _chunk(b"IHDR", header)]
    if cicp is not None:
        parts.append(_chunk(b"cICP", bytes(cicp)))
    if icc is not None:
        name = icc[0].encode("latin-1", "replace")[:79].strip() or b"ICC profile"
        parts.append(_chunk(b"iCCP", name + b"\0\0" + zlib.compress(icc[1], 9)))
    elif srgb:
        parts += [_chunk(kind, body) for kind, body in _SRGB_CHUNKS]
    for key, value in (attributes or {}).items():
        parts.append(_chunk(b"tEXt", f"{key}\0{value}".encode("latin-1", "replace")))
    if exif:
        parts.append(_chunk(b"eXIf", exif))
    if xmp:  # keyword, no compression, no language, no translated keyword, UTF-8 text
        parts.append(_chunk(b"iTXt", b"XML:com.adobe.xmp\0\0\0\0\0" + xmp.encode()))
    pieces[0] = b"\x78\x01" + pieces[0]  # zlib header: deflate, 32 KiB window, fastest
    pieces[-1] += struct.pack(">I", adler)
    parts += [_chunk(b"IDAT", piece) for piece in pieces]
    parts.append(_chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.writelines(parts)
