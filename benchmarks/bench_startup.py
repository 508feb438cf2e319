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

``--fresh-venv`` adds the first hour of a new user: the checkout copied into an
empty folder (as CI does), a new virtual environment, ``pip install -c
constraints.txt -e .`` timed, then the README's quickstart command
(``rawsim unprocess examples/photos …``) and a ``rawsim process`` of one of its
DNGs, each run twice, the first beside the second: once without ``rawsim
compile`` (the first run compiles what it uses) and once, on an empty numba cache
(``NUMBA_CACHE_DIR``), after it. Target: after ``rawsim compile``, the first
command within 2× of the second. Several minutes.

The report starts with the machine (:mod:`machine`). Sections are functions in
``SECTIONS``; each takes the parsed arguments and returns its lines.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import describe

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


def fresh_venv(args) -> list[str]:
    """A new user's first commands, in a copy of the checkout with a new venv."""
    if not args.fresh_venv:
        return []
    lines = ["first commands after a fresh install (a copy of the checkout, a new venv):"]
    with tempfile.TemporaryDirectory(prefix="rawsim-fresh-") as tmp:
        tree, venv = Path(tmp) / "rawsim", Path(tmp) / "venv"
        files = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            capture_output=True,
            check=True,
        ).stdout.split(b"\0")
        for name in filter(None, files):
            (tree / os.fsdecode(name)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / os.fsdecode(name), tree / os.fsdecode(name), follow_symlinks=False)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        env = {**os.environ, "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}"}
        env.pop("NUMBA_CACHE_DIR", None)

        def run(command: str, run_env: dict) -> float:
            start = time.perf_counter()
            subprocess.run(
                command,
                shell=True,
                cwd=tree,
                env=run_env,
                check=True,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            return time.perf_counter() - start

        seconds = run("pip install -q -c constraints.txt -e .", env)
        lines.append(f"  pip install -c constraints.txt -e .      {seconds:7.1f} s")
        quickstart = (
            "rawsim unprocess examples/photos -o {o} --profile sony_a7s2 --iso 1600 --clean"
        )
        render = "rawsim process {o}/chelsea.dng -o {o}/rgb"
        cases = [("without rawsim compile", env, None)]
        cases.append(
            (
                "after rawsim compile, empty cache",
                {**env, "NUMBA_CACHE_DIR": f"{tmp}/cache"},
                "rawsim compile",
            )
        )
        for k, (label, run_env, first) in enumerate(cases):
            lines.append(f"  {label}:")
            if first:
                lines.append(f"    {first:<38} {run(first, run_env):7.1f} s")
            for name, template in (
                ("unprocess (quickstart)", quickstart),
                ("process one DNG", render),
            ):
                a = run(template.format(o=f"out{k}a"), run_env)
                b = run(template.format(o=f"out{k}b"), run_env)
                lines.append(
                    f"    {name:<24} first {a:6.1f} s, second {b:5.1f} s: {a / b:5.1f}×"
                    + (" (target ≤ 2×)" if first else "")
                )
    return lines


#: The report's sections, in order: each takes the arguments, returns its lines.
SECTIONS = [usage_errors, fresh_venv]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=7, help="fresh processes per case")
    parser.add_argument("--git-ref", help="also time this commit (e.g. HEAD~3), same machine")
    parser.add_argument(
        "--fresh-venv", action="store_true", help="also a new venv's first commands (minutes)"
    )
    args = parser.parse_args()
    print("\n".join(describe()), flush=True)
    for section in SECTIONS:
        lines = section(args)
        if lines:
            print()
            print("\n".join(lines), flush=True)


if __name__ == "__main__":
    main()
