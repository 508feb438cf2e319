"""New CPU tensors for rawsim's outputs, in memory that earlier outputs freed.

Each call of the Python API returns new output tensors, and a new large tensor
costs its first touch: the kernel faults in and zeroes every page. Two 96 MB
outputs (a 24 MP noisy and clean mosaic) cost 76 ms that way on the 2-core
machine, against 75 ms for the unprocess kernel itself. Huge pages (as NumPy
asks for) cut that to 14 ms on a quiet machine, but once another library has
freed gigabytes the kernel compacts memory to find them: 0.2–0.3 s a call.

A caller's loop drops the last call's outputs before or while it asks for the
next ones, so :func:`empty` keeps the memory of the outputs it made once
nothing refers to them (every tensor, view and array of them gone) and hands it
to the next tensor of the same size: a caching allocator, as torch keeps for
CUDA, for rawsim's large outputs only. At most :data:`KEEP` freed blocks are
kept (two calls' noisy and clean mosaics); :func:`release` frees them, and
``RAWSIM_KEEP_OUTPUTS=0`` turns the reuse off.
"""

from __future__ import annotations

import os
import threading
import weakref
from collections import deque

import numpy as np
import torch

#: Tensors of at least this many bytes come from kept blocks; smaller ones are new.
MIN_BYTES = 4 << 20
#: Freed blocks kept at most (the oldest freed is dropped first).
KEEP = 4
#: The NumPy type of each torch type a block can hold; others are always new.
_NUMPY = {
    t: np.dtype(n)
    for t, n in [
        (torch.uint8, np.uint8),
        (torch.uint16, np.uint16),
        (torch.int16, np.int16),
        (torch.int32, np.int32),
        (torch.int64, np.int64),
        (torch.float16, np.float16),
        (torch.float32, np.float32),
        (torch.float64, np.float64),
    ]
}


class _Blocks:
    """Freed blocks (uint8 arrays) by size; safe from any thread (the garbage
    collector gives blocks back wherever it runs)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._free: deque[np.ndarray] = deque()

    def take(self, nbytes: int) -> np.ndarray:
        with self._lock:
            for i, block in enumerate(self._free):
                if block.nbytes == nbytes:
                    del self._free[i]  # by place: arrays do not compare as objects
                    return block
        return np.empty(nbytes, np.uint8)

    def give(self, block: np.ndarray) -> None:
        with self._lock:
            self._free.append(block)
            while len(self._free) > KEEP:
                self._free.popleft()

    def clear(self) -> None:
        with self._lock:
            self._free.clear()

    def __len__(self) -> int:
        return len(self._free)


_blocks = _Blocks()


def empty(shape: tuple[int, ...], dtype: torch.dtype, device="cpu") -> torch.Tensor:
    """``torch.empty(shape, dtype=dtype, device=device)``: on the CPU, one of at least
    :data:`MIN_BYTES` in a kept block of its size if there is one (its values
    undefined, as ``torch.empty``'s are), its memory kept for the next such
    tensor once nothing refers to it. Such a tensor's storage cannot grow
    (``resize_`` beyond its size)."""
    dtype_np = _NUMPY.get(dtype)
    if (
        dtype_np is None
        or torch.device(device).type != "cpu"
        or os.environ.get("RAWSIM_KEEP_OUTPUTS", "1") == "0"
    ):
        return torch.empty(shape, dtype=dtype, device=device)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype_np.itemsize
    if nbytes < MIN_BYTES:
        return torch.empty(shape, dtype=dtype, device=device)
    block = _blocks.take(nbytes)
    array = block.view(dtype_np).reshape(shape)
    weakref.finalize(array, _blocks.give, block).atexit = False
    return torch.from_numpy(array)


def release() -> None:
    """Free the kept blocks (memory of outputs no longer referred to)."""
    _blocks.clear()
