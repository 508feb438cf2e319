"""A file's outputs as one set: whole, absent, or recognisably unfinished after any kill.

A job writes each of its outputs (``<stem>.dng``, ``<stem>.clean.dng``,
``<stem>.npz``, the ``<stem>.json`` sidecar, …) to a temporary file first
(:func:`atomic_outputs`); only when all are written are they put in place, the
sidecar last. Putting a set in place is bracketed by a marker, a small hidden
file beside the outputs (``.rawsim-unfinished-<hash>``, :func:`marker`) that
names them and the process placing them: written before the first rename (or
upload) and removed after the last. So after a SIGKILL, which cannot be caught:

* no marker: the outputs present are a finished set, or files rawsim did not
  write (then a rerun refuses them, as ever);
* a marker whose process is gone: the outputs it names are an unfinished set of
  rawsim's own, which a rerun replaces (:func:`unfinished`).

A local marker is a symbolic link whose target names the process,
``<host>-<pid>`` (the host as :mod:`rawsim.io.atomic` names it in temporaries): a
target that short lives in the inode, with no data to write back. A marker file
with data made its removal wait 10–80 ms for the writeback of the outputs just
placed (ext4, ordered data, measured with ``strace -T`` in a ``process`` batch),
a tenth of a 24 MP render. Where links cannot be made, and on remote file systems,
the marker is a file of JSON: ``{"host": …, "pid": …, "outputs": [names]}``. Its
name is a hash of the outputs' names, so a marker found for a set names that
set. A clean run leaves none. Remote outputs (fsspec URLs) follow the same
rules: :func:`staged` uploads the marker, then each output, the sidecar last,
then deletes the marker.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path, PurePosixPath

from rawsim.io import remote
from rawsim.io.atomic import HOST, create, make_folder, remove_made, running, temporary_name
from rawsim.io.task import Task

MARKER_PREFIX = ".rawsim-unfinished-"


def _in_order(outputs: Mapping[str, Path | str]) -> list[tuple[str, Path | str]]:
    """The outputs in the order they are put in place: the sidecar (``json``) last,
    so that a set with its sidecar is complete even to a reader without markers."""
    return sorted(outputs.items(), key=lambda kv: kv[0] == "json")


def marker(outputs: Mapping[str, Path | str]) -> Path | str:
    """Where the marker of the set ``outputs`` lives: beside its sidecar (or its first
    output), named by a hash of the outputs' names, so any name length fits."""
    anchor = outputs.get("json") or next(iter(outputs.values()))
    names = "\0".join(sorted(file_name(p) for p in outputs.values()))
    name = MARKER_PREFIX + hashlib.sha256(os.fsencode(names)).hexdigest()[:16]
    if remote.is_url(anchor):
        return remote.join(str(anchor).rsplit("/", 1)[0], name)
    return Path(anchor).parent / name


def file_name(location: Path | str) -> str:
    return PurePosixPath(str(location)).name if remote.is_url(location) else Path(location).name


def unfinished(outputs: Mapping[str, Path | str]) -> dict | None:
    """The marker of ``outputs``, if a run left one: ``{"host", "pid", "outputs",
    "running"}``, ``running`` telling whether its process is alive on this machine
    (False for another machine's, which cannot be asked). None if there is none."""
    location = marker(outputs)
    try:
        if remote.is_url(location):
            fs, path = remote.filesystem(location)
            text = fs.cat_file(path).decode()
        else:
            text = _read_marker(Path(location), outputs)
    except FileNotFoundError:
        return None
    try:
        info = json.loads(text)
        info["pid"] = int(info["pid"])
    except (ValueError, KeyError, TypeError):  # cut short by a kill while it was written
        info = {"host": "", "pid": 0}
    info["running"] = info.get("host") == HOST and running(info["pid"])
    return info


def _read_marker(location: Path, outputs: Mapping[str, Path | str]) -> str:
    """The JSON of the local marker ``location`` of ``outputs``: a link's
    ``<host>-<pid>`` with the names of ``outputs`` (which its name hashes), or a
    marker file's text."""
    try:
        host, _, pid = os.readlink(location).partition("-")
    except OSError as err:
        if isinstance(err, FileNotFoundError):
            raise
        return location.read_text()  # not a link: a marker file
    names = [file_name(p) for p in outputs.values()]
    return json.dumps({"host": host, "pid": pid, "outputs": names})


