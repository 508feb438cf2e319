"""Running one job on one file, in this process or in a pool worker: its outcome
(:class:`Result`), what existing outputs mean, its failure message, and how SIGINT
and SIGTERM stop it (:class:`Interrupted`) so that it leaves no partial outputs.

A job is a plain function ``job(task, **kwargs) -> dict`` that knows nothing of
batches; it raises :class:`~rawsim.errors.RawsimError` for bad inputs.
"""

from __future__ import annotations

import ctypes
import errno
import os
import signal
import sys
import threading
import time
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing import get_all_start_methods, get_context

from rawsim.errors import RawsimError, shown
from rawsim.io import outputs, remote
from rawsim.io.atomic import running
from rawsim.io.task import Task

#: Seconds after which a signal that a finalizer swallowed is sent again: long enough
#: for the hook that sends it to return first on a loaded machine (at 0.01 s a
#: thread's start under a full test run could outlast it, and the signal was then
#: raised inside the hook, where it is printed, not raised).
REDELIVER_S = 0.1
#: Times the hook starts the sender again when the signal came back before it returned.
REDELIVER_TRIES = 5


class Interrupted(BaseException):
    """SIGINT or SIGTERM stopped the job; exit status 128 + ``signum`` (130, 143).

    A BaseException, like KeyboardInterrupt: no ``except Exception`` swallows it,
    and on its way out every atomic write removes its temporary file. ``finished``:
    the results of files that workers had finished and the batch had not yet given
    out when it came (:func:`rawsim.run.batch.run`), for the summary to count.
    """

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.finished: list = []

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


#: The signal that stopped the job under :class:`stop_on_signals`, or None.
_received: int | None = None


def _stop_on_signal(signum, frame) -> None:
    """The first SIGINT/SIGTERM stops the job; later ones wait for its cleanup (≤ 2 s)."""
    global _received
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    _received = signum
    raise Interrupted(signum)


def signal_received() -> int | None:
    """The signal that stopped the job, if any: a library that catches the
    :class:`Interrupted` raised inside it (Ray, waiting on its workers) raises an
    error of its own instead, which is then the interruption's."""
    return _received


def _redelivering(previous: Callable) -> Callable:
    """A ``sys.unraisablehook`` that delivers again an :class:`Interrupted` raised in
    a finalizer, and passes anything else to ``previous``.

    The garbage collector runs ``__del__`` methods at any point, and a signal
    handler that runs inside one raises where nothing can unwind the job: Python
    prints the exception and goes on, the signal now ignored. So the handler is
    re-armed and the signal sent to this process again, from a timer thread a
    moment later (sent from here, it would be handled here, in the hook), to be
    raised at the next point that can unwind.
    """

    def hook(unraisable) -> None:
        if not isinstance(unraisable.exc_value, Interrupted):
            previous(unraisable)
            return
        signum = unraisable.exc_value.signum
        for _ in range(REDELIVER_TRIES):
            signal.signal(signum, _worker_terminated if _worker else _stop_on_signal)
            again = threading.Timer(REDELIVER_S, os.kill, (os.getpid(), signum))
            again.daemon = True
            try:
                again.start()
                return
            except Interrupted:  # it came back before the hook returned: send it again
                continue

    return hook


class stop_on_signals:
    """Context: SIGINT and SIGTERM raise :class:`Interrupted` in the main thread
    (again if a finalizer swallowed it: :func:`_redelivering`).

    Restores the previous handlers on exit. Does nothing outside the main thread
    (Python delivers signals only there).
    """

    def __enter__(self):
        global _received
        _received = None
        self._old = None
        if threading.current_thread() is threading.main_thread():
            self._old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
            self._old_hook = sys.unraisablehook
            for sig in self._old:
                signal.signal(sig, _stop_on_signal)
            sys.unraisablehook = _redelivering(self._old_hook)
        return self

    def __exit__(self, *exc) -> None:
        if self._old is None:
            return
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        sys.unraisablehook = self._old_hook


