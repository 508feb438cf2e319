"""Tiles handed out as threads ask for them: an atomic counter for the engine's loops.

numba's ``prange`` splits its range evenly between the threads when it starts
(the workqueue layer schedules statically), and the loop ends with the slowest
thread. In a batch the next file's raw is decoded beside the render, and on a
shared machine one core may be busier than the other: a thread that shares its
core finishes its half late while the other waits. Instead each thread (``prange``
over the threads, each with its own buffers) takes the next tile from a shared
counter until none is left, so a slowed thread simply renders fewer tiles.
Which thread renders a tile never changes its pixels.
"""

from __future__ import annotations

from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from rawsim.engine import configure

configure()


@intrinsic
def _fetch_add(typingctx, counter, value):
    """``counter[0] += value`` as one atomic step (LLVM ``atomicrmw add``, relaxed
    ordering: the counter orders nothing else); the value before."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64):
        return None
    sig = types.int64(counter, value)

    def codegen(context, builder, signature, args):
        array, step = args
        ty = signature.args[0]
        view = context.make_array(ty)(context, builder, array)
        zero = context.get_constant(types.intp, 0)
        pointer = cgutils.get_item_pointer(context, builder, ty, view, [zero])
        step = context.cast(builder, step, signature.args[1], types.int64)
        return builder.atomic_rmw("add", pointer, step, "monotonic")

    return sig, codegen


@njit(inline="always", cache=True)
def next_tile(counter) -> int:
    """The next tile's index from ``counter`` (int64, (1,), from 0): every index once,
    across threads; at or past the tile count once they are all taken."""
    return _fetch_add(counter, 1)
