"""The compiled CPU engine: fused numba kernels for the no-gradient path.

Each kernel runs every stage of a pipeline in one pass over the image, a row at a
time, parallel over rows (``prange``), with the stage maths of the torch
reference (:mod:`rawsim.isp`, :mod:`rawsim.noise.models`) and the same counter-based
noise (:mod:`rawsim.noise.kernels`). Compiled code is cached on disk
(``cache=True``): beside the package when it is writable, else in numba's
user-wide cache folder (``NUMBA_CACHE_DIR`` or ``~/.cache/numba``), so only the
first run on a machine compiles.

:func:`available` says whether numba can be imported; callers fall back to the
torch reference when it cannot.

For developers: numba keys a cached kernel on its own module's file only. The
kernels inline functions of :mod:`rawsim.noise.kernels` and
:mod:`rawsim.noise.exact_math`, so after editing those alone, delete the cache
(``find rawsim -name '*.nbi' -delete``) or touch the kernel modules. Installs
are not affected: a new version replaces every file.
"""

from __future__ import annotations

import importlib.util
import os
import sys

#: Set by the command-line tool, whose processes compile no numba code of their own:
#: numba is then imported without its BLAS probe (see :func:`_import_numba_lean`).
lean_start = False


def available() -> bool:
    """Whether the engine can run here (numba is installed)."""
    if importlib.util.find_spec("numba") is None:
        return False
    if lean_start:
        _import_numba_lean()
    return True


def _import_numba_lean() -> None:
    """Import numba with what it imports only to probe or check hidden, once, if
    nothing imported numba or those modules before.

    * ``scipy.linalg``: numba probes for BLAS (for ``np.dot`` in compiled code) by
      importing it, 0.15 s of a cold start, for functions the engine does not use.
      Hidden, the probe fails and numba marks BLAS absent in this process.
    * ``scipy``: imported to check its version (8 ms).
    * ``cffi``: numba's typing of cffi functions builds a C parser (pycparser,
      0.04 s) when the first cached kernel loads; the engine passes none.
    * ``yaml`` (7 ms), read only for a ``.numba_config.yaml`` in the working
      folder: hidden only where there is none.

    Each imports normally afterwards.
    """
    hidden = ["scipy", "scipy.linalg", "cffi"]
    if not os.path.exists(".numba_config.yaml"):
        hidden.append("yaml")
    if "numba" in sys.modules or any(name in sys.modules for name in hidden):
        return
    for name in hidden:
        sys.modules[name] = None  # type: ignore[assignment]
    try:
        import numba.core.typing.cffi_utils  # noqa: F401  (where cffi is tried)
        import numba.np.arraymath  # noqa: F401  (where the probe runs)
    finally:
        for name in hidden:
            del sys.modules[name]


def configure() -> None:
    """Choose a fork-safe threading layer before any kernel runs, as many threads as
    the process may keep busy (:func:`rawsim.cores.usable_cores`), log the kernels
    numba compiles (:mod:`rawsim.engine.compile_log`), and let one process at a time
    compile each (:mod:`rawsim.engine.compile_lock`: the others load it from the cache).

    Batch jobs and DataLoaders fork workers; a child forked after GNU OpenMP has
    started its threads is killed ("fork() called from a process already using
    GNU OpenMP"). ``forksafe`` takes TBB where installed, else numba's own
    workqueue. A user's ``NUMBA_THREADING_LAYER`` wins.
    """
    import numba

    from rawsim.cores import usable_cores
    from rawsim.engine import compile_lock, compile_log

    if "NUMBA_THREADING_LAYER" not in os.environ:
        numba.config.THREADING_LAYER = "forksafe"
    if "NUMBA_NUM_THREADS" not in os.environ:  # a CPU quota below the visible cores
        numba.set_num_threads(min(numba.get_num_threads(), usable_cores()))
    _allow_runtime_overlap_checks()
    compile_log.install()
    compile_lock.install()


#: LLVM vectoriser limits, raised: a loop whose arrays LLVM cannot prove disjoint is
#: vectorised behind run-time overlap checks, one per pair of streams, and by
#: default LLVM gives up beyond 8 (or 128) of them. The engine's row loops read up
#: to 20 rows and write up to 8, so they need more; the checks run once per row.
_LLVM_OPTIONS = ("-runtime-memory-check-threshold=256", "-vectorize-memory-check-threshold=4096")
_llvm_configured = False


def _allow_runtime_overlap_checks() -> None:
    """Set :data:`_LLVM_OPTIONS`, once per process (LLVM's options are global)."""
    global _llvm_configured
    if _llvm_configured:
        return
    import llvmlite.binding as llvm

    for option in _LLVM_OPTIONS:
        llvm.set_option("rawsim", option)
    _llvm_configured = True


def set_threads(threads: int) -> None:
    """Use ``threads`` threads in the engine's parallel loops (e.g. cores // jobs).

    Configured first (:func:`configure`): numba starts its threads at the first
    ``set_num_threads``, in the layer chosen then, for the life of the process.
    """
    import numba

    configure()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