@dataclass
class Result:
    """The outcome of one task: ``done``, ``skipped`` or ``failed``."""

    task: Task
    status: str
    message: str = ""
    record: dict = field(default_factory=dict)
    detail: str = ""
    seconds: float = 0.0


def _run_one(job: Callable, task: Task, overwrite: bool, debug: bool, kwargs: dict) -> Result:
    """Run ``job`` on ``task``: skipped if all its outputs exist, refused if only some
    do (they are not a finished set of this command's: nothing is overwritten without
    ``--overwrite``). An unfinished set that a killed run of rawsim left (its marker
    says so: :mod:`rawsim.io.outputs`) is not a finished set: it is replaced. A job
    that fails or is interrupted leaves none of the outputs it had begun to write."""
    try:
        existing = {p for p in task.outputs.values() if remote.exists(p)}
        left = outputs.unfinished(task.outputs)
    except Exception as err:  # OSError, or a remote file system's own errors
        return Result(task, "failed", f"{shown(task.source)}: cannot check its outputs: {err}")
    if left is not None:
        if left["running"]:
            return Result(
                task,
                "failed",
                f"{shown(task.source)}: its outputs are being written by process {left['pid']} "
                "(another run into the same folder); let it finish, or stop it and run again",
            )
        ours = set(left.get("outputs", ()))  # the names that run was putting in place
        for p in existing:
            if outputs.file_name(p) in ours:
                remote.remove(p)
        outputs.clear(task.outputs)
        existing = {p for p in existing if outputs.file_name(p) not in ours}
    if not overwrite and existing:
        if len(existing) == len(task.outputs):
            return Result(task, "skipped", f"{shown(task.source)}: outputs exist (use --overwrite)")
        absent = next(p for p in task.outputs.values() if p not in existing)
        return Result(
            task,
            "failed",
            f"{shown(task.source)}: {shown(min(existing))} exists but {shown(absent)} does not; "
            "not replacing a file this run did not finish (use --overwrite to replace it)",
        )
    start = time.perf_counter()
    global _in_job
    _in_job = True
    local = task  # the task with local paths (a remote input is downloaded first)
    try:
        with outputs.staged(task) as local:
            record = job(local, **kwargs)
    except BaseException as err:
        for p in task.outputs.values():  # the outputs this job had written so far
            if p not in existing:
                remote.remove(p)
        if not any(remote.exists(p) for p in task.outputs.values()):
            outputs.clear(task.outputs)  # nothing left of the set: no marker either
        if isinstance(err, Interrupted):
            if _worker:  # terminated by the parent: the temporary files are gone, leave now
                os._exit(128 + signal.SIGTERM)
            raise
        if not isinstance(err, Exception):
            raise
        detail = traceback.format_exc() if debug else ""
        message = _failure(err, local)
        if local.source != task.source:  # name the input as the user gave it
            message = message.replace(str(local.source), shown(task.source))
        return Result(task, "failed", message, detail=detail)
    finally:
        _in_job = False
    return Result(task, "done", record=record, seconds=time.perf_counter() - start)


def _failure(err: Exception, task: Task) -> str:
    """The one-line message of a job's error: a :class:`RawsimError` says it all; a
    full disk says so; anything else (a bug, or a library's error on a bad file)
    is named with its type."""
    if isinstance(err, RawsimError):
        return _one_line(err, task)
    text = str(err)
    if isinstance(err, OSError) and (
        err.errno == errno.ENOSPC or ("requested and" in text and "written" in text)
    ):
        folder = os.path.dirname(str(next(iter(task.outputs.values()))))
        return f"{shown(task.source)}: disk full writing into {shown(folder)} (free some space)"
    return f"{shown(task.source)}: {type(err).__name__}: {_one_line(err, None)}"


def _one_line(err: BaseException, task: Task | None) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    if task is not None and str(task.source) not in text and shown(task.source) not in text:
        text = f"{shown(task.source)}: {text}"
    return text


