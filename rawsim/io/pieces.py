"""Writing large buffers to a file in pieces of :data:`PIECE_BYTES`.

One ``write()`` of a whole 144 MB render costs 0.31–0.36 s on Linux 6.18 (ext4)
once a few hundred MB of the page cache are dirty, where the same bytes in
1 MiB writes cost 0.03–0.04 s; writes of 2 MiB and more are as slow as one
(``benchmarks/bench_process.py --io``, "write 144 MB"). libtiff, under OpenImageIO,
writes strips of about 1 MB.
"""

from __future__ import annotations

from typing import BinaryIO

#: Bytes per ``write()``.
PIECE_BYTES = 1 << 20


def write_pieces(f: BinaryIO, *buffers) -> None:
    """Write each of ``buffers`` (bytes-like, any size) to ``f`` in order, at most
    :data:`PIECE_BYTES` per call."""
    for buffer in buffers:
        data = memoryview(buffer).cast("B")
        for at in range(0, len(data), PIECE_BYTES):
            f.write(data[at : at + PIECE_BYTES])
