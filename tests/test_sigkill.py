"""SIGKILL, which no process can catch: a rerun finishes what a killed run left, and
pool workers never outlive a killed parent. Real subprocesses, real SIGKILL."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import OpenImageIO as oiio
import pytest

from rawsim.io import outputs
from tests.conftest import DATA
from tests.test_cli import digest
from tests.test_signals import children, running

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc"),
]

FILES = 12
#: The CLI with a hook that holds each output set half in place: after every rename,
#: the job sleeps, so a kill lands between a file's first and last rename.
SLOW_RENAMES = """
import sys, time
import rawsim.io.outputs as o
place = o._place
def slow(tmp, path):
    place(tmp, path)
    time.sleep(0.4)
o._place = slow
from rawsim_cli.main import cli
cli()
"""
#: The CLI with each job slowed down (the decode sleeps), so workers are busy.
SLOW_JOBS = """
import time
import rawsim.pipelines.unprocess as u
read = u.read_image
def slow(path):
    time.sleep(1.0)
    return read(path)
u.read_image = slow
from rawsim_cli.main import cli
cli()
"""
CLI = "from rawsim_cli.main import cli; cli()"


def args(inputs: Path, out: Path) -> list[str]:
    return ["unprocess", str(inputs), "-o", str(out), "-p", "sony_a7s2", "--iso", "800"] + [
        "--clean",
        "--seed",
        "9",
        "--jobs",
        "2",
    ]


def run(code: str, inputs: Path, out: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, "-c", code, *args(inputs, out)]
    return subprocess.run(command, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """Small photos (crops of a vendored one), so that a batch is quick."""
    root = tmp_path_factory.mktemp("sigkill") / "in"
    root.mkdir()
    photo = oiio.ImageBuf(str(DATA / "srgb" / "chelsea.png"))
    for i in range(FILES):
        crop = oiio.ImageBufAlgo.cut(photo, oiio.ROI(8 * i, 8 * i + 96, 0, 64))
        assert crop.write(str(root / f"p{i:02d}.png"))
    return root


@pytest.fixture(scope="module")
def reference(inputs, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("reference")
    done = run(CLI, inputs, out)
    assert done.returncode == 0, done.stderr
    return digest(out)


def partial_sets(out: Path) -> list[str]:
    """Stems whose outputs are only partly in place."""
    stems = {}
    for p in out.glob("p*.*"):
        stem = p.name.split(".")[0]
        stems.setdefault(stem, set()).add(p.name[len(stem) :])
    return [s for s, kinds in stems.items() if kinds != {".dng", ".clean.dng", ".json"}]


def kill_midway(inputs: Path, out: Path) -> None:
    """Run with slow renames; SIGKILL the process group once a set is half in place."""
    command = [sys.executable, "-c", SLOW_RENAMES, *args(inputs, out)]
    proc = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.monotonic() + 120
    while not partial_sets(out) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def test_a_rerun_finishes_what_a_killed_run_left(inputs, reference, tmp_path):
    out = tmp_path / "out"
    kill_midway(inputs, out)
    left = partial_sets(out)
    assert left, "the kill did not land between a set's renames"
    markers = [p for p in out.iterdir() if p.name.startswith(outputs.MARKER_PREFIX)]
    assert markers, "a half-placed set must be marked unfinished"
    assert all(p.is_symlink() for p in markers), "local markers are links (no data to flush)"
    rerun = run(CLI, inputs, out)
    assert rerun.returncode == 0, rerun.stderr
    assert digest(out) == reference
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")], "markers or temporaries"


def test_a_file_rawsim_did_not_write_is_still_refused(inputs, reference, tmp_path):
    """A partial set without a marker is someone else's: refused, untouched."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "p03.dng").write_bytes(b"mine")
    done = run(CLI, inputs, out)
    assert done.returncode == 1
    assert "p03.dng exists but" in done.stderr and "did not finish" in done.stderr
    assert (out / "p03.dng").read_bytes() == b"mine"


