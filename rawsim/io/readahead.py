"""Reading a batch's next input in a thread while this one renders.

Decoders that release the GIL while they decode (LibRaw's unpack, numpy's
copies) run beside the compiled kernels (``nogil``) and the writers' file I/O,
so a file's read overlaps the previous file's render instead of following it.
At most :data:`AHEAD` inputs are read or held ahead: memory holds the input
being rendered, the one read ahead and the output being written, whatever the
batch's length.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Hashable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

#: Inputs read ahead at most (and reader threads): the next file's, and the current
#: one's while the first file of a process also loads the engine.
AHEAD = 2


class ReadAhead:
    """Reader threads that read inputs ahead of their use.

    :meth:`start` begins ``read(*args)`` for the input ``key``; :meth:`take` returns
    its result (waiting for it, raising its exception in the caller, as if the
    caller had read), or reads now when that input was not read ahead. Beyond
    :data:`AHEAD` inputs, the oldest not taken is dropped (a file the batch
    skipped, or failed before reading).
    """

    def __init__(self, name: str = "rawsim-read") -> None:
        self._name = name
        self._pool: ThreadPoolExecutor | None = None
        self._pid = 0  # the process whose threads the pool has (a fork has none)
        self._pending: dict[Hashable, Future] = {}

    def start(self, key: Hashable, read: Callable[..., Any], *args: Any) -> None:
        pool = self._pool_here()
        if key in self._pending:
            return
        while len(self._pending) >= AHEAD:
            self._pending.pop(next(iter(self._pending))).cancel()
        self._pending[key] = pool.submit(read, *args)

    def run(self, read: Callable[..., Any], *args: Any) -> Future:
        """``read(*args)`` in a reader thread now, for the caller to work beside it
        (not kept as a read ahead): its future."""
        return self._pool_here().submit(read, *args)

    def _pool_here(self) -> ThreadPoolExecutor:
        """The reader threads of this process (new ones after a fork, which has none)."""
        if self._pool is None or self._pid != os.getpid():
            self._pool = ThreadPoolExecutor(AHEAD, thread_name_prefix=self._name)
            self._pid, self._pending = os.getpid(), {}
        return self._pool

    def pending(self, key: Hashable) -> bool:
        """Whether the input ``key`` is read ahead (read, or being read)."""
        return self._pid == os.getpid() and key in self._pending

    def take(self, key: Hashable, read: Callable[..., Any], *args: Any) -> Any:
        future = self._pending.pop(key, None) if self._pid == os.getpid() else None
        return read(*args) if future is None else future.result()
