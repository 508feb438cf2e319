"""Reading a batch's next input ahead: the reader thread and the batch's hints."""

import json
import threading

import pytest

from rawsim.errors import UnsupportedInputError
from rawsim.io.readahead import AHEAD, ReadAhead
from rawsim.io.task import Task
from rawsim.run.batch import run


def _read(key, log):
    log.append((key, threading.current_thread().name))
    if key == "bad":
        raise UnsupportedInputError("bad: not a raw")
    return key.upper()


def test_a_read_ahead_input_is_read_once_in_the_reader_thread():
    reader, log = ReadAhead(), []
    reader.start("a", _read, "a", log)
    reader.start("a", _read, "a", log)  # already under way: not read again
    assert reader.take("a", _read, "a", log) == "A"
    assert log == [("a", log[0][1])] and log[0][1].startswith("rawsim-read")
    # taken: a second take reads now, in the caller's thread
    assert reader.take("a", _read, "a", log) == "A"
    assert log[1] == ("a", threading.current_thread().name)


def test_its_error_is_raised_where_it_is_taken():
    reader = ReadAhead()
    reader.start("bad", _read, "bad", [])
    with pytest.raises(UnsupportedInputError, match="not a raw"):
        reader.take("bad", _read, "bad", [])


def test_inputs_not_taken_are_dropped_beyond_the_limit():
    reader, log = ReadAhead(), []
    for key in "abc":  # "a" was skipped: only the last AHEAD are kept
        reader.start(key, _read, key, log)
    assert AHEAD == 2
    assert reader.take("c", _read, "c", log) == "C"
    assert reader.take("b", _read, "b", log) == "B"
    reader.take("a", _read, "a", log)  # dropped: read again, now, in the caller's thread
    assert log[-1] == ("a", threading.current_thread().name)


def test_taking_another_input_keeps_the_one_read_ahead():
    reader, log = ReadAhead(), []
    reader.start("b", _read, "b", log)
    assert reader.take("a", _read, "a", log) == "A"  # not read ahead: read now
    assert log[-1] == ("a", threading.current_thread().name)
    assert reader.take("b", _read, "b", log) == "B"
    assert [k for k, _ in log].count("b") == 1


def _job(task, log):
    log.append(("run", task.key))
    return {}


def _read_ahead(task, log):
    log.append(("ahead", task.key))


_job.read_ahead = _read_ahead


@pytest.mark.parametrize("overwrite", [False, True])
def test_the_batch_names_the_next_file_to_run_before_each(tmp_path, overwrite):
    tasks = [Task(tmp_path / k, k, {"x": tmp_path / f"{k}.out"}, 0) for k in "abcd"]
    (tmp_path / "b.out").write_text("exists")  # skipped: not read ahead
    log = []
    results = list(run(tasks, _job, overwrite=overwrite, log=log))
    assert [r.status for r in results] == [
        "done",
        "done" if overwrite else "skipped",
        "done",
        "done",
    ]
    if overwrite:
        expected = ["ahead b", "run a", "ahead c", "run b", "ahead d", "run c", "run d"]
    else:
        expected = ["ahead c", "run a", "ahead d", "run c", "run d"]
    assert [" ".join(e) for e in log] == expected


LINES_BESIDE_A_READ = """
import os, sys, threading, time
from rawsim.io.clibs import collected_stderr, separate_stderr

separate_stderr()
collected = {"a": [], "b": []}
inside = threading.Event()

def read(name, lines):  # a library that writes to descriptor 2 while it decodes
    with collected_stderr(lines):
        inside.set()
        os.write(2, f"lib: {name} says hello\\n".encode())
        time.sleep(0.3)

readers = [threading.Thread(target=read, args=(k, v)) for k, v in collected.items()]
for t in readers:
    t.start()
inside.wait()
print("done: the main thread's line", file=sys.stderr)
for t in readers:
    t.join()
os.write(2, b"after: descriptor 2 is the terminal again\\n")
print(collected)
"""


def test_lines_printed_while_a_reader_thread_collects_reach_the_terminal():
    """The main thread's messages are not collected as the file's warnings (nor lost)
    while a reader thread collects a library's lines, and two collections at once
    each get their own lines and leave descriptor 2 as it was."""
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-c", LINES_BESIDE_A_READ], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "{'a': ['a says hello'], 'b': ['b says hello']}"
    assert r.stderr.splitlines() == [
        "done: the main thread's line",
        "after: descriptor 2 is the terminal again",
    ]


def test_an_image_unprocessed_while_it_is_decoded_gives_the_same_files(tmp_path):
    """A file not read ahead is unprocessed band by band while its decode runs; one
    read ahead is decoded first: the same bytes. A decode that fails midway writes
    nothing and says why."""
    import OpenImageIO as oiio

    from rawsim.cameras.profiles import load_profile
    from rawsim.pipelines.unprocess import UnprocessOptions, read_ahead, unprocess_file
    from tests.conftest import DATA

    image = tmp_path / "even.jpg"
    buf = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(str(DATA / "srgb" / "coffee.png")), roi=oiio.ROI(0, 600, 0, 1100)
    )
    assert buf.write(str(image)), oiio.geterror()
    options = UnprocessOptions(profile=load_profile("sony_a7s2"), iso=3200, clean=True)

    def task(name, source=image):
        outputs = {k: tmp_path / f"{name}.{k}" for k in ("dng", "json")}
        return Task(source, source.name, outputs | {"clean_dng": tmp_path / f"{name}.c.dng"}, 9)

    unprocess_file(task("streamed"), options)
    ahead = task("ahead")
    read_ahead(ahead, options)
    unprocess_file(ahead, options)
    for suffix in ("dng", "c.dng"):
        streamed, read_first = (tmp_path / f"{name}.{suffix}" for name in ("streamed", "ahead"))
        assert streamed.read_bytes() == read_first.read_bytes()
    sidecars = [
        json.loads((tmp_path / f"{name}.json").read_text()) for name in ("streamed", "ahead")
    ]
    streamed, read_first = ({k: v for k, v in s.items() if k != "outputs"} for s in sidecars)
    assert streamed == read_first
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(image.read_bytes()[: image.stat().st_size // 2])
    with pytest.raises(UnsupportedInputError, match="cut.jpg"):
        unprocess_file(task("cut", cut), options)
    assert not list(tmp_path.glob("cut.*.*")) and not (tmp_path / "cut.dng").exists()
