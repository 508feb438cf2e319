"""What the C libraries that decode files (LibRaw, OpenImageIO, libpng) need around them.

* Their messages: they write their own unprefixed lines to file descriptor 2;
  rawsim collects them and folds them into its one-line messages (or the
  file's warnings), so a batch prints one line per message. One collection
  runs at a time, and the command's own messages go to a copy of the
  descriptor (:func:`separate_stderr`), so a line that the main thread prints
  while a reader thread decodes the batch's next file is neither collected as
  that file's warning nor lost.
* File names: their Python bindings take names as UTF-8 text, so a name that is
  not UTF-8 (any bytes but ``/`` and NUL are legal on Linux) is opened through
  a symbolic link with a plain name.
"""

from __future__ import annotations

import io
import os
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: Held while file descriptor 2 is redirected: a collection begun inside another's
#: (a reader thread's beside the main thread's) would put back the other's sink.
_collecting = threading.Lock()


@contextmanager
def collected_stderr(lines: list[str]):
    """Collect what C libraries (LibRaw, libpng, …) write to file descriptor 2 meanwhile
    into ``lines`` (each once, without the prefix before its first ``": "``), instead
    of letting it interleave with rawsim's own one-line messages.

    Descriptor 2 is the process's: whatever any thread writes to it meanwhile is
    collected, so a program that prints from other threads first gives Python's
    ``sys.stderr`` a descriptor of its own (:func:`separate_stderr`)."""
    with _collecting:
        sys.stderr.flush()
        saved = os.dup(2)
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                sink.seek(0)
                for line in sink.read().decode(errors="replace").splitlines():
                    text = line.split(": ", 1)[-1].strip()
                    if text and text not in lines:
                        lines.append(text)


def separate_stderr() -> None:
    """Point ``sys.stderr`` at a copy of file descriptor 2 (the same terminal, pipe or
    file), so that what Python prints never passes through descriptor 2 while
    :func:`collected_stderr` redirects it. Once per process; a ``sys.stderr`` that
    is not descriptor 2 (a test's capture) is left as it is."""
    stream = sys.stderr
    try:
        if stream is None or stream.fileno() != 2:
            return
    except (AttributeError, OSError, ValueError):  # no descriptor: not the process's
        return
    stream.flush()
    copy = os.dup(2)
    sys.stderr = io.TextIOWrapper(
        io.FileIO(copy, "w"),
        encoding=stream.encoding,
        errors=stream.errors,
        line_buffering=True,
        write_through=True,
    )


@contextmanager
def openable_name(path: str | Path) -> Iterator[str]:
    """A name for ``path`` that the libraries' bindings accept: the path itself, or,
    for a path that is not UTF-8, a symbolic link to it in a temporary folder."""
    text = str(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        with tempfile.TemporaryDirectory(prefix="rawsim-") as folder:
            link = os.path.join(
                folder, "input" + Path(text).suffix.encode("ascii", "replace").decode()
            )
            os.symlink(os.path.abspath(os.fsencode(text)), link)
            yield link
        return
    yield text
