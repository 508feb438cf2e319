"""Writing large buffers to a file in pieces of :data:`PIECE_BYTES`, into a file
opened without needless truncation (:func:`open_empty`).

One ``write()`` of a whole 144 MB render costs 0.31–0.36 s on Linux 6.18 (ext4)
once a few hundred MB of the page cache are dirty, where the same bytes in
1 MiB writes cost 0.03–0.04 s; writes of 2 MiB and more are as slow as one
(``benchmarks/bench_process.py --io``, "write 144 MB"). libtiff, under OpenImageIO,
writes strips of about 1 MB.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import BinaryIO

#: Bytes per ``write()``.
PIECE_BYTES = 1 << 20


def open_empty(path: str | Path) -> BinaryIO:
    """``path`` opened for writing from its start, created if absent, emptied if not
    empty, but not truncated when it is already empty (the temporaries of
    :func:`rawsim.io.outputs.atomic_outputs`): on ext4 a file truncated to zero
    flushes its data when closed (``auto_da_alloc``), which made ``close()`` of a
    144 MB TIFF take 0.04 s where it takes nothing otherwise."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o666)
    try:
        if os.fstat(fd).st_size:
            os.ftruncate(fd, 0)
        return os.fdopen(fd, "wb")
    except BaseException:
        os.close(fd)
        raise


def write_pieces(f: BinaryIO, *buffers) -> None:
    """Write each of ``buffers`` (bytes-like, any size) to ``f`` in order, at most
    :data:`PIECE_BYTES` per call."""
    for buffer in buffers:
        data = memoryview(buffer).cast("B")
        for at in range(0, len(data), PIECE_BYTES):
            f.write(data[at : at + PIECE_BYTES])
