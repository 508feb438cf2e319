import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from rawsim.errors import ParameterError, UnsupportedInputError
from rawsim.io import atomic, outputs
from rawsim.io.atomic import atomic_output
from rawsim.io.task import Task
from rawsim.run.batch import discover, parse_shard, plan, run
from rawsim.run.jobs import Interrupted, _run_one
from tests.conftest import ROOT


def test_atomic_output_replaces_only_on_success(tmp_path):
    target = tmp_path / "sub" / "a.dng"
    with atomic_output(target) as tmp:
        assert tmp.parent == target.parent and tmp.suffix == ".dng"
        tmp.write_bytes(b"first")
    assert target.read_bytes() == b"first"
    with pytest.raises(RuntimeError), atomic_output(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("interrupted")
    assert target.read_bytes() == b"first"  # the old file survives a failed write
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.dng"]  # no temporaries


INTERRUPTIBLE = {str(Path(m.__file__)) for m in (atomic, outputs)}


def _interrupt_at(step: int):
    """A trace function that raises :class:`Interrupted` once, at the ``step``-th line
    run in :mod:`rawsim.io.atomic` or :mod:`rawsim.io.outputs` (a signal's handler
    raises at such points); a list holding whether it fired."""
    seen, fired = [0], []

    def local(frame, event, arg):
        if event == "line" and not fired:
            seen[0] += 1
            if seen[0] == step:
                fired.append(True)
                raise Interrupted(signal.SIGINT)
        return local

    def tracer(frame, event, arg):
        return local if frame.f_code.co_filename in INTERRUPTIBLE else None

    return tracer, fired


def test_a_signal_at_any_step_of_a_write_leaves_nothing(tmp_path):
    """SIGINT may raise between any two lines of the atomic writes: a job stopped at
    each line in turn leaves neither outputs, nor temporaries, nor a marker."""

    def job(task):
        with outputs.atomic_outputs(task.outputs) as tmp:
            tmp["dng"].write_bytes(b"dng")
            tmp["json"].write_text("{}")
        with atomic_output(task.outputs["dng"].with_suffix(".log")) as tmp:
            tmp.write_text("log")
        return {}

    out = tmp_path / "out"
    out.mkdir()
    task = Task(tmp_path / "a.png", "a.png", {"dng": out / "a.dng", "json": out / "a.json"}, 0)
    step = 0
    while True:
        step += 1
        tracer, fired = _interrupt_at(step)
        sys.settrace(tracer)
        try:
            _run_one(job, task, overwrite=False, debug=False, kwargs={})
        except Interrupted:
            pass
        finally:
            sys.settrace(None)
        if not fired:
            break
        left = sorted(p.name for p in out.iterdir())
        assert left in ([], ["a.log"]), f"interrupted at step {step}: {left} left"
        (out / "a.log").unlink(missing_ok=True)
    assert step > 20  # the whole job ran once without an interruption
    assert sorted(p.name for p in out.iterdir()) == ["a.dng", "a.json", "a.log"]


def test_discover_keys_are_relative_to_each_input(tmp_path):
    (tmp_path / "a" / "deep").mkdir(parents=True)
    for name in ("a/x.png", "a/deep/y.JPG", "a/z.txt", "a/.hidden.png", "b.exr"):
        (tmp_path / name).write_bytes(b"x")
    found, missing, ignored = discover(
        [tmp_path / "a", tmp_path / "b.exr", tmp_path / "nope"], [".png", ".jpg", ".exr"]
    )
    assert [key for _, key in found] == ["b.exr", "deep/y.JPG", "x.png"]
    assert len(missing) == 1 and "nope: no such folder" in missing[0].message
    assert ignored == [tmp_path / "a" / "z.txt"]  # hidden files are neither taken nor counted


def test_plan_mirrors_tree_and_rejects_clashes(tmp_path):
    found = [
        (tmp_path / "in/a.png", "a.png"),
        (tmp_path / "in/a.jpg", "a.jpg"),
        (tmp_path / "in/s/b.png", "s/b.png"),
    ]
    tasks, failed = plan(found, tmp_path / "out", {"dng": ".dng", "json": ".json"}, seed=3)
    assert [t.key for t in tasks] == ["a.png", "s/b.png"]  # the first to claim a.dng keeps it
    assert tasks[1].outputs["dng"] == tmp_path / "out" / "s" / "b.dng"
    assert [r.task.key for r in failed] == ["a.jpg"]
    assert "clash" in failed[0].message and "rename" in failed[0].message


@pytest.mark.parametrize("name", ["..png", ".png", "...", "a\nb.png", " sp ace .png", "-x.png"])
def test_outputs_stay_inside_the_output_folder_and_visible(tmp_path, name):
    out = tmp_path / "out"
    tasks, failed = plan([(tmp_path / name, name)], out, {"dng": ".dng", "json": ".json"}, 1)
    assert not failed
    for p in tasks[0].outputs.values():
        assert p.parent == out and not p.name.startswith(".")


def test_a_name_that_is_not_utf8_has_a_stable_seed(tmp_path):
    name = os.fsdecode(b"caf\xe9.png")  # Latin-1 bytes: a surrogate escape in Python
    first = plan([(tmp_path / name, name)], tmp_path / "o", {"dng": ".dng"}, 5)[0][0]
    again = plan([(tmp_path / name, name)], tmp_path / "o", {"dng": ".dng"}, 5)[0][0]
    other = plan([(tmp_path / "cafe.png", "cafe.png")], tmp_path, {"dng": ".dng"}, 5)[0][0]
    assert first.seed == again.seed != other.seed


def _writes_then_fails(task):
    task.outputs["dng"].write_bytes(b"half a set")
    raise UnsupportedInputError(f"{task.source}: broken")


def test_a_failed_job_leaves_none_of_its_outputs_and_partial_sets_are_not_replaced(tmp_path):
    outputs = {"dng": tmp_path / "a.dng", "json": tmp_path / "a.json"}
    task = Task(tmp_path / "a.png", "a.png", outputs, 1)
    result = _run_one(_writes_then_fails, task, False, False, {})
    assert result.status == "failed" and not any(p.exists() for p in outputs.values())
    outputs["json"].write_text("another command's")  # one of the two names taken
    result = _run_one(_writes_then_fails, task, False, False, {})
    assert result.status == "failed" and "use --overwrite" in result.message
    assert outputs["json"].read_text() == "another command's" and not outputs["dng"].exists()
    outputs["dng"].write_bytes(b"x")
    assert _run_one(_writes_then_fails, task, False, False, {}).status == "skipped"


def test_temporaries_fit_long_names_and_stale_ones_are_removed(tmp_path):
    long = tmp_path / ("n" * 251 + ".dng")  # 255 bytes, the most ext4 allows
    with atomic_output(long) as tmp:
        assert len(tmp.name) < 40
        tmp.write_bytes(b"ok")
    assert long.read_bytes() == b"ok"
    dead = _dead_pid()
    stale = tmp_path / f".rawsim-{atomic.HOST}-{dead}-0123abcd.tmp.dng"
    live = tmp_path / f".rawsim-{atomic.HOST}-{os.getpid()}-0123abcd.tmp.dng"
    other = tmp_path / f".rawsim-ffffff-{dead}-0123abcd.tmp.dng"  # another machine's
    for p in (stale, live, other):
        p.write_bytes(b"")
    task = Task(tmp_path / "in.png", "in.png", {"dng": tmp_path / "in.dng"}, 0)
    list(run([task], lambda task: {}, jobs=1))
    assert not stale.exists() and live.exists() and other.exists()


def _dead_pid() -> int:
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def test_plan_refuses_to_overwrite_an_input(tmp_path):
    src = tmp_path / "x.json"
    tasks, failed = plan([(src, "x.json")], tmp_path, {"json": ".json"}, seed=0)
    assert not tasks and "it is an input" in failed[0].message


def test_shards_partition_the_run(tmp_path):
    found = [(tmp_path / f"{i}.png", f"{i}.png") for i in range(10)]
    full, _ = plan(found, tmp_path / "o", {"dng": ".dng"}, seed=1)
    parts = [
        plan(found, tmp_path / "o", {"dng": ".dng"}, seed=1, shard=(k, 3))[0] for k in (1, 2, 3)
    ]
    keys = sorted(t.key for p in parts for t in p)
    assert keys == sorted(t.key for t in full) and sum(len(p) for p in parts) == 10
    seeds = {t.key: t.seed for p in parts for t in p}
    assert all(seeds[t.key] == t.seed for t in full)  # seeds do not depend on the shard
    assert parse_shard("2/8") == (2, 8) and parse_shard(None) == (1, 1)
    for bad in ("0/3", "4/3", "a/b", "3"):
        with pytest.raises(ParameterError):
            parse_shard(bad)


def test_shard_auto_reads_a_slurm_array():
    array = {"SLURM_ARRAY_TASK_MIN": "0", "SLURM_ARRAY_TASK_COUNT": "16"}
    assert parse_shard("auto", {**array, "SLURM_ARRAY_TASK_ID": "0"}) == (1, 16)
    assert parse_shard("auto", {**array, "SLURM_ARRAY_TASK_ID": "15"}) == (16, 16)
    stepped = {"SLURM_ARRAY_TASK_MIN": "10", "SLURM_ARRAY_TASK_STEP": "5"}
    stepped |= {"SLURM_ARRAY_TASK_COUNT": "3", "SLURM_ARRAY_TASK_ID": "20"}
    assert parse_shard("auto", stepped) == (3, 3)
    with pytest.raises(ParameterError, match="needs a Slurm array job"):
        parse_shard("auto", {})
    with pytest.raises(ParameterError, match="as a range"):  # --array=1,3,7 has no step
        parse_shard(
            "auto",
            {
                **array,
                "SLURM_ARRAY_TASK_ID": "3",
                "SLURM_ARRAY_TASK_MIN": "1",
                "SLURM_ARRAY_TASK_COUNT": "3",
                "SLURM_ARRAY_TASK_STEP": "2",
            }
            | {"SLURM_ARRAY_TASK_ID": "7"},
        )


def _fails_on_b(task, **_):
    if task.key == "b":
        raise UnsupportedInputError(f"{task.source}: broken")
    if task.key == "c":
        raise ZeroDivisionError("bug")
    return {"ok": task.key}


def test_run_reports_every_outcome(tmp_path):
    tasks = [Task(tmp_path / k, k, {"x": tmp_path / f"{k}.out"}, 0) for k in "abc"]
    (tmp_path / "d.out").write_text("exists")
    tasks.append(Task(tmp_path / "d", "d", {"x": tmp_path / "d.out"}, 0))
    for jobs in (1, 2):
        results = {r.task.key: r for r in run(tasks, _fails_on_b, jobs=jobs)}
        assert results["a"].status == "done" and results["a"].record == {"ok": "a"}
        assert results["b"].status == "failed" and results["b"].message.endswith("broken")
        assert results["c"].status == "failed" and "ZeroDivisionError: bug" in results["c"].message
        assert results["d"].status == "skipped"


def test_readme_python_example_runs():
    text = (ROOT / "README.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert namespace["noisy"].shape == (8, 1, 256, 256)
    assert torch.equal(namespace["noisy"], namespace["noisy"].round())
    assert namespace["rgb"].shape == (8, 3, 256, 256)
    assert namespace["images"].grad.abs().sum() > 0
    assert Path(ROOT / "examples" / "photos").is_dir()


def _fills_the_disk(task):
    raise OSError(28, "No space left on device")


def _short_write(task):
    raise OSError("393216 requested and 267976 written")


@pytest.mark.parametrize("job", [_fills_the_disk, _short_write])
def test_a_full_disk_is_said_in_words(tmp_path, job):
    task = Task(tmp_path / "a.png", "a.png", {"dng": tmp_path / "out" / "a.dng"}, 0)
    result = _run_one(job, task, False, False, {})
    assert result.status == "failed"
    assert (
        result.message
        == f"{tmp_path / 'a.png'}: disk full writing into {tmp_path / 'out'} (free some space)"
    )
