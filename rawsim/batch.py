"""Running a job over many files: discovery, output paths, per-file seeds, skipping,
sharding, parallel workers, failures and the summary.

The job itself is a plain function ``job(task, **kwargs) -> dict`` that knows nothing
of batches; it raises :class:`~rawsim.errors.RawsimError` for bad inputs. Every task
gets its outcome in a :class:`Result`; one failure never stops the others.
"""

from __future__ import annotations

import errno
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from multiprocessing import get_all_start_methods, get_context
from pathlib import Path, PurePosixPath
from typing import NamedTuple

from rawsim.errors import ParameterError, RawsimError
from rawsim.io import remote
from rawsim.io.atomic import remove_stale_temporaries
from rawsim.seeds import derive_seed

#: Exit statuses of the batch commands.
EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
#: The longest file name (bytes) of common file systems (ext4, XFS, APFS, NTFS).
NAME_MAX = 255
#: Seconds a terminated worker gets to remove its temporary files before it is killed.
WORKER_GRACE = 1.5
#: Seconds after which a signal that a finalizer swallowed is sent again.
REDELIVER_S = 0.01


class Interrupted(BaseException):
    """SIGINT or SIGTERM stopped the job; exit status 128 + ``signum`` (130, 143).

    A BaseException, like KeyboardInterrupt: no ``except Exception`` swallows it,
    and on its way out every atomic write removes its temporary file.
    """

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def _stop_on_signal(signum, frame) -> None:
    """The first SIGINT/SIGTERM stops the job; later ones wait for its cleanup (≤ 2 s)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    raise Interrupted(signum)


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
        signal.signal(signum, _worker_terminated if _worker else _stop_on_signal)
        again = threading.Timer(REDELIVER_S, os.kill, (os.getpid(), signum))
        again.daemon = True
        again.start()

    return hook


class stop_on_signals:
    """Context: SIGINT and SIGTERM raise :class:`Interrupted` in the main thread
    (again if a finalizer swallowed it: :func:`_redelivering`).

    Restores the previous handlers on exit. Does nothing outside the main thread
    (Python delivers signals only there).
    """

    def __enter__(self):
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


@dataclass(frozen=True)
class Task:
    """One input file and where its outputs go.

    Attributes:
        source: the input file.
        key: its path relative to the input root given on the command line (POSIX
            form); names outputs and seeds the file's randomness.
        outputs: output kind → path.
        seed: the file's seed, derived from the run's seed and ``key``.
    """

    source: Path
    key: str
    outputs: dict[str, Path]
    seed: int


@dataclass
class Result:
    """The outcome of one task: ``done``, ``skipped`` or ``failed``."""

    task: Task
    status: str
    message: str = ""
    record: dict = field(default_factory=dict)
    detail: str = ""
    seconds: float = 0.0


class Discovered(NamedTuple):
    """What :func:`discover` found.

    Attributes:
        found: sorted (path, key) pairs.
        missing: a failed :class:`Result` for each input that does not exist.
        ignored: files in the searched folders whose extension is not taken.
    """

    found: list[tuple[Path, str]]
    missing: list[Result]
    ignored: list[Path]


def discover(inputs: Sequence[str | Path], extensions: Iterable[str]) -> Discovered:
    """Find input files. Folders are searched recursively for ``extensions``; hidden
    files (and rawsim's temporaries) are left out, and files given by name are taken
    whatever their extension. Inputs may be fsspec URLs (:mod:`rawsim.io.remote`):
    their files are found as URLs (``str``), local ones as ``Path``."""
    exts = tuple(e.lower() for e in extensions)
    found: dict[Path | str, str] = {}
    missing, ignored = [], []
    for item in map(remote.localize, inputs):
        if remote.is_url(item):
            try:
                taken, skipped = remote.find(item, exts)
            except FileNotFoundError:
                message = f"{shown(item)}: no such file or folder (check the URL)"
                missing.append(Result(Task(item, item, {}, 0), "failed", message))
                continue
            for url, key in taken:
                found.setdefault(url, key)
            ignored.extend(skipped)
            continue
        path = Path(item)
        if path.is_dir():
            for p in sorted(path.rglob("*")):
                if p.name.startswith("."):
                    continue
                if p.is_symlink() and not p.exists() and p.suffix.lower() in exts:
                    message = f"{shown(p)}: broken symbolic link (its target is missing, or a loop)"
                    missing.append(
                        Result(Task(p, p.relative_to(path).as_posix(), {}, 0), "failed", message)
                    )
                elif not p.is_file():
                    continue
                elif p.suffix.lower() in exts:
                    found.setdefault(p, p.relative_to(path).as_posix())
                else:
                    ignored.append(p)
        elif path.exists():
            found.setdefault(path, path.name)
        else:
            what = "folder" if str(item).endswith(os.sep) or not path.suffix else "file"
            message = f"{shown(item)}: no such {what} (check the path)"
            missing.append(Result(Task(path, str(item), {}, 0), "failed", message))
    return Discovered(sorted(found.items(), key=lambda kv: (kv[1], str(kv[0]))), missing, ignored)


def shown(path: str | Path) -> str:
    """A path as messages print it: quoted (Python's escapes) if it holds control
    characters or bytes that are not UTF-8, so one message stays one line."""
    text = str(path)
    return text if text.isprintable() else repr(text)


def parse_shard(text: str | None, environ: Mapping[str, str] | None = None) -> tuple[int, int]:
    """Parse ``"K/N"`` (1-based K) into (K, N); None means the whole run (1/1).

    ``"auto"`` takes them from a Slurm array job's environment (``environ``,
    default ``os.environ``): K = (SLURM_ARRAY_TASK_ID − SLURM_ARRAY_TASK_MIN) /
    SLURM_ARRAY_TASK_STEP + 1 and N = SLURM_ARRAY_TASK_COUNT.
    """
    if not text:
        return 1, 1
    if text == "auto":
        return slurm_shard(os.environ if environ is None else environ)
    try:
        k, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise ParameterError(f"shard must look like K/N, e.g. 2/8; got {text!r}") from None
    if not 1 <= k <= n:
        raise ParameterError(f"shard K/N needs 1 ≤ K ≤ N, got {text!r}")
    return k, n


def slurm_shard(environ: Mapping[str, str]) -> tuple[int, int]:
    """(K, N) of this task of a Slurm array whose indices are a range MIN-MAX[:STEP]."""
    names = ("SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_MIN", "SLURM_ARRAY_TASK_COUNT")
    missing = [n for n in names if n not in environ]
    if missing:
        raise ParameterError(
            f"--shard auto needs a Slurm array job ({', '.join(missing)} not set); "
            "submit with sbatch --array, or give --shard K/N"
        )
    try:
        task, low, count = (int(environ[n]) for n in names)
        step = int(environ.get("SLURM_ARRAY_TASK_STEP", "1"))
    except ValueError:
        raise ParameterError(
            "--shard auto: the SLURM_ARRAY_TASK_* variables are not integers"
        ) from None
    k, rest = divmod(task - low, max(step, 1))
    if rest or not 0 <= k < count:
        raise ParameterError(
            f"--shard auto: task {task} is not the {count} indices from {low} by {step}; give "
            "the array as a range (--array=MIN-MAX[:STEP]) or use --shard K/N"
        )
    return k + 1, count


def plan(
    found: Sequence[tuple[Path, str]],
    out_dir: str | Path,
    suffixes: dict[str, str],
    seed: int,
    shard: tuple[int, int] = (1, 1),
) -> tuple[list[Task], list[Result]]:
    """Map inputs to tasks, mirroring each key's folders under ``out_dir``.

    ``suffixes`` maps output kinds to suffixes (``{"dng": ".dng"}``); ``out_dir`` may
    be a URL, and then the outputs are URLs (``str``). The shard keeps
    every N-th file of the sorted list, so shards of one run never overlap and
    together cover it. Returns the tasks and failed results for inputs whose outputs
    would overwrite an input, leave ``out_dir``, or take a name an earlier input's
    output has (of ``a.jpg`` and ``a.png``, the first in key order is done and the
    other fails, asking for a rename).
    """
    k, n = shard
    out_dir = remote.localize(out_dir)
    at_url = remote.is_url(out_dir)
    if not at_url:
        out_dir = Path(out_dir)
        root = out_dir.resolve()
    tasks, bad = [], {}
    for path, key in found:
        rel = PurePosixPath(key)
        stem = output_stem(rel.name)
        if at_url:
            folder = rel.parent.as_posix()
            outputs = {k: remote.join(out_dir, folder, stem + s) for k, s in suffixes.items()}
        else:
            outputs = {k: out_dir / rel.parent / (stem + s) for k, s in suffixes.items()}
        task = Task(path, key, outputs, derive_seed(seed, key))
        tasks.append(task)
        names = [PurePosixPath(str(p)).name for p in outputs.values()]
        if not at_url and any(not p.resolve().is_relative_to(root) for p in outputs.values()):
            bad[key] = f"its outputs would be outside {shown(out_dir)}: rename it"
        elif any(len(os.fsencode(name)) > NAME_MAX for name in names):
            longest = max(names, key=lambda name: len(os.fsencode(name)))
            bad[key] = (
                f"output name {shown(longest)} would be longer than the {NAME_MAX} bytes "
                "file systems allow: shorten the input's name"
            )
    owner: dict[Path | str, Task] = {}
    inputs = {_canonical(t.source) for t in tasks}
    for t in tasks:  # in key order: the first input to claim an output name keeps it
        for p in map(_canonical, t.outputs.values()):
            if p in inputs:
                bad.setdefault(t.key, f"refusing to write {shown(p)}: it is an input")
            first = owner.setdefault(p, t)
            if first is not t:
                bad.setdefault(
                    t.key,
                    f"output name clash: {shown(p)} is written for {shown(first.source)}; "
                    "rename one of them or give them to separate runs",
                )
    mine = [t for i, t in enumerate(tasks) if i % n == k - 1]
    failed = [Result(t, "failed", f"{shown(t.source)}: {bad[t.key]}") for t in mine if t.key in bad]
    return [t for t in mine if t.key not in bad], failed


def _canonical(location: Path | str) -> Path | str:
    """A file's location in one spelling: local paths resolved, URLs as given."""
    return location if remote.is_url(location) else Path(location).resolve()


def output_stem(name: str) -> str:
    """The outputs' name stem for an input ``name``: its stem, with ``_`` before a leading
    dot (``.png`` → ``_.png``, ``..png`` → ``_.``), so no output is hidden or a
    path component such as ``..``."""
    stem = Path(name).stem
    return f"_{stem}" if stem.startswith(".") or not stem else stem


def _run_one(job: Callable, task: Task, overwrite: bool, debug: bool, kwargs: dict) -> Result:
    """Run ``job`` on ``task``: skipped if all its outputs exist, refused if only some
    do (they are not a finished set of this command's: nothing is overwritten without
    ``--overwrite``). A job that fails or is interrupted leaves none of the outputs
    it had begun to write."""
    try:
        existing = {p for p in task.outputs.values() if remote.exists(p)}
    except Exception as err:  # OSError, or a remote file system's own errors
        return Result(task, "failed", f"{shown(task.source)}: cannot check its outputs: {err}")
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
        with remote.staged(task) as local:
            record = job(local, **kwargs)
    except BaseException as err:
        for p in task.outputs.values():  # the outputs this job had written so far
            if p not in existing:
                remote.remove(p)
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
    work before the pool starts. CUDA does not survive a fork, so with a GPU
    present the workers are spawned.
    """
    import torch

    if "fork" in get_all_start_methods() and not torch.cuda.is_available():
        return get_context("fork")
    return get_context("spawn")


#: Whether this process is a pool worker, and whether it is running a job now.
_worker = False
_in_job = False


def _worker_terminated(signum, frame) -> None:
    """SIGTERM in a worker: unwind the running job (its atomic writes remove their
    temporary files), then exit; an idle worker exits at once."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if _in_job:
        raise Interrupted(signum)
    os._exit(128 + signum)


def _init_worker(threads: int) -> None:
    """Give each worker its share of the cores, in torch and in the engine, so that
    jobs × threads ≤ cores; leave SIGINT (Ctrl-C reaches the whole process group)
    to the parent, which terminates the workers with SIGTERM."""
    global _worker
    _worker = True
    # rawpy warns of OpenMP in forked processes: the parent never ran LibRaw (nor any
    # OpenMP code) before forking, so its threads cannot be held by a lost lock.
    warnings.filterwarnings("ignore", "rawpy is being used in a process created by multi")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_terminated)
    sys.unraisablehook = _redelivering(sys.unraisablehook)
    set_threads(threads)


