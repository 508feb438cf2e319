"""Beyond one machine: a real local Ray cluster (two worker CPUs, started with
``ray start``), and a real S3 endpoint (moto's server) reached over HTTP by s3fs.

The cluster's workers get the S3 endpoint and credentials from the environment
``ray start`` ran in, as the nodes of a real cluster would have their own.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import boto3
import numpy as np
import pytest
import tifffile
from click.testing import CliRunner

from rawsim.io import outputs
from rawsim_cli.main import cli
from tests.conftest import DATA

COMMON = ["-p", "sony_a7s2", "--iso", "1600", "--seed", "9", "--clean", "-q"]
BUCKET = "rawsim-test"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def digest(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def s3():
    """A local S3 endpoint (moto's server mode) with one bucket; its URL and
    credentials in the environment, as a user's would be."""
    from moto.server import ThreadedMotoServer

    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port)
    server.start()
    env = {
        "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}",
        "AWS_ACCESS_KEY_ID": "rawsim",
        "AWS_SECRET_ACCESS_KEY": "rawsim-secret",
        "AWS_DEFAULT_REGION": "us-east-1",
    }
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    client = boto3.client("s3")
    client.create_bucket(Bucket=BUCKET)
    yield client
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    server.stop()


@pytest.fixture(scope="module")
def cluster(s3):
    """A two-CPU Ray head node started as users start one; its address."""
    port = _free_port()
    exe = Path(sys.executable).with_name("ray")
    # Token authentication, Ray's default for new clusters: the head and every client
    # need the token. A fresh one in the environment, as a user would export it, so
    # the test does not depend on a ~/.ray/auth_token left on the machine.
    auth = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    os.environ.update(auth)
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    start = [str(exe), "start", "--head", f"--port={port}", "--num-cpus=2"]
    start += ["--include-dashboard=false", "--object-store-memory=100000000"]
    said = subprocess.run(start, env=env, capture_output=True, text=True)
    assert said.returncode == 0, said.stdout + said.stderr
    address = re.search(r"ray start --address='([^']+)'", said.stdout + said.stderr)
    assert address, said.stdout + said.stderr
    yield address[1]  # HOST:PORT, as `ray start` tells users to join it
    subprocess.run([str(exe), "stop", "--force"], env=env, capture_output=True)
    for name in auth:
        os.environ.pop(name)


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    """16 small photos in two folders, and one file that is not an image."""
    root = tmp_path_factory.mktemp("cluster") / "in"
    for folder in ("a", "b"):
        (root / folder).mkdir(parents=True)
        for i, name in enumerate(("chelsea.png", "rocket.jpg", "coffee.png", "astronaut.png")):
            for copy in range(2):
                shutil.copy(DATA / "srgb" / name, root / folder / f"{copy}{i}_{name}")
    (root / "b" / "broken.jpg").write_bytes(b"not a jpeg")
    return root


@pytest.fixture(scope="module")
def local_run(photos, tmp_path_factory):
    """The reference: a local --jobs 1 run; (outputs folder, exit code, stderr)."""
    out = tmp_path_factory.mktemp("local") / "out"
    r = CliRunner().invoke(cli, ["unprocess", str(photos), "-o", str(out), *COMMON])
    return out, r.exit_code, r.output


def rawsim(*args, **kwargs) -> subprocess.CompletedProcess:
    command = [sys.executable, "-c", "from rawsim_cli.main import main; main()", *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, **kwargs)


def here(*args):
    """The command in this process (the fixtures' environment holds the S3 endpoint)."""
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.mark.slow
def test_ray_run_is_byte_identical_to_a_local_run(photos, local_run, cluster, tmp_path):
    out, code, said = local_run
    assert code == 1 and said.count("error:") == 1 and "broken.jpg" in said
    r = rawsim(
        "unprocess", photos, "-o", tmp_path, *COMMON, "--executor", "ray", "--address", cluster
    )
    assert r.returncode == 1
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert errors == [line for line in said.splitlines() if line.startswith("error:")]
    assert "16 done, 0 skipped, 1 failed" in r.stderr
    assert digest(tmp_path) == digest(out)
    again = rawsim(
        "unprocess", photos, "-o", tmp_path, *COMMON, "--executor", "ray", "--address", cluster
    )
    assert "0 done, 16 skipped, 1 failed" in again.stderr


