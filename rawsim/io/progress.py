"""The rows of an image decoded so far, for work on the first rows while the decoder
writes the rest.

A decoder in a reader thread fills an array strip by strip; the unprocess engine
in the caller's thread works on bands of rows as they are filled, so a single
file's decode and compute overlap instead of following each other (a batch
already overlaps them across files: :mod:`rawsim.io.readahead`).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import numpy as np


class DecodeProgress:
    """How far a decode in another thread has got.

    The decoder calls :meth:`begin` with the array it decodes into (only where
    that array is the decoded image itself, rows in order), :meth:`advance` as
    rows are written and :meth:`end` when it stops, done or failed. The consumer
    takes :meth:`pixels`, then :meth:`bands` of written rows.
    """

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._pixels: np.ndarray | None = None
        self._rows = 0
        self._ended = False

    def begin(self, pixels: np.ndarray) -> None:
        with self._changed:
            self._pixels = pixels
            self._changed.notify_all()

    def advance(self, rows: int) -> None:
        """``rows`` rows from the top are written."""
        with self._changed:
            self._rows = rows
            self._changed.notify_all()

    def end(self) -> None:
        with self._changed:
            self._ended = True
            self._changed.notify_all()

    def pixels(self) -> np.ndarray | None:
        """The array being decoded into, once the decoder has it; None if the decode
        ended without one (it failed, or it does not decode by rows)."""
        with self._changed:
            self._changed.wait_for(lambda: self._pixels is not None or self._ended)
            return self._pixels

    def bands(self, rows: int) -> Iterator[tuple[int, int]]:
        """(start, stop) ranges of written rows, in order, each of at least ``rows``
        rows but the last; they end where the decode ended: at the last row, or
        where it failed (the decoder's caller raises why)."""
        done = 0
        while True:
            with self._changed:
                self._changed.wait_for(lambda need=done + rows: self._rows >= need or self._ended)
                written, ended = self._rows, self._ended
            if written > done:
                yield done, written
                done = written
            if ended:
                return