def set_threads(threads: int) -> None:
    """Use ``threads`` CPU threads in torch, the engine, PNG writing and decoders."""
    import torch

    from rawsim import engine
    from rawsim.io import png

    torch.set_num_threads(threads)
    png.set_threads(threads)
    if "OpenImageIO" in sys.modules:  # decoders' own thread pools: the same share
        sys.modules["OpenImageIO"].attribute("threads", threads)
    if engine.available():
        engine.set_threads(threads)


def run(
    tasks: Sequence[Task],
    job: Callable,
    *,
    jobs: int = 1,
    overwrite: bool = False,
    debug: bool = False,
    executor: str = "local",
    address: str | None = None,
    **kwargs,
) -> Iterator[Result]:
    """Run ``job`` on every task, yielding results as they finish.

    With ``jobs`` > 1, tasks run in that many worker processes, each with an equal
    share of the CPU threads. ``executor="ray"`` runs them as tasks of a Ray cluster
    instead (:mod:`rawsim.ray_executor`; ``address`` as ``ray.init`` takes it, None
    for a new local cluster). Results do not depend on ``jobs`` or the executor.
    Temporary files that killed runs left in the local output folders are removed
    first.
    """
    if jobs < 1:
        raise ParameterError(f"--jobs must be ≥ 1, got {jobs}")
    folders = {p.parent for t in tasks for p in t.outputs.values() if not remote.is_url(p)}
    for folder in folders:
        remove_stale_temporaries(folder)  # what killed runs left
    if executor == "ray":
        from rawsim import ray_executor

        try:
            yield from ray_executor.run(tasks, job, address, overwrite, debug, kwargs)
        finally:
            for folder in folders:  # those of workers killed mid-write
                remove_stale_temporaries(folder)
        return
    if executor != "local":
        raise ParameterError(f"executor must be local or ray, got {executor!r}")
    if jobs == 1 or len(tasks) <= 1:
        for t in tasks:
            yield _run_one(job, t, overwrite, debug, kwargs)
        return
    threads = max(1, (os.cpu_count() or 1) // jobs)
    pool = ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=_worker_context(),
        initializer=_init_worker,
        initargs=(threads,),
    )
    try:
        futures = {pool.submit(_run_one, job, t, overwrite, debug, kwargs): t for t in tasks}
        for fut in as_completed(futures):
            try:
                yield fut.result()
            except Exception as err:  # the worker died (killed, out of memory)
                task = futures[fut]
                yield Result(task, "failed", f"{task.source}: worker failed: {err}")
    except BaseException:  # interrupted (or the consumer stopped): no file starts any more
        _terminate(pool)
        for folder in folders:  # those of workers killed after the grace period
            remove_stale_temporaries(folder)
        raise
    pool.shutdown()


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Cancel the queued tasks and stop the workers: SIGTERM (they remove their
    temporary files and exit), SIGKILL for any still alive after :data:`WORKER_GRACE`."""
    workers = multiprocessing.active_children()
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in workers:
        proc.terminate()
    deadline = time.monotonic() + WORKER_GRACE
    for proc in workers:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.kill()
            proc.join()


@dataclass
class Summary:
    """Counts of a finished batch and its exit status."""

    done: int = 0
    skipped: int = 0
    failed: int = 0
    seconds: float = 0.0

    def add(self, result: Result) -> None:
        setattr(self, result.status, getattr(self, result.status) + 1)

    @property
    def exit_code(self) -> int:
        return EXIT_FAILED if self.failed else EXIT_OK

    def __str__(self) -> str:
        return (
            f"{self.done} done, {self.skipped} skipped, {self.failed} failed "
            f"in {self.seconds:.1f} s"
        )
