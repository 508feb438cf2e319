"""The CPU cores this process may use: its CPU affinity, capped by a cgroup CPU quota.

``os.cpu_count()`` counts the machine's cores. A container or a batch job (Docker's
``--cpus``, Kubernetes limits, Slurm under cgroups) may allow fewer: its affinity
(``taskset``, cpusets), or a quota of CPU time per period (``cpu.max`` in cgroup v2,
``cpu.cfs_quota_us`` in v1) that leaves every core visible. More compute threads
than the quota allows are descheduled in turn at each period's end, and a
parallel loop waits for its slowest thread: numba's and the PNG writer's thread
counts come from here.
"""

from __future__ import annotations

import math
import os
from functools import cache
from pathlib import Path


@cache
def usable_cores() -> int:
    """Cores this process may keep busy: its affinity, capped by its cgroup's quota."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        cores = os.cpu_count() or 1
    quota = cgroup_quota(Path("/proc/self/cgroup"), Path("/sys/fs/cgroup"))
    return max(1, min(cores, quota)) if quota else cores


def cgroup_quota(membership: Path, root: Path) -> int | None:
    """The CPU quota, in whole cores rounded up, of the cgroup named in
    ``membership`` (``/proc/self/cgroup``) and of its ancestors, the lowest; None
    where none is set or the files cannot be read.

    cgroup v2 (one ``0::/path`` line): ``cpu.max`` (``"max 100000"`` or ``"QUOTA
    PERIOD"`` µs) in each folder from ``root/path`` up to ``root``. cgroup v1 (a
    ``cpu`` controller line): ``cpu.cfs_quota_us`` (-1: none) over
    ``cpu.cfs_period_us`` in ``root/cpu`` (or ``root/cpu,cpuacct``) at the path, or
    at its root where a container mounts only its own group.
    """
    try:
        lines = membership.read_text().splitlines()
    except OSError:
        return None
    quotas = []
    for line in lines:
        _, controllers, path = line.split(":", 2)
        rel = Path(path.lstrip("/"))
        if controllers == "":  # v2
            folder = root / rel
            while True:
                quotas.append(_v2_quota(folder / "cpu.max"))
                if folder == root:
                    break
                folder = folder.parent
        elif "cpu" in controllers.split(","):  # v1
            for mount in ("cpu", "cpu,cpuacct", "cpuacct,cpu"):
                for folder in (root / mount / rel, root / mount):
                    quotas.append(_v1_quota(folder))
    quotas = [q for q in quotas if q is not None]
    return min(quotas) if quotas else None


def _v2_quota(path: Path) -> int | None:
    try:
        quota, period = path.read_text().split()
    except (OSError, ValueError):
        return None
    return None if quota == "max" else _cores(int(quota), int(period))


def _v1_quota(folder: Path) -> int | None:
    try:
        quota = int((folder / "cpu.cfs_quota_us").read_text())
        period = int((folder / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return None if quota <= 0 else _cores(quota, period)


def _cores(quota: int, period: int) -> int | None:
    return max(1, math.ceil(quota / period)) if period > 0 else None
