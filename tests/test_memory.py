"""New CPU tensors advised as huge pages (rawsim.memory)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
import torch

from rawsim import memory

THP = Path("/sys/kernel/mm/transparent_hugepage/enabled")
MODE = re.search(r"\[(\w+)\]", THP.read_text()).group(1) if THP.exists() else None


def huge_page_eligible(address: int) -> bool:
    """Whether the kernel may back the mapping that holds ``address`` by huge pages
    (``THPeligible`` of its entry in /proc/self/smaps)."""
    inside = False
    for line in Path("/proc/self/smaps").read_text().splitlines():
        span = re.match(r"([0-9a-f]+)-([0-9a-f]+) ", line)
        if span:
            inside = int(span.group(1), 16) <= address < int(span.group(2), 16)
        elif inside and line.startswith("THPeligible:"):
            return line.split()[1] == "1"
    raise AssertionError(f"no mapping holds {address:#x}")


def test_empty_is_torch_empty():
    for shape, dtype in [
        ((2, 3), torch.float32),
        ((1, 1, 1500, 2000), torch.uint16),
        ((0,), torch.int8),
    ]:
        t = memory.empty(shape, dtype)
        assert t.shape == shape and t.dtype == dtype and t.device.type == "cpu"
        assert t.is_contiguous()
        t.fill_(1)  # writable, resizable storage like any torch tensor
        t.resize_(4)


@pytest.mark.skipif(
    sys.platform != "linux" or MODE not in ("always", "madvise"),
    reason=f"transparent huge pages are {MODE or 'absent'} here",
)
def test_large_tensors_are_advised_as_huge_pages():
    size = 64 << 20  # over glibc's largest mmap threshold: a mapping of its own
    t = memory.empty((size // 4,), torch.float32)
    inner = -(-t.data_ptr() // (2 << 20)) * (2 << 20)  # the first whole 2 MiB page
    assert huge_page_eligible(inner)
    plain = torch.empty(size // 4, dtype=torch.float32)
    if MODE == "madvise":  # the advice is what makes the difference
        assert not huge_page_eligible(-(-plain.data_ptr() // (2 << 20)) * (2 << 20))
