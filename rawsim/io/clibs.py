"""What the C libraries that decode files (LibRaw, OpenImageIO, libpng) need around them.

* Their messages: they write their own unprefixed lines to file descriptor 2;
  rawsim collects them and folds them into its one-line messages (or the
  file's warnings), so a batch prints one line per message.
* File names: their Python bindings take names as UTF-8 text, so a name that is
  not UTF-8 (any bytes but ``/`` and NUL are legal on Linux) is opened through
  a symbolic link with a plain name.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def collected_stderr(lines: list[str]):
    """Collect what C libraries (LibRaw, libpng, …) write to file descriptor 2 meanwhile
    into ``lines`` (each once, without the prefix before its first ``": "``), instead
    of letting it interleave with rawsim's own one-line messages."""
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