def _mark(location: Path, text: str) -> None:
    """Write the local marker ``location`` (whole, in one rename): a link to
    ``<host>-<pid>``, or a file of ``text`` where links cannot be made."""
    tmp = temporary_name(location)
    try:
        try:
            os.symlink(f"{HOST}-{os.getpid()}", tmp)
        except OSError:
            create(tmp)
            tmp.write_text(text)
        os.replace(tmp, location)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def clear(outputs: Mapping[str, Path | str]) -> None:
    """Remove the marker of ``outputs`` (if any)."""
    remote.remove(marker(outputs))


@contextmanager
def placing(outputs: Mapping[str, Path | str]) -> Iterator[None]:
    """Context: the set ``outputs`` is being put in place. The marker is written
    before the block and removed after it succeeds; if the block fails, it stays
    until the caller has removed what the block placed (then :func:`clear`)."""
    location = marker(outputs)
    names = [file_name(p) for p in outputs.values()]
    text = json.dumps({"host": HOST, "pid": os.getpid(), "outputs": names})
    if remote.is_url(location):
        fs, path = remote.filesystem(location)
        fs.pipe_file(path, text.encode())
    else:
        _mark(Path(location), text)
    yield
    clear(outputs)


def _place(tmp: Path, path: Path) -> None:
    """Put one finished output in place (a rename: whole or not at all)."""
    os.replace(tmp, path)


@contextmanager
def atomic_outputs(outputs: Mapping[str, Path]) -> Iterator[dict[str, Path]]:
    """Yield a temporary path in each output's folder (kind → path, keeping the
    suffix for writers that choose a format by it); when the block succeeds, put
    them all in place as one set (:func:`placing`), the sidecar last.

    The outputs' folders are made here, at the first write; on any error every
    temporary is removed, and the folders made here if they are left empty; outputs
    already renamed stay for the caller (:func:`rawsim.run.jobs._run_one` removes the
    ones it wrote). A signal raises between any two steps, so each temporary's name
    is held before its file is made and let go only after its rename.
    """
    paths = {kind: Path(p) for kind, p in outputs.items()}
    temporaries: dict[str, Path] = {}
    made: list[Path] = []  # the folders this set's first write makes
    try:
        for kind, path in paths.items():
            make_folder(path.parent, made)
            temporaries[kind] = temporary_name(path)
            create(temporaries[kind])
        yield dict(temporaries)
        with placing(paths):
            for kind, path in _in_order(paths):
                _place(temporaries[kind], path)
                del temporaries[kind]
    except BaseException:
        for tmp in temporaries.values():
            tmp.unlink(missing_ok=True)
        remove_made(made)  # those left empty: a failed set leaves no folder
        raise
    finally:
        for tmp in temporaries.values():
            tmp.unlink(missing_ok=True)


@contextmanager
def staged(task: Task) -> Iterator[Task]:
    """Yield ``task`` with local paths: a remote source is downloaded into a scratch
    folder and remote outputs point there, keeping their names. When the job
    returns, the remote outputs it wrote are uploaded as one set (:func:`placing`,
    the sidecar last); the scratch folder is removed in every case."""
    if not remote.is_url(task.source) and not any(map(remote.is_url, task.outputs.values())):
        yield task
        return
    scratch = Path(tempfile.mkdtemp(prefix="rawsim-"))
    try:
        source = task.source
        if remote.is_url(source):
            fs, path = remote.filesystem(source)
            source = scratch / "in" / PurePosixPath(path).name
            source.parent.mkdir()
            fs.get_file(path, os.fspath(source))
        local = {
            k: scratch / "out" / PurePosixPath(p).name if remote.is_url(p) else p
            for k, p in task.outputs.items()
        }
        yield replace(task, source=source, outputs=local)
        uploads = {
            kind: target
            for kind, target in task.outputs.items()
            if remote.is_url(target) and local[kind].exists()
        }
        if uploads:
            with placing(task.outputs):
                for kind, target in _in_order(uploads):
                    fs, path = remote.filesystem(target)
                    fs.put_file(os.fspath(local[kind]), path)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
