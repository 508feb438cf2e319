"""The output arrays of a batch's last file, for the next file of its size to write into.

A new 24 MP output costs its first touch: page faults and the zeroing of fresh
huge pages were 17 % of a ``process`` batch's CPU samples and 9 % of an
``unprocess`` batch's on the development VM (``perf``: ``clear_page_erms``).
A batch runs its files one after another in a process, so once a file's outputs
are written their arrays can take the next file's results.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any


class Spare:
    """At most one value (an array, or a set of them) kept under its key: its size and
    type. :meth:`take` hands it out once (or makes a new one); :meth:`keep` puts one
    back, in place of any other."""

    def __init__(self) -> None:
        self._kept: dict[Hashable, Any] = {}

    def take(self, key: Hashable, make: Callable[[], Any]) -> Any:
        kept = self._kept.pop(key, None)
        return make() if kept is None else kept

    def keep(self, key: Hashable, value: Any) -> None:
        self._kept.clear()
        self._kept[key] = value

    def clear(self) -> None:
        self._kept.clear()

    def __len__(self) -> int:
        return len(self._kept)