def _bundle_workers() -> list[int]:
    """Processes of Ray workers running rawsim's bundle task (Ray names them so)."""
    pids = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and b"ray::_run_bundle" in (entry / "cmdline").read_bytes():
                pids.append(int(entry.name))
        except OSError:
            continue
    return pids


@pytest.mark.slow
def test_a_killed_ray_worker_is_retried_and_the_outputs_are_complete(
    photos, local_run, cluster, tmp_path
):
    out, _, _ = local_run
    args = ["unprocess", photos, "-o", tmp_path, *COMMON[:-1], "--executor", "ray"]
    command = [sys.executable, "-c", "from rawsim_cli.main import main; main()"]
    proc = subprocess.Popen(
        [*command, *map(str, args), "--address", cluster],
        stderr=subprocess.PIPE,
        text=True,
    )
    killed, deadline = None, time.monotonic() + 120
    while killed is None and proc.poll() is None and time.monotonic() < deadline:
        pids = _bundle_workers()
        if pids and any(tmp_path.rglob("*.dng")):  # mid-job: some files are done
            killed = pids[0]
            os.kill(killed, signal.SIGKILL)
        time.sleep(0.01)
    stderr = proc.communicate(timeout=300)[1]
    assert killed is not None, "no worker was seen running a bundle"
    assert proc.returncode == 1, stderr  # the broken file only
    assert "Ray worker died" in stderr and "retrying it" in stderr
    assert "16 done, 0 skipped, 1 failed" in stderr
    assert digest(tmp_path) == digest(out)  # complete, no stray temporaries


