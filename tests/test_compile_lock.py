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


#: A DataLoader with 2 workers over ``argv[1]``'s photos, for a Bayer sensor.
LOADER = """
import sys

import torch

import rawsim

sensor = rawsim.RGBSensor.from_profile("sony_a7s2")
data = rawsim.UnprocessDataset(sys.argv[1], sensor, crop=64, iso=1600, seed=3)
loader = torch.utils.data.DataLoader(data, batch_size=1, num_workers=2)
print(sum(batch["noisy"].shape[0] for batch in loader))
"""


@pytest.mark.slow
def test_a_dataloader_compiles_nothing_after_rawsim_compile(tmp_path, monkeypatch):
    """After what ``rawsim compile`` runs for UnprocessDataset (its Python API task, in
    an empty cache), a DataLoader's 2 workers over other photos (8-bit, 16-bit, EXR)
    compile no kernel: the task's arrays have the Dataset's types and layouts."""
    import shutil

    from rawsim_cli import compile as rc

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    folders = {"in": tmp_path / "in", "out": tmp_path / "out"}
    rc._inputs(folders["in"])
    (args,) = [args for _, _, args in rc.TASKS if args.startswith("api dataset ")]
    _, kernels = rc._run(args, folders)
    assert "engine.unprocess.unprocess_kernel" in kernels  # compiled into the empty cache
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("srgb/rocket.jpg", "srgb16/painted_figure_16bit.tif", "exr/cannon_half_b44.exr"):
        shutil.copy(ROOT / "tests" / "data" / name, photos)
    script = tmp_path / "loader.py"
    script.write_text(LOADER)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    run = subprocess.run(
        [sys.executable, script, photos], env=env, capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["3"]
    assert "compiling" not in run.stderr, run.stderr