@pytest.mark.parametrize("form", ["link", "file"])
def test_a_marker_of_a_live_run_is_respected(inputs, tmp_path, form):
    """A set another running process is placing is left to it, whether its marker is
    a link (as rawsim writes them locally) or a file of JSON (remote, or where links
    cannot be made)."""
    out = tmp_path / "out"
    out.mkdir()
    paths = {k: out / f"p00{s}" for k, s in (("dng", ".dng"), ("clean_dng", ".clean.dng"))}
    paths["json"] = out / "p00.json"
    (out / "p00.dng").write_bytes(b"being placed")
    info = {"host": outputs.HOST, "pid": os.getpid(), "outputs": [p.name for p in paths.values()]}
    if form == "link":
        Path(outputs.marker(paths)).symlink_to(f"{outputs.HOST}-{os.getpid()}")
    else:
        Path(outputs.marker(paths)).write_text(json.dumps(info))
    done = run(CLI, inputs, out)
    assert done.returncode == 1
    assert f"being written by process {os.getpid()}" in done.stderr
    assert (out / "p00.dng").read_bytes() == b"being placed"


def test_workers_die_with_a_killed_parent(inputs, tmp_path):
    out = tmp_path / "out"
    command = [sys.executable, "-c", SLOW_JOBS, *args(inputs, out)]
    proc = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    workers = []
    try:
        deadline = time.monotonic() + 60
        while len(workers := children(proc.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(workers) == 2
        time.sleep(0.5)  # both are inside a job now
        proc.kill()  # the main process only, not the group
        proc.wait()
        time.sleep(2.0)
        alive = [pid for pid in workers if running(pid)]
        assert not alive, f"workers outlived their parent: {alive}"
        before = sorted(p.name for p in out.rglob("*")) if out.exists() else []
        time.sleep(1.5)  # a worker that went on would finish a file by now
        after = sorted(p.name for p in out.rglob("*")) if out.exists() else []
        assert after == before
        assert not [n for n in after if n.startswith(".")], f"temporaries left: {after}"
    finally:
        for pid in workers:
            if running(pid):
                os.kill(pid, signal.SIGKILL)


def tagged(tag: str) -> list[int]:
    """Live processes whose environment holds ``RAWSIM_TEST_TAG=tag``."""
    found = []
    for environ in Path("/proc").glob("[0-9]*/environ"):
        try:
            if f"RAWSIM_TEST_TAG={tag}".encode() in environ.read_bytes().split(b"\0"):
                if running(int(environ.parent.name)):
                    found.append(int(environ.parent.name))
        except OSError:
            continue
    return found


AGENTS = (b"ray::DashboardAgent", b"ray::RuntimeEnvAgent")


def cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def test_ray_tasks_of_a_local_cluster_die_with_a_killed_parent(tmp_path):
    """With no --address, rawsim starts a Ray cluster of its own; SIGKILL the main
    process only: its tasks stop, and nothing is written after 2 s."""
    pytest.importorskip("ray")
    inputs, out = tmp_path / "in", tmp_path / "out"
    inputs.mkdir()
    for i in range(40):
        shutil.copy(DATA / "srgb" / "astronaut.png", inputs / f"a{i:02d}.png")
    tag = f"{os.getpid()}-{time.monotonic_ns()}"
    env = {**os.environ, "RAWSIM_TEST_TAG": tag, "RAY_USAGE_STATS_ENABLED": "0"}
    command = [sys.executable, "-c", CLI, *args(inputs, out)[:-2], "--noise", "physics"]
    command += ["--executor", "ray"]  # (not --jobs: the cluster's CPUs set that)
    proc = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env=env,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(list(out.glob("*.json"))) < 2:
            time.sleep(0.1)
        assert list(out.glob("*.json")), "the Ray run did not start"
        assert [pid for pid in tagged(tag) if b"ray::" in cmdline(pid)], "no Ray workers seen"
        proc.kill()
        proc.wait()
        time.sleep(2.0)
        alive = [cmdline(pid) for pid in tagged(tag)]
        # Ray's dashboard and runtime-env agents linger, idle: they run no task
        assert [c for c in alive if not c.startswith(AGENTS)] == [], "outlived their parent"
        before = sorted(p.name for p in out.iterdir())
        time.sleep(1.5)
        assert sorted(p.name for p in out.iterdir()) == before
    finally:
        for pid in tagged(tag):  # whatever of the cluster is left (Ray's own agents)
            os.kill(pid, signal.SIGKILL)
