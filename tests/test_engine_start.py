"""How the engine starts: the cores it may use (cgroup quotas), and compiles said aloud."""

import logging
import os
import subprocess
import sys

import numba
import numpy as np
import pytest

import rawsim.engine
from rawsim.cores import cgroup_quota, usable_cores
from rawsim.engine import compile_log
from rawsim.engine.tiles import next_tile
from tests.conftest import ROOT


def _cgroup(tmp_path, membership: str, files: dict[str, str]):
    (tmp_path / "self").write_text(membership)
    for name, text in files.items():
        path = tmp_path / "fs" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path / "self", tmp_path / "fs"


@pytest.mark.parametrize(
    "membership, files, cores",
    [
        ("0::/\n", {"cpu.max": "max 100000\n"}, None),  # v2, no quota
        ("0::/\n", {"cpu.max": "200000 100000\n"}, 2),  # v2, 2 cores' worth
        ("0::/\n", {"cpu.max": "150000 100000\n"}, 2),  # 1.5 cores: rounded up
        ("0::/\n", {"cpu.max": "20000 100000\n"}, 1),  # a fifth of a core: still 1
        # v2: a parent's lower quota holds for its children
        (
            "0::/job/step\n",
            {"job/step/cpu.max": "400000 100000\n", "job/cpu.max": "100000 100000\n"},
            1,
        ),
        # v1: cpu controller, quota -1 is none
        (
            "4:cpu,cpuacct:/\n",
            {"cpu,cpuacct/cpu.cfs_quota_us": "-1\n", "cpu,cpuacct/cpu.cfs_period_us": "100000\n"},
            None,
        ),
        (
            "4:cpu,cpuacct:/\n",
            {
                "cpu,cpuacct/cpu.cfs_quota_us": "300000\n",
                "cpu,cpuacct/cpu.cfs_period_us": "100000\n",
            },
            3,
        ),
        ("0::/\n", {}, None),  # no cpu.max file (cpu controller not enabled)
    ],
)
def test_cgroup_quota(tmp_path, membership, files, cores):
    assert cgroup_quota(*_cgroup(tmp_path, membership, files)) == cores


def test_usable_cores_within_affinity():
    assert 1 <= usable_cores() <= len(os.sched_getaffinity(0))


def test_engine_threads_capped_by_usable_cores():
    rawsim.engine.configure()
    if "NUMBA_NUM_THREADS" not in os.environ:
        assert numba.get_num_threads() <= usable_cores()


def test_a_job_share_of_threads_keeps_the_fork_safe_layer():
    """A batch worker sets its threads before importing any kernel: numba starts its
    threads then, and must start them in the fork-safe layer, not GNU OpenMP."""
    code = (
        "from rawsim.run.jobs import set_threads; set_threads(1); import numba; "
        "print(numba.threading_layer(), numba.get_num_threads())"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING")}
    said = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert said.returncode == 0, said.stderr
    layer, threads = said.stdout.split()
    assert layer in ("tbb", "workqueue") and threads == "1"


def test_compile_is_logged_once_per_kernel(caplog):
    """A rawsim kernel's compile (a cache miss) logs its start, with how to compile
    ahead, and its end with the seconds; a second call (compiled) logs nothing."""

    def probe(x):
        return x + 1

    probe.__qualname__ = "probe"
    probe.__module__ = "rawsim.engine.probe"  # as if rawsim's: only those are logged
    kernel = numba.njit(probe)  # no cache: a compile every test run
    rawsim.engine.configure()
    compile_log._listener._announced = False
    with caplog.at_level(logging.WARNING, logger="rawsim.engine"):
        assert kernel(1) == 2
        assert kernel(2) == 3
    lines = [r.getMessage() for r in caplog.records]
    assert "rawsim compile" in lines[0]
    assert lines[1] == "compiling engine.probe.probe …"
    assert lines[2].startswith("compiled engine.probe.probe in ") and lines[2].endswith(" s")
    assert len(lines) == 3


def test_foreign_kernels_are_not_logged(caplog):
    kernel = numba.njit(lambda x: x * 2)
    rawsim.engine.configure()
    with caplog.at_level(logging.WARNING, logger="rawsim.engine"):
        assert kernel(2) == 4
    assert not caplog.records


@pytest.mark.slow
def test_first_run_with_empty_cache_says_it_compiles(tmp_path):
    """A user's first command on an empty numba cache says on stderr that it compiles."""
    frames = tmp_path / "frames"
    frames.mkdir()
    from rawsim.io.images import write_image

    for i in range(2):
        write_image(frames / f"{i}.png", np.full((16, 16, 3), 60 * (i + 1), np.uint8), "png")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    cmd = [sys.executable, "-m", "rawsim_cli.main", "events", str(frames), "--fps", "100"]
    cmd += ["-o", str(tmp_path / "ev")]
    first = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=ROOT)
    assert first.returncode == 0, first.stderr
    assert "compiling the engine's kernels for this CPU" in first.stderr
    assert "rawsim compile" in first.stderr
    again = subprocess.run([*cmd, "--overwrite"], env=env, capture_output=True, text=True, cwd=ROOT)
    assert again.returncode == 0, again.stderr
    assert "compiling" not in again.stderr


