"""The arrays of a batch's last file, for the next file of its size to write into.

A new 24 MP array costs its first touch: page faults and the zeroing of fresh
huge pages were 17 % of a ``process`` batch's CPU samples and 9 % of an
``unprocess`` batch's on the development VM (``perf``: ``clear_page_erms``), and
the decode buffer of each JPEG another 0.1 core-seconds an ``unprocess`` file.
A batch runs its files one after another in a process, so once a file's outputs
are written its arrays can take the next file's decode or results.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np


class Spare:
    """At most one value (an array, or a set of them) kept under its key: its size and
    type. :meth:`take` hands it out once (or makes a new one); :meth:`keep` puts one
    back, in place of any other. Safe across threads (a reader thread takes what the
    batch's thread keeps): a value is handed to one taker only."""

    def __init__(self) -> None:
        self._kept: dict[Hashable, Any] = {}
        self._lock = threading.Lock()

    def take(self, key: Hashable, make: Callable[[], Any]) -> Any:
        with self._lock:
            kept = self._kept.pop(key, None)
        return make() if kept is None else kept

    def keep(self, key: Hashable, value: Any) -> None:
        with self._lock:
            self._kept.clear()
            self._kept[key] = value

    def array(self, shape: tuple[int, ...], dtype) -> np.ndarray:
        """An array of ``shape`` and ``dtype``, its values undefined: the one
        :meth:`keep_array` kept, if it has that shape and dtype, else a new one."""
        shape, dtype = tuple(shape), np.dtype(dtype)
        return self.take((shape, dtype), lambda: np.empty(shape, dtype))

    def keep_array(self, array: np.ndarray) -> None:
        """Keep ``array``, no longer used, for :meth:`array` of its shape and dtype."""
        self.keep((array.shape, array.dtype), array)

    def clear(self) -> None:
        with self._lock:
            self._kept.clear()

    def __len__(self) -> int:
        return len(self._kept)
