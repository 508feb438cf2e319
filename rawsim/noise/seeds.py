"""Deterministic seeds derived from names, independent of order, workers and run splits."""

from __future__ import annotations

import hashlib


def derive_seed(*parts: object) -> int:
    """A 63-bit seed from the parts' text, e.g. ``derive_seed(42, "sub/a.png", "noise")``.

    Text is taken as its UTF-8 bytes; a file name that is not UTF-8 (decoded by
    Python with surrogate escapes) as its own bytes, so every name has a stable seed.
    """
    text = "\x1f".join(str(p) for p in parts).encode("utf-8", "surrogateescape")
    return int.from_bytes(hashlib.sha256(text).digest()[:8], "little") >> 1
