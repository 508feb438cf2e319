"""Atomic file writes: write to a temporary file beside the target, then rename.

Temporary files are named ``.rawsim-<host>-<pid>-<random>.tmp<suffix>``: short
whatever the output name's length (a name of 255 bytes still has a temporary),
hidden, and recognisable, so that :func:`remove_stale_temporaries` can delete
those a killed run left (SIGKILL cannot be caught) without touching those of a
run still going, here or on another machine sharing the folder.
"""

from __future__ import annotations

import hashlib
import os
import re
import secrets
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

# New files get the permissions of an ordinary new file (the umask's).
_UMASK = os.umask(0)
os.umask(_UMASK)
#: This machine, in temporary names: 6 hex digits of its host name's hash.
HOST = hashlib.sha256(socket.gethostname().encode()).hexdigest()[:6]
_TEMPORARY = re.compile(r"^\.rawsim-(?P<host>[0-9a-f]{6})-(?P<pid>\d+)-[0-9a-f]{8}\.tmp")


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; on success rename it onto ``path``.

    On any error the temporary file is removed, so an interrupted or failed write
    leaves neither a partial file nor a stray temporary. The suffix is kept so that
    writers that choose a format by extension still work.
    """
    path = Path(path)
    made: list[Path] = []
    tmp = temporary_name(path)
    try:  # the name is held before the file exists: a signal at any point leaves none
        make_folder(path.parent, made)
        create(tmp)
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        remove_made(made)
        raise


def make_folder(folder: Path, made: list[Path]) -> None:
    """Make ``folder`` and its missing parents, recording each in ``made`` (deepest
    first) before it is made, so that :func:`remove_made` can take away what a write
    that failed had made: a run that writes nothing leaves no folder."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    for f in reversed(missing):  # the outermost first
        made.insert(0, f)
        f.mkdir(exist_ok=True)


def remove_made(made: list[Path]) -> None:
    """Remove the folders of ``made`` (deepest first) that are empty. One that is not
    (another output is in it) and those above it stay; :func:`create` makes again a
    folder removed under another write that had just made it."""
    for folder in made:
        try:
            folder.rmdir()
        except FileNotFoundError:
            continue
        except OSError:
            return


def create(tmp: Path) -> None:
    """Make ``tmp``, a name from :func:`temporary_name`, as a new empty file.

    The name is chosen (and held by the caller for its cleanup) before the file is
    made, so that no moment exists when the file is there and its name is not:
    SIGINT and SIGTERM raise between any two steps. A clash of names (one chance in
    2^32 against each other temporary of this process) fails this write, and the
    other one, whose file its cleanup removes: no partial output either way.
    """
    for attempt in range(3):
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666 & ~_UMASK))
            return
        except FileNotFoundError:  # a failed write beside this one took the empty folder
            if attempt == 2:
                raise
            tmp.parent.mkdir(parents=True, exist_ok=True)


def temporary_name(path: Path) -> Path:
    """A name for a new temporary in ``path``'s folder (nothing is created: see
    :func:`create`), named as this module's docstring says; ``path``'s suffix is
    kept (if ≤ 16 characters)."""
    suffix = path.suffix if len(path.suffix) <= 16 else ""
    return path.parent / f".rawsim-{HOST}-{os.getpid()}-{secrets.token_hex(4)}.tmp{suffix}"


def remove_stale_temporaries(folder: str | Path) -> int:
    """Delete the temporaries in ``folder`` (not below it) of rawsim processes of this
    machine that no longer run; returns how many. Missing folders have none."""
    removed = 0
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return 0
    for entry in entries:
        match = _TEMPORARY.match(entry.name)
        if match and match["host"] == HOST and not running(int(match["pid"])):
            try:
                os.unlink(entry.path)
                removed += 1
            except OSError:
                pass
    return removed


def running(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine and is not a zombie (a killed
    process its parent has not reaped yet writes nothing more)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except FileNotFoundError:  # it ended just now, or there is no /proc (not Linux)
        return not os.path.isdir("/proc/self")
    except (OSError, IndexError):
        return True
