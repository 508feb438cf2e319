"""What a benchmark's timings were taken on: printed at the top of every report.

CPU model, its vector extensions, the cores this process may use (affinity and
cgroup quota, :func:`rawsim.cores.usable_cores`), numba's compile target (the CPU
name and whether AVX-512 is in its features: ``NUMBA_CPU_NAME`` and
``NUMBA_CPU_FEATURES`` make numba target another CPU, e.g. ``znver3`` without
AVX-512 on a machine that has it), the engine's and torch's threads, and the load.
"""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path


def cpu() -> tuple[str, set[str]]:
    """The CPU's model name and its flags, from /proc/cpuinfo."""
    model, flags = platform.processor() or "unknown", set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and model in ("unknown", "x86_64", ""):
                model = value.strip()
            elif key.strip() in ("flags", "Features") and not flags:
                flags = set(value.split())
    except OSError:
        pass
    return model, flags


def numba_target() -> str:
    """numba's compile target: CPU name, AVX-512 or not, and who chose it."""
    import llvmlite.binding as llvm
    from numba.core import config

    name = config.CPU_NAME or llvm.get_host_cpu_name()
    features = config.CPU_FEATURES or llvm.get_host_cpu_features().flatten()
    avx512 = "+avx512f" in features.split(",")
    chosen = "NUMBA_CPU_NAME" if config.CPU_NAME else "host"
    return f"{name} ({chosen}), {'with' if avx512 else 'without'} AVX-512"


def describe() -> list[str]:
    """The report's first lines."""
    import numba

    from rawsim.cores import usable_cores

    model, flags = cpu()
    vector = [f for f in ("avx2", "fma", "avx512f") if f in flags]
    torch = sys.modules.get("torch")
    threads = f"numba {numba.config.NUMBA_NUM_THREADS} (engine: at most {usable_cores()})"
    if torch is not None:
        threads += f", torch {torch.get_num_threads()}"
    return [
        f"CPU: {model}; vector extensions: {', '.join(vector) or 'none of avx2, fma, avx512f'}",
        f"cores: {os.cpu_count()}, usable by this process {usable_cores()}; threads: {threads}",
        f"numba target: {numba_target()}; load average "
        + " ".join(f"{v:.2f}" for v in os.getloadavg()),
        f"Python {platform.python_version()}, numba {numba.__version__}",
    ]


if __name__ == "__main__":
    print("\n".join(describe()))
