"""Inputs and outputs at fsspec URLs: ``s3://bucket/folder``, ``gs://…``, ``file://…``.

A job reads and writes local files as always: :func:`rawsim.io.outputs.staged`
copies a remote input into a private scratch folder, gives the job local output
paths there, and then uploads each finished output under its final name. An object
store shows an object only when its upload is complete (a PUT or a completed multipart upload), so a
remote output appears whole or not at all, as a local rename makes it.

The file system of a URL comes from fsspec and the package the user installed for
it (``s3fs`` for ``s3://``: ``pip install 'rawsim[s3]'``). Credentials and endpoints
are the file system's own settings (for S3: ``AWS_ACCESS_KEY_ID``,
``AWS_ENDPOINT_URL``, ``~/.aws``, …). Remote paths are ``str``; local ones ``Path``.
"""

from __future__ import annotations

import secrets
from collections.abc import Iterable
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING

from rawsim.errors import ParameterError

if TYPE_CHECKING:
    pass

#: Object stores: no folders, and a missing bucket is an error, not something to make.
_OBJECT_STORES = {"s3", "s3a", "gs", "gcs", "az", "abfs", "abfss", "oss"}
#: What to install for the file systems of the common schemes.
_PACKAGES = {"s3": "rawsim[s3]", "s3a": "rawsim[s3]", "gs": "gcsfs", "gcs": "gcsfs"}


def is_url(location: str | Path) -> bool:
    """Whether ``location`` is a URL (``scheme://…``) rather than a local path."""
    return isinstance(location, str) and "://" in location


def localize(location: str | Path) -> str | Path:
    """``file://`` URLs as local paths (written with a local rename); others unchanged."""
    if isinstance(location, str) and location.startswith("file://"):
        from urllib.parse import unquote, urlparse

        return unquote(urlparse(location).path)
    return location


def filesystem(url: str):
    """(fsspec file system, path inside it) of ``url``; a clear error if none serves it."""
    try:
        from fsspec.core import url_to_fs
    except ImportError:
        raise ParameterError(f"{url}: URLs need fsspec: pip install 'rawsim[s3]'") from None
    scheme = url.split("://", 1)[0]
    try:
        return url_to_fs(url)
    except (ImportError, ValueError) as err:
        package = _PACKAGES.get(scheme, f"an fsspec file system for {scheme}://")
        raise ParameterError(f"{url}: cannot open {scheme}:// ({err}); install {package}") from None


def join(url: str, *parts: str) -> str:
    """``url`` with ``parts`` appended as path components (``/``-separated)."""
    tail = "/".join(p for p in parts if p and p != ".")
    return f"{url.rstrip('/')}/{tail}" if tail else url


def find(url: str, extensions: Iterable[str]) -> tuple[list[tuple[str, str]], list[str]]:
    """Files at ``url``: ((url, key) taken, ignored urls). A folder is searched
    recursively for ``extensions`` (hidden names left out); a file is taken
    whatever its extension; nothing there raises FileNotFoundError."""
    fs, root = filesystem(url)
    exts = tuple(e.lower() for e in extensions)
    if fs.isfile(root):
        return [(url, PurePosixPath(root).name)], []
    if not fs.isdir(root):
        raise FileNotFoundError(url)
    taken, ignored = [], []
    for path in sorted(fs.find(root)):
        key = PurePosixPath(path).relative_to(PurePosixPath(root.rstrip("/"))).as_posix()
        if any(part.startswith(".") for part in key.split("/")):
            continue
        full = join(url, key)
        (taken if PurePosixPath(key).suffix.lower() in exts else ignored).append((full, key))
    return taken, [u for u, _ in ignored]


def exists(location: str | Path) -> bool:
    """Whether the file (local path or URL) exists."""
    if is_url(location):
        fs, path = filesystem(location)
        return fs.exists(path)
    return Path(location).exists()


def remove(location: str | Path) -> None:
    """Delete the file (local path or URL) if it is there."""
    if not is_url(location):
        Path(location).unlink(missing_ok=True)
        return
    fs, path = filesystem(location)
    if fs.exists(path):
        fs.rm_file(path)


def check_writable(url: str) -> None:
    """Write and delete a probe object under ``url``; raises OSError if that fails."""
    fs, root = filesystem(url)
    probe = f"{root.rstrip('/')}/.rawsim-probe-{secrets.token_hex(4)}"
    protocols = {fs.protocol} if isinstance(fs.protocol, str) else set(fs.protocol)
    try:
        if not protocols & _OBJECT_STORES:  # (making a "folder" there makes a bucket)
            fs.makedirs(root, exist_ok=True)
        fs.pipe_file(probe, b"rawsim")
        fs.rm_file(probe)
    except Exception as err:  # the file system's own errors too (credentials, no bucket)
        raise OSError(str(err) or type(err).__name__) from None
