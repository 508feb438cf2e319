"""Event-stream files, written step by step (memory stays flat for long sequences).

* ``h5``: the layout v2e writes (Hu et al. 2021): dataset ``events`` (N, 4) uint32
  rows ``[t µs, x, y, p]`` (p 1 ON, 0 OFF), ``frame_ts`` (uint32 µs) and
  ``frame_idx`` (uint64, the number of events up to each frame), and the
  parameters as the ``params`` attribute (JSON); uncompressed (gzip, v2e's
  choice, would take longer than the simulation). Needs h5py
  (``pip install 'rawsim[events]'``).
* ``txt``: the text format of ESIM and the RPG event-camera datasets, one event
  per line ``t x y p``, t in seconds with 9 decimals, p 1 or 0.
* ``npz``: arrays ``t`` (float64 s), ``x``, ``y`` (uint16), ``p`` (int8), the
  count maps ``events`` (steps, 2, H, W) int32, ``frame_ts`` and ``frames``. Held
  in memory until the end.

Every file is written to a temporary and renamed when complete.
"""

from __future__ import annotations

import json
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from rawsim.errors import ParameterError
from rawsim.io.atomic import atomic_output
from rawsim.io.pieces import open_empty

FORMATS = ("npz", "h5", "txt")
SUFFIX = {"npz": ".npz", "h5": ".h5", "txt": ".txt"}


class EventFile:
    """A stream file being written: ``add(batch, frame_time)`` per step, then ``close()``.

    Use as a context manager; on an error the temporary is removed.
    """

    def __init__(self, path: Path, fmt: str, shape: tuple[int, int], meta: dict):
        if fmt not in FORMATS:
            raise ParameterError(f"unknown event format {fmt!r}; valid: {', '.join(FORMATS)}")
        self.path, self.fmt, self.shape, self.meta = Path(path), fmt, shape, meta
        self.stack = ExitStack()
        self.count, self.frame_ts, self.frame_idx = 0, [], []
        self.parts: list = []
        self.h5 = self.text = None

    def __enter__(self) -> EventFile:
        tmp = self.stack.enter_context(atomic_output(self.path))
        if self.fmt == "h5":
            try:
                import h5py
            except ImportError:
                raise ParameterError(
                    "--format h5 needs h5py: pip install 'rawsim[events]' (or h5py)"
                ) from None
            self.h5 = self.stack.enter_context(h5py.File(tmp, "w"))
            # Uncompressed: gzip (v2e's choice) would take longer than the simulation.
            self.events = self.h5.create_dataset(
                "events", (0, 4), np.uint32, maxshape=(None, 4), chunks=(1 << 16, 4)
            )
            self.h5.attrs["params"] = json.dumps(self.meta)
        elif self.fmt == "txt":
            self.text = self.stack.enter_context(open_empty(tmp))
        self.tmp = tmp
        return self

    def start(self, frame_time: float) -> None:
        """The first frame's time (s): no events before it."""
        self.frame_ts.append(frame_time)
        self.frame_idx.append(0)

    def add(self, batch, frame_time: float) -> None:
        """One step's events (an :class:`~rawsim.events.stream.EventBatch`), ending at
        ``frame_time``."""
        n = batch.t.size
        if self.fmt == "h5":
            from rawsim.events import kernels as ee

            rows = np.empty((n, 4), dtype=np.uint32)
            ee.v2e_rows(batch.t, batch.x, batch.y, batch.p, rows)
            self.events.resize(self.count + n, axis=0)
            self.events[self.count :] = rows
        elif self.fmt == "txt":
            self.text.write(_lines(batch))
        else:
            self.parts.append(batch)
        self.count += n
        self.frame_ts.append(frame_time)
        self.frame_idx.append(self.count)

    def close(self, frames: list[str]) -> None:
        """Finish the file (``frames``: the input paths, in order) and rename it in place."""
        if self.fmt == "h5":
            self.h5.create_dataset(
                "frame_ts", data=np.round(np.array(self.frame_ts) * 1e6).astype(np.uint32)
            )
            self.h5.create_dataset("frame_idx", data=np.array(self.frame_idx, dtype=np.uint64))
        elif self.fmt == "npz":
            cat = lambda name: _Joined([getattr(b, name) for b in self.parts])  # noqa: E731
            with open_empty(self.tmp) as fh:
                _savez(
                    fh,
                    t=cat("t"),
                    x=cat("x"),
                    y=cat("y"),
                    p=cat("p"),
                    events=_Joined([b.counts for b in self.parts], stacked=True),
                    frame_ts=np.array(self.frame_ts),
                    frames=np.array(frames),
                    params=np.array(json.dumps(self.meta)),
                )
        self.stack.close()

    def __exit__(self, kind, value, tb) -> None:
        if kind is not None:
            self.stack.__exit__(kind, value, tb)


class _Joined:
    """Arrays of one dtype, joined along axis 0 (``np.concatenate``) or along a new one
    (``stacked``: ``np.stack``), without the copy: :func:`_savez` writes their bytes
    one after another, which are the joined array's in C order."""

    def __init__(self, parts: list[np.ndarray], stacked: bool = False):
        parts = [np.ascontiguousarray(a) for a in parts]
        first = parts[0]
        alike = slice(0 if stacked else 1, None)  # the shape the parts must share
        if any(a.dtype != first.dtype or a.shape[alike] != first.shape[alike] for a in parts):
            parts = [np.stack(parts) if stacked else np.concatenate(parts)]  # as numpy joins
            stacked = False
        self.parts, self.dtype = parts, parts[0].dtype
        if stacked:
            self.shape = (len(parts), *first.shape)
        else:
            self.shape = (sum(a.shape[0] for a in parts), *parts[0].shape[1:])


def _savez(fh, **arrays) -> None:
    """``np.savez(fh, **arrays)``, byte for byte (a zip of ``<name>.npy`` members, stored,
    zip64 headers), where an array may be :class:`_Joined`: its ``.npy`` header is the
    joined array's and its parts' bytes follow it, with no joined copy. A busy clip
    (64 M events, 1.3 GB) spent most of its writing in ``np.concatenate``,
    ``np.stack`` and the 16 MiB copies ``np.save`` makes of an array it writes into a
    zip member."""
    import zipfile

    from numpy.lib import format as npy

    with zipfile.ZipFile(fh, mode="w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, value in arrays.items():
            with zf.open(name + ".npy", "w", force_zip64=True) as member:
                if not isinstance(value, _Joined):
                    npy.write_array(member, np.asanyarray(value), allow_pickle=True)
                    continue
                header = npy.header_data_from_array_1_0(np.empty(0, value.dtype))
                npy.write_array_header_1_0(member, {**header, "shape": value.shape})
                for part in value.parts:
                    if part.size:
                        member.write(memoryview(part).cast("B"))


def _lines(batch) -> np.ndarray:
    """``t x y p`` lines (uint8), t in seconds with 9 decimals (from integer
    nanoseconds: no drift over long sequences)."""
    from rawsim.events import kernels as ee

    out = np.empty(batch.t.size * ee.LINE_BYTES, dtype=np.uint8)
    return out[: ee.text_lines(batch.t, batch.x, batch.y, batch.p, out)]
