"""One input file and where its outputs go: what a job is given, whether it runs
locally, in a pool worker, on a Ray cluster or on files in object storage."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Task:
    """One input file and where its outputs go.

    Attributes:
        source: the input file.
        key: its path relative to the input root given on the command line (POSIX
            form); names outputs and seeds the file's randomness.
        outputs: output kind → path.
        seed: the file's seed, derived from the run's seed and ``key``.
    """

    source: Path
    key: str
    outputs: dict[str, Path]
    seed: int