def _worker_context():
    """Fork where the platform can (as torch's DataLoader does), else spawn.

    Forked workers share the parent's imported modules, which spares each of them
    the seconds that importing torch takes; the parent has run no parallel torch
    work before the pool starts. CUDA does not survive a fork, so where the parent
    has imported torch and a GPU is present, the workers are spawned. A parent that
    has not imported torch (``process`` on the compiled engine needs none) holds no
    CUDA state, and does not import torch (1.0 s) to ask.
    """
    torch = sys.modules.get("torch")
    if "fork" in get_all_start_methods() and (torch is None or not torch.cuda.is_available()):
        return get_context("fork")
    return get_context("spawn")


#: Whether this process is a pool worker, and whether it is running a job now.
_worker = False
_in_job = False
#: Seconds between a worker's checks that its parent is still alive.
PARENT_POLL_S = 0.2
#: Seconds an orphaned worker gets to unwind its job before it exits regardless.
ORPHAN_GRACE_S = 1.5
#: Linux prctl option: the signal this process gets when its parent dies.
_PR_SET_PDEATHSIG = 1


def _worker_terminated(signum, frame) -> None:
    """SIGTERM in a worker: unwind the running job (its atomic writes remove their
    temporary files), then exit; an idle worker exits at once."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if _in_job:
        raise Interrupted(signum)
    os._exit(128 + signum)


def _init_worker(threads: int, parent: int | None = None) -> None:
    """Give each worker its share of the cores, in torch and in the engine, so that
    jobs × threads ≤ cores; leave SIGINT (Ctrl-C reaches the whole process group)
    to the parent, which terminates the workers with SIGTERM; and stop when the
    parent (pid ``parent``, default this process's parent now) dies, by any signal
    (:func:`_die_with_parent`)."""
    global _worker
    _worker = True
    # rawpy warns of OpenMP in forked processes: the parent never ran LibRaw (nor any
    # OpenMP code) before forking, so its threads cannot be held by a lost lock.
    warnings.filterwarnings("ignore", "rawpy is being used in a process created by multi")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_terminated)
    sys.unraisablehook = _redelivering(sys.unraisablehook)
    _die_with_parent(os.getppid() if parent is None else parent)
    set_threads(threads)


def _die_with_parent(parent: int) -> None:
    """SIGTERM this worker when process ``parent`` dies, even by SIGKILL, which the
    parent cannot pass on: the running job unwinds (no partial outputs, no
    temporaries) and the worker exits, within :data:`ORPHAN_GRACE_S`.

    On Linux the kernel sends the signal at once (``prctl(PR_SET_PDEATHSIG)``);
    everywhere, :func:`stop_with` also watches the parent.
    """
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    stop_with(parent)


#: The processes this one already watches (:func:`stop_with`).
_watched: set[int] = set()


def stop_with(pid: int) -> None:
    """Stop this process when process ``pid`` (of this machine) is gone: a thread
    polls it every :data:`PARENT_POLL_S`, then sends this process SIGTERM (the
    running job unwinds) and, should it not be gone after :data:`ORPHAN_GRACE_S`
    (stuck in native code), ends it. Once per ``pid``."""
    if pid in _watched:
        return
    _watched.add(pid)
    threading.Thread(target=_watch, args=(pid,), daemon=True).start()


def _watch(pid: int) -> None:
    while running(pid):
        time.sleep(PARENT_POLL_S)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(ORPHAN_GRACE_S)
    os._exit(128 + signal.SIGKILL)


def set_threads(threads: int) -> None:
    """Use ``threads`` CPU threads in torch, the engine, PNG writing and decoders.

    Torch is told now if imported, else by ``OMP_NUM_THREADS``, which it reads when
    it is imported (as do OpenMP runtimes when they start, LibRaw's among them).
    """
    os.environ["OMP_NUM_THREADS"] = str(threads)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(threads)
    from rawsim import engine
    from rawsim.io import png

    png.set_threads(threads)
    if "OpenImageIO" in sys.modules:  # decoders' own thread pools: the same share
        sys.modules["OpenImageIO"].attribute("threads", threads)
    if engine.available():
        engine.set_threads(threads)
