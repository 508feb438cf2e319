"""Parallel processes on one cache: a kernel is compiled, and said, once; a killed
compiler holds nobody up (rawsim.engine.compile_lock)."""

import os
import signal
import subprocess
import sys
import time

import pytest

from rawsim.engine.compile_lock import held
from tests.conftest import ROOT

pytest.importorskip("fcntl")

#: A cached kernel (a prange loop: a second or so to compile), loaded by :data:`PROBE`
#: as the module ``rawsim.engine.probe``: locked and logged as rawsim's.
KERNEL = """
import numba
import numpy as np


def probe(x):
    out = np.empty_like(x)
    for i in numba.prange(x.shape[0]):
        out[i] = np.sqrt(x[i]) * 2.0 + np.sin(x[i])
    return out
"""

#: A process that compiles :data:`KERNEL` (file ``argv[3]``) when the file ``argv[1]``
#: appears, once it has made ``argv[2]``.
PROBE = """
import sys, time, types
from pathlib import Path

import numba
import numpy as np

import rawsim.engine

rawsim.engine.configure()
module = types.ModuleType("rawsim.engine.probe")
sys.modules[module.__name__] = module  # importable: the cache's loader imports it
exec(compile(Path(sys.argv[3]).read_text(), sys.argv[3], "exec"), module.__dict__)
kernel = numba.njit(parallel=True, cache=True)(module.probe)
Path(sys.argv[2]).touch()
while not Path(sys.argv[1]).exists():
    time.sleep(0.005)
kernel(np.ones(8))
print("done")
"""


def _hold(path):
    """A process that holds the lock on ``path`` until killed (it says when it has it)."""
    code = (
        "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); "
        "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE)
    assert proc.stdout.readline() == b"held\n"
    return proc


def test_parallel_processes_compile_a_kernel_once_and_say_it_once(tmp_path):
    script, kernel = tmp_path / "probe.py", tmp_path / "probe_kernel.py"
    script.write_text(PROBE)
    kernel.write_text(KERNEL)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(ROOT))
    go = tmp_path / "go"
    with open(tmp_path / "stderr", "ab") as err:  # one stream for all, as a shared terminal
        procs = [
            subprocess.Popen(
                [sys.executable, script, go, tmp_path / f"ready{i}", kernel],
                env=env,
                stdout=subprocess.PIPE,
                stderr=err,
            )
            for i in range(3)
        ]
        deadline = time.monotonic() + 120
        while not all((tmp_path / f"ready{i}").exists() for i in range(3)):
            assert time.monotonic() < deadline and all(p.poll() is None for p in procs)
            time.sleep(0.01)
        go.touch()  # all three call the kernel at once
        outs = [p.communicate(timeout=300)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs) and outs == [b"done\n"] * 3
    lines = (tmp_path / "stderr").read_text().splitlines()
    said = [line for line in lines if "engine.probe.probe" in line]
    assert [line.split(" in ")[0] for line in said] == [
        "compiling engine.probe.probe …",
        "compiled engine.probe.probe",
    ], lines
    assert len([line for line in lines if "'rawsim compile'" in line]) == 1, lines
    assert list((tmp_path / "cache").rglob("*.lock"))  # where the lock was taken


def test_a_killed_holder_frees_the_lock_at_once(tmp_path):
    path = str(tmp_path / "kernel.lock")
    holder = _hold(path)
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    started = time.monotonic()
    with held(path, wait=30):
        assert time.monotonic() - started < 1


def test_a_stuck_holder_is_waited_for_at_most_the_wait(tmp_path):
    path = str(tmp_path / "kernel.lock")
    holder = _hold(path)
    try:
        started = time.monotonic()
        with held(path, wait=0.3):  # then the block runs unlocked
            waited = time.monotonic() - started
        assert 0.3 <= waited < 5
    finally:
        holder.kill()
        holder.wait()
