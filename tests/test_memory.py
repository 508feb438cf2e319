"""New CPU tensors in memory that earlier outputs freed (rawsim.memory)."""

from __future__ import annotations

import gc

import torch

from rawsim import memory

SHAPE = (1, 1, 1024, 1536)  # 6 MiB of float32: above MIN_BYTES


def test_empty_is_like_torch_empty():
    for shape, dtype in [((2, 3), torch.float32), (SHAPE, torch.uint16), ((0,), torch.int8)]:
        t = memory.empty(shape, dtype)
        assert t.shape == shape and t.dtype == dtype and t.device.type == "cpu"
        assert t.is_contiguous()
        t.fill_(1)
        assert int(t.sum()) == t.numel()


def test_a_freed_outputs_memory_is_the_next_ones():
    memory.release()
    t = memory.empty(SHAPE, torch.float32)
    address, view = t.data_ptr(), t[0, 0, 5:]
    del t
    gc.collect()
    assert len(memory._blocks) == 0  # a view still refers to it
    del view
    gc.collect()
    assert len(memory._blocks) == 1
    other = memory.empty((1, 1, 1024, 1024), torch.float32)  # another size: new memory
    other_address = other.data_ptr()
    assert other_address != address and len(memory._blocks) == 1
    del other
    gc.collect()
    assert len(memory._blocks) == 2  # the other size kept too, after the first
    other = memory.empty((1, 1, 1024, 1024), torch.float32)  # the second kept block
    assert other.data_ptr() == other_address and len(memory._blocks) == 1
    del other
    gc.collect()
    same = memory.empty((2, 1, 1024, 768), torch.float32)  # the same bytes, any shape
    assert same.data_ptr() == address and len(memory._blocks) == 1
    del same
    gc.collect()
    assert len(memory._blocks) == 2
    memory.release()
    assert len(memory._blocks) == 0


def test_at_most_keep_blocks_are_kept(monkeypatch):
    memory.release()
    tensors = [memory.empty(SHAPE, torch.float32) for _ in range(memory.KEEP + 2)]
    del tensors
    gc.collect()
    assert len(memory._blocks) == memory.KEEP
    memory.release()
    small = memory.empty((16,), torch.float32)  # below MIN_BYTES: torch's own
    small.resize_(1 << 20)  # a storage of torch's grows
    brain = memory.empty(SHAPE, torch.bfloat16)  # a type NumPy has not: torch's own
    brain.resize_(2 * brain.numel())
    monkeypatch.setenv("RAWSIM_KEEP_OUTPUTS", "0")
    plain = memory.empty(SHAPE, torch.float32)
    plain.resize_(2 * plain.numel())
    del plain
    gc.collect()
    assert len(memory._blocks) == 0
