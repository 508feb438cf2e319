"""Start-up latency of the command line: how long each command takes to answer a
usage error, in a fresh process, as a new user meets them (issue 42).

    python benchmarks/bench_startup.py [--runs N] [--git-ref REF]

Each case runs N times (default 7) as ``python -c 'from rawsim_cli.main import
main; main()' ARGS`` (what the ``rawsim`` script runs), each a new process;
the median wall time is reported, with the fastest and slowest, and the heavy
libraries (torch, numba, rawpy, OpenImageIO, SciPy, matplotlib) the command
imported before it answered (from ``-X importtime``, one extra run). Target: every
usage error under 0.5 s, none of those libraries imported.

``--git-ref REF`` also times the same cases on a checkout of REF (a temporary git
worktree, run with this interpreter and ``PYTHONPATH`` pointing at it), for a
before/after on the same machine at the same moment.

The report starts with the machine: CPU model, vector extensions (avx2, avx512f,
fma from /proc/cpuinfo), cores, and this process's CPU affinity. Sections are
functions in ``SECTIONS``; each takes the parsed arguments and returns its lines.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CODE = "import sys; from rawsim_cli.main import main; sys.argv[0] = 'rawsim'; main()"
HEAVY = ("torch", "numba", "rawpy", "OpenImageIO", "scipy", "matplotlib")

#: name → (arguments with {t} for a scratch folder, the exit status expected).
CASES = {
    "unprocess --iso -5": ("unprocess {t}/one -o {t}/out -p sony_a7s2 --iso -5", 2),
    "unprocess, no --iso": ("unprocess {t}/one -o {t}/out -p sony_a7s2", 2),
    "unprocess, unknown profile": ("unprocess {t}/one -o {t}/out -p sony_a7s9 --iso 800", 2),
    "unprocess, missing file": ("unprocess {t}/nope.png -o {t}/out -p sony_a7s2 --iso 800", 2),
    "unprocess, empty folder": ("unprocess {t}/empty -o {t}/out -p sony_a7s2 --iso 800", 2),
    "unprocess, -o is a file": ("unprocess {t}/one -o {t}/afile -p sony_a7s2 --iso 800", 2),
    "process, missing file": ("process {t}/nope.dng -o {t}/out", 2),
    "process, empty folder": ("process {t}/empty -o {t}/out", 2),
    "calibrate, empty folder": ("calibrate {t}/empty -o {t}/cam.json", 2),
    "events, one frame": ("events {t}/one -o {t}/out --fps 30", 2),
    "isp check, missing file": ("isp check {t}/isp.toml", 2),
    "profiles show, unknown": ("profiles show nikon_d86", 2),
    "profiles list": ("profiles list", 0),
    "profiles show sony_a7s2": ("profiles show sony_a7s2", 0),
    "--help": ("--help", 0),
}


def machine() -> list[str]:
    """CPU model, vector extensions, cores: what the timings were taken on."""
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
    vector = [f for f in ("avx2", "avx512f", "fma") if f in flags]
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return [
        f"CPU: {model}",
        f"vector extensions: {', '.join(vector) or 'none of avx2, avx512f, fma'}",
        f"cores: {os.cpu_count()} (this process may use {usable}); load average: "
        + " ".join(f"{v:.2f}" for v in os.getloadavg()),
        f"Python {platform.python_version()}, {sys.executable}",
    ]


def scratch(folder: Path) -> None:
    """The inputs of the cases: an empty folder, a folder of one image, a plain file."""
    (folder / "empty").mkdir()
    (folder / "one").mkdir()
    shutil.copy(ROOT / "tests" / "data" / "srgb" / "chelsea.png", folder / "one" / "a.png")
    (folder / "afile").write_text("x")


def once(args: list[str], env: dict, cwd: Path, importtime: bool = False):
    """(seconds, exit status, heavy modules imported) of one fresh process in ``cwd``
    (``python -c`` puts it first on the path: the tree whose packages it holds wins)."""
    cmd = [sys.executable, *(["-X", "importtime"] if importtime else []), "-c", CODE, *args]
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd)
    seconds = time.perf_counter() - start
    heavy = set()
    for line in done.stderr.splitlines():
        if line.startswith("import time:"):
            name = line.rsplit("|", 1)[1].strip()
            if name in HEAVY:
                heavy.add(name)
    return seconds, done.returncode, heavy


def time_cases(runs: int, env: dict, label: str, cwd: Path = ROOT) -> list[str]:
    """The usage-error latency of every case: median (min–max) of ``runs`` fresh processes."""
    lines = [f"{label}: median (min–max) of {runs} fresh processes"]
    worst = 0.0
    with tempfile.TemporaryDirectory(prefix="rawsim-startup-") as tmp:
        scratch(Path(tmp))
        for name, (template, expected) in CASES.items():
            args = template.format(t=tmp).split()
            _, code, heavy = once(args, env, cwd, importtime=True)
            times = [once(args, env, cwd)[0] for _ in range(runs)]
            median = statistics.median(times)
            if expected == 2:
                worst = max(worst, median)
            status = "" if code == expected else f"  (exit {code}, expected {expected})"
            loaded = ", ".join(sorted(heavy)) or "none"
            lines.append(
                f"  {name:<28} {median:6.3f} s ({min(times):.3f}–{max(times):.3f})"
                f"  heavy imports: {loaded}{status}"
            )
    lines.append(f"  slowest usage error: {worst:.3f} s (target < 0.5 s)")
    return lines


def usage_errors(args) -> list[str]:
    """This tree's usage-error latency, and REF's beside it with --git-ref."""
    env = dict(os.environ)
    lines = time_cases(args.runs, env, "this tree")
    if args.git_ref:
        with tempfile.TemporaryDirectory(prefix="rawsim-ref-") as tmp:
            tree = Path(tmp) / "tree"
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), args.git_ref],
                check=True,
                capture_output=True,
            )
            try:
                # The installed rawsim_cli is this tree's: point both packages at REF's.
                shim = Path(tmp) / "shim"
                shim.mkdir()
                (shim / "rawsim_cli").symlink_to(tree / "cli")
                (shim / "rawsim").symlink_to(tree / "rawsim")
                ref_env = {**env, "PYTHONPATH": str(shim)}
                lines += time_cases(args.runs, ref_env, f"{args.git_ref}", cwd=shim)
            finally:
                subprocess.run(
                    ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)],
                    check=False,
                    capture_output=True,
                )
    return lines


#: The report's sections, in order: each takes the arguments, returns its lines.
#: (A "first command of a fresh venv against the second" section goes here.)
SECTIONS = [usage_errors]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=7, help="fresh processes per case")
    parser.add_argument("--git-ref", help="also time this commit (e.g. HEAD~3), same machine")
    args = parser.parse_args()
    print("\n".join(machine()), flush=True)
    for section in SECTIONS:
        print()
        print("\n".join(section(args)), flush=True)


if __name__ == "__main__":
    main()
