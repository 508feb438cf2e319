"""Running a batch on a Ray cluster (``--executor ray``).

Tasks are grouped into bundles of about equal cost (input bytes plus a fixed
overhead per file), several per cluster CPU so that the load balances; each bundle
is a Ray generator task that runs :func:`rawsim.run.jobs._run_one` on its files in
order and streams back one :class:`~rawsim.run.jobs.Result` per file, so progress,
messages and ``--json`` records arrive as files finish, as in a local run.

A bundle whose worker dies (killed, out of memory, node lost) is resubmitted
without the files it had finished. The file it was working on is retried once
(its outputs are atomic, so nothing partial is left to trip the retry); if its
worker dies again it is reported as failed. A retry that finds the file's outputs
in place, written since the run began, reports it done: the worker died between
putting them in place and reporting them. The outputs do not depend on where a
file ran: byte-identical to a local ``--jobs 1`` run.

Every node needs rawsim installed and the inputs and outputs at the same paths
(a shared file system) or at URLs (:mod:`rawsim.io.remote`).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence

from rawsim.errors import ParameterError, shown
from rawsim.io import remote
from rawsim.io.atomic import HOST
from rawsim.io.task import Task
from rawsim.run.jobs import Result, _run_one, set_threads, stop_with

_log = logging.getLogger(__name__)

#: Times a file is retried after its worker died.
RETRIES = 1
#: Cost of a file beyond its bytes (decoding, set-up, writing its sidecar): bytes.
FILE_OVERHEAD = 256 * 1024
#: Smallest bundle worth a Ray task (its scheduling costs a few milliseconds): bytes.
MIN_BUNDLE = 8 * 1024 * 1024
#: Bundles per cluster CPU, for load balance.
BUNDLES_PER_CPU = 4


def _ray():
    try:
        import ray
    except ImportError:
        raise ParameterError(
            "--executor ray needs Ray: pip install 'rawsim[ray]' (on every node of the cluster)"
        ) from None
    return ray


def cost(task: Task) -> int:
    """Estimated cost of a task: its input's size (0 for URLs) + :data:`FILE_OVERHEAD`."""
    size = 0
    if not remote.is_url(task.source):
        try:
            size = os.path.getsize(task.source)
        except OSError:
            pass  # its job reports it
    return size + FILE_OVERHEAD


def bundles(tasks: Sequence[Task], cpus: int) -> list[list[Task]]:
    """Consecutive runs of ``tasks`` of about equal cost: :data:`BUNDLES_PER_CPU` per
    CPU, each of at least :data:`MIN_BUNDLE` unless that would leave CPUs idle."""
    costs = [cost(t) for t in tasks]
    total = sum(costs)
    target = max(total // (cpus * BUNDLES_PER_CPU), min(MIN_BUNDLE, total // cpus), 1)
    out, current, total = [], [], 0
    for task, c in zip(tasks, costs, strict=True):
        current.append(task)
        total += c
        if total >= target:
            out.append(current)
            current, total = [], 0
    return out + [current] if current else out


def _run_bundle(tasks, shared, cwd, driver) -> Iterator[Result]:
    """The Ray task: one CPU thread, the driver's working folder (relative paths
    mean the same on a shared file system), then each file in order. ``shared``
    is (job, overwrite, debug, kwargs), stored once in the object store.
    ``driver`` (host, pid) of a run that started this cluster itself: the task
    stops when that process dies, whatever killed it (:func:`stop_with`)."""
    job, overwrite, debug, kwargs = shared
    if driver is not None and driver[0] == HOST:
        stop_with(driver[1])
    set_threads(1)
    if os.path.isdir(cwd):
        os.chdir(cwd)
    for task in tasks:
        yield _run_one(job, task, overwrite, debug, kwargs)


def _done_before_it_died(result: Result, began: float) -> Result:
    """A retried file "skipped" because its outputs exist: done, if they were written
    since this run began (the worker that died had put them in place but not yet
    reported them). Outputs at URLs, or older ones, leave it skipped."""
    try:
        paths = list(result.task.outputs.values())
        if any(remote.is_url(p) or os.stat(p).st_mtime < began for p in paths):
            return result
    except OSError:
        return result
    return Result(result.task, "done")


def run(
    tasks: Sequence[Task],
    job: Callable,
    address: str | None,
    overwrite: bool,
    debug: bool,
    kwargs: dict,
) -> Iterator[Result]:
    """Run ``job`` on ``tasks`` on the Ray cluster at ``address`` (None: start a local
    one for this run; ``"auto"``: the one this machine belongs to); yield results as
    files finish. An interruption cancels the bundles (their jobs remove their
    temporary files) and stops a cluster this run started."""
    ray = _ray()
    if not tasks:
        return
    began = time.time()
    started = not ray.is_initialized()
    if started:
        if not debug:  # Ray's own notices (a local cluster started, token set-up)
            logging.getLogger("ray").setLevel(logging.ERROR)
        try:
            ray.init(
                address=address,
                include_dashboard=False,
                log_to_driver=debug,
                logging_level="ERROR",
                configure_logging=False,
            )
        except (ConnectionError, RuntimeError) as err:
            raise ParameterError(
                f"cannot connect to the Ray cluster at {address}: "
                f"{str(err).splitlines()[0]} (check the address; a cluster with token "
                "authentication also needs RAY_AUTH_MODE=token and its token)"
            ) from None
    cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
    remote_bundle = ray.remote(num_cpus=1, max_retries=0)(_run_bundle)
    shared = ray.put((job, overwrite, debug, kwargs))
    cwd = os.getcwd()
    # A cluster started for this run lives on this machine and dies with it.
    driver = (HOST, os.getpid()) if started and address is None else None
    pending: dict = {}  # running generator → its files not yet reported, in order
    attempts: dict[str, int] = {}

    def submit(group: list[Task]) -> None:
        pending[remote_bundle.remote(group, shared, cwd, driver)] = list(group)

    try:
        for group in bundles(tasks, cpus):
            submit(group)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for gen in ready:
                left = pending[gen]
                try:
                    result = ray.get(next(gen))
                except StopIteration:
                    del pending[gen]
                    continue
                except ray.exceptions.RayTaskError as err:  # not the job: rawsim itself
                    del pending[gen]
                    reason = str(err.cause if err.cause is not None else err).splitlines()[-1]
                    for task in left:
                        yield Result(task, "failed", f"{shown(task.source)}: Ray task: {reason}")
                    continue
                except ray.exceptions.RayError as err:  # the worker or its node died
                    del pending[gen]
                    first = left[0]
                    attempts[first.key] = attempts.get(first.key, 0) + 1
                    if attempts[first.key] > RETRIES:
                        reason = type(err).__name__
                        yield Result(
                            first,
                            "failed",
                            f"{shown(first.source)}: its Ray worker died {attempts[first.key]} "
                            f"times ({reason}: killed, or out of memory?)",
                        )
                        left = left[1:]
                    else:
                        _log.warning(
                            "%s: its Ray worker died (%s); retrying it",
                            shown(first.source),
                            type(err).__name__,
                        )
                    if left:
                        submit(left)
                    continue
                left.pop(0)
                if result.status == "skipped" and attempts.get(result.task.key):
                    result = _done_before_it_died(result, began)
                yield result
    except BaseException:
        for gen in pending:
            ray.cancel(gen)
        raise
    finally:
        if started:
            ray.shutdown()
