"""One process compiles a kernel; the others wait for it and load it from the cache.

DataLoader workers and ``--jobs`` processes start together on an empty cache, and
each would compile the same kernel (seconds to minutes) and say so. Around numba's
compile of one of rawsim's cached kernels for one signature, each process takes an
exclusive lock on a file beside the cache (``<index>.<signature hash>.lock``):
the first compiles and saves the kernel, and each other, once the lock is free,
finds it in the cache and loads it, silently. The lock is ``flock``'s: the system
frees it when its holder exits or is killed, so none waits on a dead process; one
that is alive but stuck is waited for at most :data:`LOCK_WAIT` seconds, then the
waiting process compiles the kernel itself. Where ``fcntl`` is missing (Windows)
or the cache folder cannot take a lock file, each process compiles as before.

Installed by :func:`rawsim.engine.configure`, once per process.
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
import time
from contextlib import contextmanager

from numba.core import dispatcher, sigutils
from numba.core.compiler_lock import global_compiler_lock

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; each process compiles
    fcntl = None

log = logging.getLogger("rawsim.engine")

#: The longest a process waits for another's compile of a kernel (seconds) before it
#: compiles the kernel itself; a killed holder frees its lock at once.
LOCK_WAIT = 600.0
#: How often a waiting process tries the lock again (seconds).
POLL = 0.05

_held: set[str] = set()  # lock files this process holds (a nested compile takes none)
_installed = False


def lock_path(disp: dispatcher.Dispatcher, sig) -> str | None:
    """The lock file of ``disp``'s compile for ``sig``: beside its on-disk cache, named
    after the cache's index and the signature; None where there is nothing to lock:
    not one of rawsim's kernels, not cached on disk, or compiled in this process."""
    func = disp.py_func
    if not (getattr(func, "__module__", "") or "").startswith("rawsim."):
        return None
    cache = disp._cache
    impl = getattr(cache, "_impl", None)
    if impl is None:  # a NullCache: cache=False
        return None
    args, _ = sigutils.normalize_signature(sig)
    if disp.overloads.get(tuple(args)) is not None:
        return None
    digest = hashlib.sha1(str(tuple(args)).encode()).hexdigest()[:16]
    # the index's own name (module.function-line.pyXY) with the signature's hash
    return os.path.join(cache.cache_path, f"{impl.filename_base}.{digest}.lock")


@contextmanager
def held(path: str, wait: float = LOCK_WAIT):
    """Hold the exclusive lock on ``path`` inside the block, waiting at most ``wait``
    seconds for another process to free it (then the block runs unlocked); unlocked
    too where the file cannot be opened. Reentrant in one process."""
    if path in _held:
        yield
        return
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        yield
        return
    try:
        deadline = time.monotonic() + wait
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                locked = True
                break
            except OSError:
                if time.monotonic() >= deadline:
                    log.debug("%s: still locked after %.0f s: compiling anyway", path, wait)
                    locked = False
                    break
                time.sleep(POLL)
        if locked:
            _held.add(path)
        try:
            yield
        finally:
            _held.discard(path)
    finally:
        os.close(fd)  # frees the lock


def _locked(compile_):
    """``Dispatcher.compile`` with the lock of :func:`lock_path` held around it. Taken
    inside numba's own (process-wide, reentrant) compiler lock, so that two threads of
    one process never hold a lock file each while waiting for the other's."""

    def compile(self, sig):
        with global_compiler_lock:
            path = lock_path(self, sig)
            if path is None:
                return compile_(self, sig)
            with held(path):
                return compile_(self, sig)

    compile.__wrapped__ = compile_
    compile.__doc__ = compile_.__doc__
    return compile


_install_lock = threading.Lock()


def install() -> None:
    """Wrap numba's ``Dispatcher.compile`` (for rawsim's cached kernels), once per process."""
    global _installed
    with _install_lock:
        if _installed or fcntl is None:
            return
        dispatcher.Dispatcher.compile = _locked(dispatcher.Dispatcher.compile)
        _installed = True
