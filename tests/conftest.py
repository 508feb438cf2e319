"""Shared fixtures: test data location, dtype tolerances, small helpers."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
#: Real test files vendored in the repository (see tests/data/SOURCES.md).
DATA = ROOT / "tests" / "data"
PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
#: Absolute tolerance of round trips per dtype.
TOL = {torch.float32: 2e-5, torch.float64: 1e-10}


def pytest_configure(config):
    """Under pytest-xdist, each worker keeps its share of the cores busy, as each of
    rawsim's ``--jobs`` workers does (:func:`rawsim.run.jobs.set_threads`: torch, the
    engine, and ``OMP_NUM_THREADS`` for the commands a test starts). Two workers of
    two OpenMP threads each on two cores wait on each other's spinning threads: the
    suite took a quarter longer."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if "PYTEST_XDIST_WORKER" in os.environ and workers > 1:
        from rawsim.cores import usable_cores
        from rawsim.run.jobs import set_threads

        set_threads(max(1, usable_cores() // workers))


@contextmanager
def numba_threads(threads: int):
    """Run the engine's parallel loops on ``threads`` threads inside the block."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def thread_counts() -> list[int]:
    """One thread, and every thread numba may start: the counts a parallel loop's
    result must not depend on (whatever share of the cores this process keeps)."""
    import numba

    return sorted({1, numba.config.NUMBA_NUM_THREADS})


def pytest_collection_modifyitems(config, items):
    if not DATA.is_dir():
        raise pytest.UsageError(f"test data not found at {DATA} (it is part of the repository)")


@pytest.fixture(autouse=True)
def _seeded_global_rngs():
    """Each test draws from torch's and NumPy's global generators from the same state,
    whatever ran before it in its process: a test's inputs do not depend on the tests
    selected (``-m``, ``-k``) or on how pytest-xdist shares modules among workers."""
    torch.manual_seed(0)
    np.random.seed(0)


#: Test modules that start Ray. Under pytest-xdist (``-n 2 --dist loadfile``: each
#: module whole on one worker) they take turns: the cluster fixture's
#: ``ray stop --force`` ends every Ray process on the machine, and a run without
#: ``--address`` joins the latest cluster started.
RAY_MODULES = {"test_cluster", "test_sigkill"}


@pytest.fixture(scope="module", autouse=True)
def _one_ray_module_at_a_time(request, tmp_path_factory):
    if "PYTEST_XDIST_WORKER" not in os.environ:
        yield
        return
    if request.module.__name__.rsplit(".", 1)[-1] not in RAY_MODULES:
        yield
        return
    import fcntl

    # the workers' base folders (popen-gw0, ...) share their parent, one per run
    with open(tmp_path_factory.getbasetemp().parent / "ray.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        yield


@pytest.fixture(params=PATTERNS)
def pattern(request) -> str:
    return request.param


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request):
    return request.param


@pytest.fixture
def data() -> Path:
    return DATA


@pytest.fixture
def rng() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(peak**2 / mse)


def require_tool(name: str) -> str:
    """Path of an external tool; the test fails (not skips) on CI if it is missing."""
    path = shutil.which(name)
    if path is None:
        import os

        if os.environ.get("CI"):
            pytest.fail(f"{name} is not installed (.ci/run installs it)")
        pytest.skip(f"{name} not installed")
    return path


def cpsnr(y: torch.Tensor, x: torch.Tensor, border: int = 10) -> float:
    """CPSNR on the 8-bit scale, ``border`` pixels cropped (the standard demosaic test)."""
    a = (y.clamp(0, 1) * 255).round()[..., border:-border, border:-border].double()
    b = (x * 255).round()[..., border:-border, border:-border].double()
    return float(10 * torch.log10(255**2 / ((a - b) ** 2).mean()))


def libraw_linear(path, algorithm) -> torch.Tensor:
    """LibRaw's demosaic (a ``rawpy.DemosaicAlgorithm``) of a raw in raw colour, linear,
    unscaled: (1, 3, H, W) in [0, 1]."""
    import rawpy

    with rawpy.imread(str(path)) as raw:
        y = raw.postprocess(
            demosaic_algorithm=algorithm,
            output_color=rawpy.ColorSpace.raw,
            gamma=(1, 1),
            no_auto_bright=True,
            user_wb=[1, 1, 1, 1],
            output_bps=16,
            user_flip=0,
            adjust_maximum_thr=0,
        )
    return torch.from_numpy(y.astype(np.float32) / 65535).permute(2, 0, 1)[None]


def simulated_raw(data: np.ndarray, profile, iso: float, path: str = "<simulated>"):
    """A :class:`~rawsim.io.raw.RawImage` of a simulated mosaic ``data`` (H, W) uint16 with
    ``profile``'s CFA, levels, make and model, as calibrate reads a real raw."""
    from rawsim.io.raw import RawImage

    return RawImage(
        data=data,
        cfa=profile.cfa,
        black_level=np.full(profile.cfa.period, profile.black_level),
        white_level=profile.white_level,
        as_shot_wb=None,
        daylight_wb=None,
        xyz_to_camera=None,
        camera_to_srgb=None,
        orientation=1,
        iso=iso,
        make=profile.make,
        model=profile.model,
        path=path,
    )


def installed_command_imports(*args: str) -> set[str]:
    """Run ``rawsim ARGS`` through the installed console script (as a user's shell
    does: the script enters through ``main``) under ``-X importtime``; assert it
    succeeded and return the names of the modules it imported."""
    code = (
        "import sys\n"
        "from importlib.metadata import entry_points\n"
        "(script,) = entry_points(group='console_scripts', name='rawsim')\n"
        f"sys.argv = ['rawsim', *{list(map(str, args))!r}]\n"
        "sys.exit(script.load()())\n"
    )
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return {line.rsplit("|", 1)[-1].strip() for line in done.stderr.splitlines()}