def test_compile_runs_each_task_once_after_the_tasks_it_needs(monkeypatch):
    """``rawsim compile``'s schedule: every task once, none before the tasks whose
    DNGs or kernels it needs have ended, at most ``jobs`` at a time."""
    import threading
    import time

    from rawsim_cli import compile as rc

    names = [t[0] for t in rc.TASKS]
    assert len(set(names)) == len(names)
    assert all(set(needs) <= set(names) for _, needs, _ in rc.TASKS)
    events, lock, running = [], threading.Lock(), [0]
    needs = {args: need for _, need, args in rc.TASKS}
    what = {args: name for name, _, args in rc.TASKS}

    def fake_run(args, folders):
        with lock:
            running[0] += 1
            assert running[0] <= 2
            events.append(("start", what[args], needs[args]))
        time.sleep(0.01)
        with lock:
            running[0] -= 1
            events.append(("end", what[args], None))
        return 0.01, ["engine.x.kernel"]

    monkeypatch.setattr(rc, "_run", fake_run)
    ended = [w for w, _, _ in rc._schedule({}, 2)]
    assert sorted(ended) == sorted(names)
    for i, (kind, name, need) in enumerate(events):
        for task in need if kind == "start" else ():
            assert ("end", task, None) in events[:i], f"{name} started before {task} ended"


def test_byte_compile_writes_bytecode_where_python_would_not(tmp_path, monkeypatch):
    """``rawsim compile`` writes the bytecode of a package's modules even where
    ``PYTHONDONTWRITEBYTECODE`` holds, once: a second run finds it up to date."""
    from rawsim_cli.compile import byte_compile

    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    for name in ("pkg/__init__.py", "pkg/a.py", "pkg/sub/__init__.py", "pkg/sub/b.py"):
        (tmp_path / name).write_text("X = 1\n")
    assert byte_compile(1, [tmp_path / "pkg"]) == 4
    assert len(list((tmp_path / "pkg").rglob("__pycache__/*.pyc"))) == 4
    assert byte_compile(1, [tmp_path / "pkg"]) == 0


def test_lean_numba_start_hides_only_while_numba_imports():
    """The command-line start imports numba without SciPy, cffi or YAML, and each of
    them imports normally afterwards."""
    code = (
        "import sys, rawsim.engine as e; e.lean_start = True; e.available(); "
        "print(sorted(m for m in ('scipy', 'cffi', 'yaml') if m in sys.modules)); "
        "import scipy.linalg, cffi, yaml; print('ok')"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout.split()
    assert out == ["[]", "ok"]


@numba.njit(parallel=True)
def _take_all(n, threads):
    counter = np.zeros(1, np.int64)
    seen = np.zeros(n, np.int64)
    owner = np.full(n, -1, np.int64)
    for t in numba.prange(threads):
        while True:
            i = next_tile(counter)
            if i >= n:
                break
            seen[i] += 1  # no race: each index is taken once
            owner[i] = t
    return seen, owner


def test_next_tile_hands_out_every_tile_once():
    """The engine's tile counter: every index exactly once across the threads, and a
    thread that asks again gets the next one (so a slowed thread takes fewer)."""
    seen, owner = _take_all(20_000, 2)
    assert (seen == 1).all()
    assert (owner >= 0).all()
    seen, _ = _take_all(3, 2)  # fewer tiles than threads
    assert (seen == 1).all()
