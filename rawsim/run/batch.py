"""Running a job over many files: discovery, output paths, per-file seeds, skipping,
sharding, parallel workers, failures and the summary.

The job itself is a plain function ``job(task, **kwargs) -> dict`` that knows nothing
of batches; it raises :class:`~rawsim.errors.RawsimError` for bad inputs. Every task
gets its outcome in a :class:`Result`; one failure never stops the others.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import NamedTuple

from rawsim.cores import usable_cores
from rawsim.errors import ParameterError, shown
from rawsim.io import remote
from rawsim.io.atomic import remove_stale_temporaries
from rawsim.io.task import Task
from rawsim.noise.seeds import derive_seed
from rawsim.run.jobs import (
    Interrupted,
    Result,
    _init_worker,
    _run_one,
    _worker_context,
)

#: Exit statuses of the batch commands.
EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


#: The longest file name (bytes) of common file systems (ext4, XFS, APFS, NTFS).
NAME_MAX = 255


#: Seconds a terminated worker gets to remove its temporary files before it is killed.
WORKER_GRACE = 1.5


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
    instead (:mod:`rawsim.run.ray_executor`; ``address`` as ``ray.init`` takes it, None
    for a new local cluster). Results do not depend on ``jobs`` or the executor.
    Temporary files that killed runs left in the local output folders are removed
    first, and again at the end.
    """
    if jobs < 1:
        raise ParameterError(f"--jobs must be ≥ 1, got {jobs}")
    if executor not in ("local", "ray"):
        raise ParameterError(f"executor must be local or ray, got {executor!r}")
    folders = {p.parent for t in tasks for p in t.outputs.values() if not remote.is_url(p)}
    for folder in folders:
        remove_stale_temporaries(folder)  # what killed runs left
    try:
        if executor == "ray":
            from rawsim.run import ray_executor

            yield from ray_executor.run(tasks, job, address, overwrite, debug, kwargs)
        elif jobs == 1 or len(tasks) <= 1:
            yield from _run_local(tasks, job, overwrite, debug, kwargs)
        else:
            yield from _run_pool(tasks, job, jobs, overwrite, debug, kwargs)
    finally:
        # Again at the end, stopped or not: those of workers killed mid-write, and
        # those of a killed run whose processes were still exiting at the start.
        for folder in folders:
            remove_stale_temporaries(folder)


def _run_local(tasks, job, overwrite, debug, kwargs) -> Iterator[Result]:
    """:func:`run` in this process. A job with a ``read_ahead(task, **kwargs)`` is told
    the next task to run before each task starts, so that it can read that input in
    a thread while this one runs (:mod:`rawsim.io.readahead`); not a remote input,
    which the task's run downloads first."""
    read_ahead = getattr(job, "read_ahead", None)
    ahead = told = 0  # the next task to run after this one (skipped ones passed by)
    for i, t in enumerate(tasks):
        if read_ahead is not None:
            ahead = max(ahead, i + 1)
            while ahead < len(tasks) and not overwrite and _outputs_exist(tasks[ahead]):
                ahead += 1
            if told < ahead < len(tasks) and not remote.is_url(tasks[ahead].source):
                read_ahead(tasks[ahead], **kwargs)
                told = ahead
        yield _run_one(job, t, overwrite, debug, kwargs)


def _outputs_exist(task: Task) -> bool:
    """Whether all of a task's outputs exist (it will be skipped): not worth reading
    ahead. Remote outputs count as absent (no round trip to ask)."""
    return all(not remote.is_url(p) and Path(p).exists() for p in task.outputs.values())


def _run_pool(tasks, job, jobs, overwrite, debug, kwargs) -> Iterator[Result]:
    """:func:`run` in ``jobs`` worker processes (each with its share of the threads)."""
    threads = max(1, usable_cores() // jobs)
    pool = ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=_worker_context(),
        initializer=_init_worker,
        initargs=(threads, os.getpid()),
    )
    futures: dict = {}
    given = set()
    try:
        futures = {pool.submit(_run_one, job, t, overwrite, debug, kwargs): t for t in tasks}
        for fut in as_completed(futures):
            given.add(fut)
            try:
                yield fut.result()
            except Exception as err:  # the worker died (killed, out of memory)
                task = futures[fut]
                yield Result(task, "failed", f"{task.source}: worker failed: {err}")
    except BaseException as stop:  # interrupted (or the consumer stopped): no file starts
        if isinstance(stop, Interrupted):  # what workers finished before it, not yet given
            stop.finished = [
                f.result()
                for f in futures
                if f not in given and f.done() and not f.cancelled() and f.exception() is None
            ]
        _terminate(pool)
        raise
    pool.shutdown()


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Cancel the queued tasks and stop the workers: SIGTERM (they remove their
    temporary files and exit), SIGKILL for any still alive after :data:`WORKER_GRACE`.
    Then wait (as long again at most) for the pool's manager thread to close its
    pipes: left running, it races the interpreter's exit, whose wake-up call can
    write to a pipe it is closing and print ``OSError: [Errno 9] Bad file
    descriptor`` after the job's summary (CPython 3.11)."""
    workers = multiprocessing.active_children()
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() drops it
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in workers:
        proc.terminate()
    deadline = time.monotonic() + WORKER_GRACE
    for proc in workers:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.kill()
            proc.join()
    if manager is not None:
        manager.join(WORKER_GRACE)


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
