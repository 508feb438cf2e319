"""Say when numba compiles one of rawsim's kernels: a miss in its on-disk cache.

The first run on a machine compiles each kernel it uses (seconds to minutes each,
longer on a loaded machine); later runs load them from the cache. Without a word
that looks like a hang, so every compile of a rawsim kernel is logged (warning
level: shown unless ``-q``), its start with what is happening and how to do it ahead
of time (``rawsim compile``), its end with the seconds it took. A kernel loaded
from the cache logs nothing, so of processes that need one kernel at once only
the one that compiles it logs (:mod:`rawsim.engine.compile_lock`: the others wait
and load it). Each line is one record, written whole by the logging handler.

Imported by :func:`rawsim.engine.configure`, so only where numba is.
"""

from __future__ import annotations

import logging
import threading
import time

from numba.core import event

log = logging.getLogger("rawsim.engine")


class CompileLog(event.Listener):
    """A ``numba:compile`` listener that logs rawsim's outermost kernels.

    numba compiles a kernel's callees inside the kernel's own compile (nested
    events, in the compiling thread): only the outermost compile is logged, and
    only if its function is rawsim's.
    """

    def __init__(self) -> None:
        self._local = threading.local()
        self._announced = False

    def on_start(self, ev: event.Event) -> None:
        depth = getattr(self._local, "depth", 0)
        self._local.depth = depth + 1
        name = _rawsim_kernel(ev)
        if depth or name is None:
            return
        self._local.started = time.perf_counter()
        if not self._announced:
            self._announced = True
            log.warning(
                "compiling the engine's kernels for this CPU, once: seconds to minutes "
                "each, cached for later runs ('rawsim compile' builds them all ahead)"
            )
        log.warning("compiling %s …", name)

    def on_end(self, ev: event.Event) -> None:
        self._local.depth -= 1
        name = _rawsim_kernel(ev)
        if self._local.depth or name is None:
            return
        # rawsim compile counts a task's kernels by this line (rawsim_cli.compile)
        log.warning("compiled %s in %.1f s", name, time.perf_counter() - self._local.started)


def _rawsim_kernel(ev: event.Event) -> str | None:
    """The compiled function as ``module.function`` below ``rawsim`` (e.g.
    ``engine.process.process_kernel``), or None if it is not rawsim's."""
    func = ev.data["dispatcher"].py_func
    module = getattr(func, "__module__", "") or ""
    if not module.startswith("rawsim."):
        return None
    return f"{module.removeprefix('rawsim.')}.{func.__qualname__}"


_listener: CompileLog | None = None


def install() -> None:
    """Register the listener, once per process."""
    global _listener
    if _listener is None:
        _listener = CompileLog()
        event.register("numba:compile", _listener)
