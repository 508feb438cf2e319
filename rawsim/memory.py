"""New CPU tensors whose memory faults in by huge pages.

torch serves a large CPU tensor with its own ``mmap`` and leaves the kernel's
transparent huge pages to the system default, which is often ``madvise``: the
tensor's first write then faults in 4 KiB pages, one at a time. Two 96 MB
outputs cost 76 ms to fault in that way on the 2-core machine against 14 ms by
2 MiB pages, more than half the unprocess kernel itself. NumPy asks for huge
pages on its large arrays; :func:`empty` asks the same for torch's.
"""

from __future__ import annotations

import ctypes
import mmap
import sys

import torch

#: Huge pages are asked for on tensors of at least this many bytes.
MIN_BYTES = 4 << 20
_HUGE_PAGE = 2 << 20

_madvise = None
if sys.platform == "linux" and hasattr(mmap, "MADV_HUGEPAGE"):
    _madvise = ctypes.CDLL(None, use_errno=True).madvise
    _madvise.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    _madvise.restype = ctypes.c_int


def empty(shape: tuple[int, ...], dtype: torch.dtype, device="cpu") -> torch.Tensor:
    """``torch.empty(shape, dtype=dtype, device=device)``; on a Linux CPU, one of at
    least :data:`MIN_BYTES` has the whole 2 MiB pages inside its memory advised as
    huge pages (``MADV_HUGEPAGE``) before anything touches them. The advice is
    only advice: where the kernel refuses it, the tensor is the same, its pages
    small."""
    t = torch.empty(shape, dtype=dtype, device=device)
    if _madvise is not None and t.device.type == "cpu" and t.nbytes >= MIN_BYTES:
        start = -(-t.data_ptr() // _HUGE_PAGE) * _HUGE_PAGE
        end = (t.data_ptr() + t.nbytes) // _HUGE_PAGE * _HUGE_PAGE
        if end > start:
            _madvise(start, end - start, mmap.MADV_HUGEPAGE)
    return t