@pytest.mark.slow
def test_ctrl_c_stops_a_ray_run_and_a_rerun_completes_it(photos, local_run, cluster, tmp_path):
    """SIGINT mid-run: exit 130 within seconds, the summary says what is unfinished, no
    partial output; the same command again finishes with the local run's bytes."""
    out, _, _ = local_run
    args = ["unprocess", photos, "-o", tmp_path, *COMMON[:-1], "--executor", "ray"]
    command = [sys.executable, "-c", "from rawsim_cli.main import main; main()"]
    proc = subprocess.Popen(
        [*command, *map(str, args), "--address", cluster], stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 120
    while not any(tmp_path.rglob("*.dng")) and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    stopped = time.monotonic()
    stderr = proc.communicate(timeout=60)[1]
    assert proc.returncode == 130 and time.monotonic() - stopped < 10, stderr[-3000:]
    assert "interrupted by SIGINT" in stderr and "not finished" in stderr
    for dng in tmp_path.rglob("*.dng"):  # every output set that exists is complete
        assert dng.with_suffix(".json").exists() or dng.name.endswith(".clean.dng")
    r = rawsim(*args, "--address", cluster)
    assert r.returncode == 1 and "1 failed" in r.stderr  # the broken file
    assert digest(tmp_path) == digest(out)


def test_ray_executor_needs_ray_flags_right(photos, tmp_path):
    r = CliRunner().invoke(
        cli, ["unprocess", str(photos), "-o", str(tmp_path), *COMMON, "--address", "auto"]
    )
    assert r.exit_code == 2 and "--address needs --executor ray" in r.output
    r = CliRunner().invoke(
        cli,
        ["unprocess", str(photos), "-o", str(tmp_path), *COMMON, "--executor", "ray", "-j", "2"],
    )
    assert r.exit_code == 2 and "--jobs is for local workers" in r.output


def _upload(client, folder: Path, prefix: str) -> None:
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            client.upload_file(str(p), BUCKET, f"{prefix}/{p.relative_to(folder).as_posix()}")


def _objects(client, prefix: str) -> dict[str, str]:
    listing = client.list_objects_v2(Bucket=BUCKET, Prefix=prefix + "/").get("Contents", [])
    return {
        o["Key"][len(prefix) + 1 :]: hashlib.sha256(
            client.get_object(Bucket=BUCKET, Key=o["Key"])["Body"].read()
        ).hexdigest()
        for o in listing
    }


@pytest.mark.slow
def test_s3_inputs_and_outputs_give_the_local_bytes(photos, local_run, s3, tmp_path):
    out, _, said = local_run
    _upload(s3, photos, "photos")
    url_in, url_out = f"s3://{BUCKET}/photos", f"s3://{BUCKET}/raw"
    r = here("unprocess", url_in, "-o", url_out, *COMMON, "-j", "2")
    assert r.exit_code == 1 and "16 done, 0 skipped, 1 failed" in r.output
    assert f"error: {url_in}/b/broken.jpg: not a readable image" in r.output
    assert _objects(s3, "raw") == digest(out)
    again = here("unprocess", url_in, "-o", url_out, *COMMON)
    assert "0 done, 16 skipped, 1 failed" in again.output
    # a remote file to a local folder, and a local folder to a remote one: the bytes of
    # the same command with local paths (a file given by name is keyed by its name)
    local, remote_file = tmp_path / "local", tmp_path / "remote-file"
    assert (
        here("unprocess", f"{url_in}/a/00_chelsea.png", "-o", remote_file, *COMMON).exit_code == 0
    )
    assert here("unprocess", photos / "a" / "00_chelsea.png", "-o", local, *COMMON).exit_code == 0
    assert digest(remote_file) == digest(local) and len(digest(local)) == 3
    assert (
        here("unprocess", photos / "a", "-o", f"s3://{BUCKET}/from-local", *COMMON).exit_code == 0
    )
    assert here("unprocess", photos / "a", "-o", tmp_path / "a", *COMMON).exit_code == 0
    assert _objects(s3, "from-local") == digest(tmp_path / "a")


@pytest.mark.slow
def test_s3_with_the_ray_executor(photos, local_run, s3, cluster):
    out, _, _ = local_run
    _upload(s3, photos, "photos-ray")
    url_in, url_out = f"s3://{BUCKET}/photos-ray", f"s3://{BUCKET}/raw-ray"
    r = rawsim(
        "unprocess", url_in, "-o", url_out, *COMMON, "--executor", "ray", "--address", cluster
    )
    assert r.returncode == 1 and "16 done, 0 skipped, 1 failed" in r.stderr
    assert _objects(s3, "raw-ray") == digest(out)


def _leave_unfinished(client, prefix: str, stem: str, marked: bool) -> None:
    """Make ``stem``'s outputs under ``prefix`` look as a run killed while uploading
    them left them: the sidecar and the clean DNG missing, and (``marked``) the
    set's marker naming a process that is gone; unmarked, they are someone else's."""
    for suffix in (".json", ".clean.dng"):
        client.delete_object(Bucket=BUCKET, Key=f"{prefix}/{stem}{suffix}")
    if marked:
        gone = subprocess.Popen(["true"])
        gone.wait()
        urls = {k: f"s3://{BUCKET}/{prefix}/{stem}{s}" for k, s in SUFFIXES.items()}
        key = outputs.marker(urls)[len(f"s3://{BUCKET}/") :]
        names = [u.rsplit("/", 1)[1] for u in urls.values()]
        info = {"host": outputs.HOST, "pid": gone.pid, "outputs": names}
        client.put_object(Bucket=BUCKET, Key=key, Body=json.dumps(info).encode())


SUFFIXES = {"dng": ".dng", "clean_dng": ".clean.dng", "json": ".json"}


@pytest.mark.slow
@pytest.mark.parametrize("executor", ["local", "ray"])
def test_an_unfinished_remote_set_is_finished_and_a_foreign_one_refused(
    photos, s3, executor, request, tmp_path
):
    assert here("unprocess", photos / "a", "-o", tmp_path, *COMMON).exit_code == 0
    prefix = f"unfinished-{executor}"
    url_out = f"s3://{BUCKET}/{prefix}"
    assert here("unprocess", photos / "a", "-o", url_out, *COMMON).exit_code == 0
    _leave_unfinished(s3, prefix, "00_chelsea", marked=True)
    _leave_unfinished(s3, prefix, "01_rocket", marked=False)
    ray = []
    if executor == "ray":
        ray = ["--executor", "ray", "--address", request.getfixturevalue("cluster")]
    r = rawsim("unprocess", photos / "a", "-o", url_out, *COMMON, *ray)
    assert r.returncode == 1 and "1 done, 6 skipped, 1 failed" in r.stderr, r.stderr
    assert "01_rocket.dng exists but" in r.stderr
    objects = _objects(s3, prefix)
    expected = digest(tmp_path)
    del expected["01_rocket.json"], expected["01_rocket.clean.dng"]
    assert objects == expected  # the marker gone, the set whole, the foreign one untouched


@pytest.mark.slow
def test_bad_urls_say_what_is_wrong(s3, tmp_path):
    r = here("unprocess", f"s3://{BUCKET}/nothing-here", "-o", tmp_path, *COMMON)
    assert r.exit_code == 2 and "no such file or folder (check the URL)" in r.output
    r = here("unprocess", DATA / "srgb" / "chelsea.png", "-o", "s3://no-such-bucket/x", *COMMON)
    assert r.exit_code == 2 and "cannot write to s3://no-such-bucket/x" in r.output
    r = here("unprocess", "nosuchscheme://a/b.png", "-o", tmp_path, *COMMON)
    assert r.exit_code == 2 and "install an fsspec file system for nosuchscheme://" in r.output


@pytest.mark.slow
def test_ray_data_pairs_are_the_cli_samples(photos, local_run, cluster):
    """RawPairs in Dataset.map_batches gives, row by row, the DNGs' samples."""
    import ray  # here: Ray reads RAY_AUTH_MODE (set by the cluster fixture) on import

    from rawsim.ray_data import RawPairs

    out, _, _ = local_run
    ray.init(address=cluster, logging_level="ERROR")
    try:
        folder = str(photos / "a")
        images = ray.data.read_images(folder, include_paths=True, mode="RGB")
        options = dict(profile="sony_a7s2", root=str(photos), iso=1600, seed=9)
        pairs = images.map_batches(
            RawPairs,
            fn_constructor_kwargs=options,
            batch_size=3,
            compute=ray.data.ActorPoolStrategy(size=1),
        )
        rows = pairs.take_all()
    finally:
        ray.shutdown()
    assert len(rows) == 8
    for row in rows:
        stem = out / Path(row["key"]).with_suffix("")
        assert np.array_equal(row["noisy"], tifffile.imread(f"{stem}.dng"))
        assert np.array_equal(row["clean"], tifffile.imread(f"{stem}.clean.dng"))
        assert row["iso"] == 1600


@pytest.mark.slow
def test_process_on_ray_and_from_s3_gives_the_local_renders(s3, cluster, tmp_path):
    """Camera raws (a DNG, a QuickTake, a Kodak KDC) rendered on Ray and from S3: the
    bytes of a local run."""
    raws = tmp_path / "raws"
    raws.mkdir()
    for name in ("canon_eos60d_mlv.dng", "apple_quicktake150.qtk", "kodak_dc50_grbg.kdc"):
        shutil.copy(DATA / "raw" / name, raws / name)
    args = ["--format", "tiff", "--bits", "16", "-q"]
    assert here("process", raws, "-o", tmp_path / "local", *args).exit_code == 0
    where = ["--executor", "ray", "--address", cluster]
    r = rawsim("process", raws, "-o", tmp_path / "ray", *args, *where)
    assert r.returncode == 0, r.stderr
    assert digest(tmp_path / "ray") == digest(tmp_path / "local")
    _upload(s3, raws, "raws")
    r = here("process", f"s3://{BUCKET}/raws", "-o", f"s3://{BUCKET}/renders", *args)
    assert r.exit_code == 0, r.output
    assert _objects(s3, "renders") == digest(tmp_path / "local")


def test_ray_executor_without_ray_says_how_to_install(photos, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed
    r = here("unprocess", photos, "-o", tmp_path, *COMMON, "--executor", "ray")
    assert r.exit_code == 2 and "pip install 'rawsim[ray]'" in r.output


def test_a_retried_file_whose_outputs_the_dead_worker_wrote_is_done(tmp_path):
    """A worker killed between putting a file's outputs in place and reporting them:
    its retry finds them and is counted done, not skipped; outputs older than the
    run (there before it) or at URLs stay skipped."""
    from rawsim.io.task import Task
    from rawsim.run.jobs import Result
    from rawsim.run.ray_executor import _done_before_it_died

    began = time.time()
    outs = {"dng": tmp_path / "a.dng", "json": tmp_path / "a.json"}
    for p in outs.values():
        p.write_bytes(b"x")
    task = Task(tmp_path / "a.png", "a.png", outs, 0)
    skipped = Result(task, "skipped", "a.png: outputs exist (use --overwrite)")
    assert _done_before_it_died(skipped, began - 1).status == "done"
    os.utime(outs["json"], (began - 3600, began - 3600))
    assert _done_before_it_died(skipped, began - 1) is skipped
    remote = Task(tmp_path / "a.png", "a.png", {"dng": "s3://bucket/a.dng"}, 0)
    assert _done_before_it_died(Result(remote, "skipped"), began - 1).status == "skipped"
