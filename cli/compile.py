"""``rawsim compile``: build every compiled kernel for this CPU ahead of time.

The engine's kernels are numba functions cached on disk (see :mod:`rawsim.engine`).
Without this step the first command that needs a kernel compiles it (seconds to
minutes, logged as it happens); after it, the first command runs as fast as the
second. It runs each command the engine serves once, on tiny images made here,
in ``--jobs`` processes at a time: the commands compile exactly what they use.
First it byte-compiles rawsim's own modules, which an editable install, or an
environment with ``PYTHONDONTWRITEBYTECODE`` set, otherwise compiles from source
in every process (0.06 s of each command's start).
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

import click

from rawsim_cli.options import output_options, usage_errors

BAYER = "unprocess: 8-bit photo, Bayer, physics noise"
RENDER = "process: Bayer, 8/16-bit output"
OTHERS = "process: Bayer, the learned demosaic"
LENS = "unprocess: through a lens"
XTRANS = "unprocess: X-Trans"
FLOAT = "process: float output"
LINEAR = "unprocess: linear EXR, Gaussian noise"

#: (what it builds, the tasks whose outputs or kernels it needs, rawsim arguments, or
#: ``api TASK {in}``: a task of :mod:`rawsim_cli.compile_api`), in the order they
#: start: ``{in}`` is the folder of inputs, ``{out}`` of outputs.
#: Each command compiles what a user's run of its kind uses (input types, CFA, noise
#: model, output type, lens). A task whose kernels (or their callees) another also
#: compiles waits for it, and loads them from the cache instead of compiling them a
#: second time alongside.
TASKS: tuple[tuple[str, tuple[str, ...], str], ...] = (
    (
        BAYER,
        (),
        "unprocess {in}/photo.png -o {out}/bayer -p sony_a7s2 --iso 1600 --noise physics --clean",
    ),
    (
        "unprocess: 16-bit photo, Poisson-Gaussian noise",
        (),
        "unprocess {in}/photo16.png -o {out}/u16 -p nikon_d850 --iso 3200 --noise poisson-gaussian",
    ),
    (RENDER, (BAYER,), "process {out}/bayer/photo.dng -o {out}/png"),
    (FLOAT, (RENDER,), "process {out}/bayer/photo.dng -o {out}/exr --format exr"),
    (  # the learned demosaic's kernel is its own (rawsim.engine.process.bayer_kernel)
        OTHERS,
        (RENDER,),
        "process {out}/bayer/photo.dng -o {out}/learned --demosaic learned",
    ),
    (
        "process: float output, the learned demosaic",
        (OTHERS, FLOAT),
        "process {out}/bayer/photo.dng -o {out}/learned_exr --format exr --demosaic learned",
    ),
    ("process: half size", (RENDER,), "process {out}/bayer/photo.dng -o {out}/half --half-size"),
    (
        "process: profiled denoise",
        (RENDER,),
        "process {out}/bayer/photo.dng -o {out}/denoised --denoise profiled",
    ),
    (XTRANS, (BAYER,), "unprocess {in}/photo.png -o {out}/xtrans -p fujifilm_xt3 --iso 800"),
    ("process: X-Trans", (XTRANS,), "process {out}/xtrans/photo.dng -o {out}/xtrans_png"),
    (  # the profiled denoiser's colour pattern of a one-plane mosaic
        "process: X-Trans profiled denoise",
        (XTRANS, "process: profiled denoise"),
        "process {out}/xtrans/photo.dng -o {out}/xtrans_denoised --denoise profiled",
    ),
    (
        LENS,
        (BAYER,),
        "unprocess {in}/photo.png -o {out}/lens -p canon_eos_700d --iso 800 "
        "--lens 'Canon EF-S 18-55mm f/3.5-5.6 IS STM' --focal-length 18 --aperture 3.5",
    ),
    (  # the lens remap renders through the float output's kernel
        "process: lens correction",
        (LENS, FLOAT),
        "process {out}/lens/photo.dng -o {out}/lens_png --lens-correction auto",
    ),
    (
        LINEAR,
        (),
        "unprocess {in}/linear.exr -o {out}/linear -p nikon_d850 --iso 800 --noise gaussian",
    ),
    (  # the linear EXR reaches 1.5: its DNG clips (the render's highlight kernels)
        "process: highlight reconstruction",
        (LINEAR, RENDER),
        "process {out}/linear/linear.dng -o {out}/reconstruct --highlights reconstruct",
    ),
    (
        "process: unclip",
        (LINEAR, RENDER),
        "process {out}/linear/linear.dng -o {out}/unclip --highlights unclip",
    ),
    (  # the integral's kernel; then the linear EXR's unprocess kernel, from the cache
        "unprocess: spectral scenes",
        (LINEAR,),
        "unprocess {in}/spectral -o {out}/spectral -p nikon_d850 --iso 800",
    ),
    (
        "unprocess: monochrome sensor",
        (BAYER,),
        "unprocess {in}/photo.png -o {out}/mono -p sony_a7s2 --iso 800 --sensor mono",
    ),
    ("events", (), "events {in}/frames -o {out}/events --fps 100"),
    # the Python API's arrays (tensor views, int32 codes, float32 outputs): rawsim_cli.compile_api
    ("Python API: UnprocessDataset", (), "api dataset {in}"),
    ("Python API: unprocess", (), "api unprocess {in}"),
    ("Python API: process", (), "api process {in}"),
)

#: The line :mod:`rawsim.engine.compile_log` logs as a kernel's compile ends (its
#: ``on_end``), as the command's stderr shows it: how a task counts its kernels.
_COMPILED = re.compile(r"^rawsim: compiled (\S+) in ", re.M)


@click.command("compile")
@output_options
@click.option(
    "-j",
    "--jobs",
    type=click.IntRange(min=1),
    default=None,
    help="Commands compiled at a time (default: the cores this process may use).",
)
@usage_errors
@click.pass_context
def command(ctx, jobs):
    """Compile the engine's kernels for this CPU now, so no later command waits.

    Each command the compiled engine serves (unprocess, process, events, in each
    of their kinds: 8/16-bit and float inputs, noise models, Bayer and X-Trans,
    lenses, float outputs), and the Python API (rawsim.unprocess, rawsim.process,
    UnprocessDataset), is run once on tiny images in a temporary folder; numba
    caches what they compile on disk, where every later run loads it. Run it once
    after installing or upgrading rawsim (a few minutes); a second run finds the
    kernels cached and takes seconds. Progress goes to stderr.

    \b
    Example:
      pip install rawsim && rawsim compile
    """
    from rawsim.cores import usable_cores

    jobs = jobs or usable_cores()
    quiet = (ctx.obj or {}).get("quiet")
    started = time.monotonic()
    if not quiet:
        click.echo(
            f"rawsim: compiling the engine's kernels: {len(TASKS)} commands, {jobs} at a time",
            err=True,
        )
    modules = byte_compile(jobs)
    if not quiet:
        click.echo(f"rawsim: byte-compiled {modules} modules", err=True)
    compiled = 0
    with tempfile.TemporaryDirectory(prefix="rawsim-compile-") as tmp:
        folders = {"in": Path(tmp) / "in", "out": Path(tmp) / "out"}
        _inputs(folders["in"])
        for done, (what, seconds, kernels) in enumerate(_schedule(folders, jobs), 1):
            compiled += len(kernels)
            n = len(kernels)
            news = f"{n} kernel{'s' * (n != 1)} compiled" if kernels else "cached already"
            if not quiet:
                click.echo(
                    f"rawsim: [{done}/{len(TASKS)}] {what}: {news} ({seconds:.1f} s)", err=True
                )
    click.echo(
        f"rawsim: {compiled} kernels compiled in {time.monotonic() - started:.1f} s; "
        "later runs load them from numba's cache",
        err=True,
    )


def byte_compile(jobs: int = 1, folders: list[Path] | None = None) -> int:
    """Write the bytecode (``__pycache__``) of every module in ``folders`` (default:
    the ``rawsim`` and ``rawsim_cli`` packages) that lacks an up-to-date one, even
    where ``PYTHONDONTWRITEBYTECODE`` is set: how many were written. A folder this
    process may not write to (a system install, whose bytecode pip wrote) is left
    as it is."""
    import compileall
    import os

    import rawsim
    import rawsim_cli

    if folders is None:
        folders = [Path(rawsim.__file__).parent, Path(rawsim_cli.__file__).parent]
    written = 0
    for folder in folders:
        if not os.access(folder, os.W_OK):
            continue
        before = _bytecode(folder)
        compileall.compile_dir(folder, quiet=2, workers=jobs)
        written += sum(before.get(p) != t for p, t in _bytecode(folder).items())
    return written


def _bytecode(folder: Path) -> dict[Path, int]:
    """The bytecode files under ``folder`` and their modification times (ns)."""
    return {p: p.stat().st_mtime_ns for p in folder.rglob("__pycache__/*.pyc")}


def _schedule(folders: dict[str, Path], jobs: int):
    """Run :data:`TASKS`, ``jobs`` at a time, each once the tasks it needs are done;
    yield (what, seconds, kernels compiled) as each ends."""
    waiting, finished = list(TASKS), set()
    with ThreadPoolExecutor(jobs) as pool:
        running = {}
        while waiting or running:
            for task in [t for t in waiting if finished.issuperset(t[1])]:
                if len(running) == jobs:
                    break
                waiting.remove(task)
                running[pool.submit(_run, task[2], folders)] = task[0]
            ended = next(as_completed(running))
            what = running.pop(ended)
            finished.add(what)
            yield (what, *ended.result())


def _run(args: str, folders: dict[str, Path]) -> tuple[float, list[str]]:
    """Run one rawsim command (or Python API task) in a fresh process; its seconds and
    the kernels it compiled."""
    argv = [a.format_map(folders) for a in shlex.split(args)]
    module = "rawsim_cli.main"
    if argv[0] == "api":
        module, argv = "rawsim_cli.compile_api", argv[1:]
    started = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", module, *argv],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
    )
    if proc.returncode:
        lines = proc.stderr.strip().splitlines()
        api = module != "rawsim_cli.main"
        command = f"python -m {module}" if api else "rawsim"
        rerun = "rerun it to see the traceback" if api else "rerun it with --debug to see why"
        raise click.ClickException(
            f"'{command} {' '.join(argv)}' failed while compiling (exit {proc.returncode}): "
            f"{lines[-1] if lines else 'no message'}; {rerun}"
        )
    return time.perf_counter() - started, _COMPILED.findall(proc.stderr)


def _inputs(folder: Path) -> None:
    """The tiny inputs: a 96 × 144 8-bit and 16-bit photo, a linear EXR of it, three
    frames for events, and two spectral scenes (npz; the second of odd size, cropped
    to even in place: the integral's kernel reads it with strides). Smooth gradients
    with a little texture: every code path (highlights, darks) is reached."""
    import numpy as np

    from rawsim.io.images import write_image

    folder.mkdir()
    (folder / "frames").mkdir()
    y, x = np.mgrid[0:96, 0:144].astype(np.float32)
    base = np.stack([x / 143, y / 95, 0.5 + 0.5 * np.sin(x / 7) * np.cos(y / 5)], axis=-1)
    photo = np.clip(base, 0, 1)
    write_image(folder / "photo.png", np.round(photo * 255).astype(np.uint8), "png")
    write_image(folder / "photo16.png", np.round(photo * 65535).astype(np.uint16), "png")
    write_image(folder / "linear.exr", (photo**2.2 * 1.5).astype(np.float32), "exr", color=None)
    for i in range(3):
        frame = np.clip(photo * (0.6 + 0.2 * i), 0, 1)
        write_image(folder / "frames" / f"{i}.png", np.round(frame * 255).astype(np.uint8), "png")
    (folder / "spectral").mkdir()
    nm = np.arange(400, 701, 10.0)
    bells = np.exp(-0.5 * ((nm - np.array([[610.0], [540.0], [455.0]])) / 40) ** 2)  # (3, 31)
    scene = np.minimum(photo**2.2 @ bells, 1).astype(np.float32)  # reflectances, 0–1
    np.savez(folder / "spectral" / "scene.npz", spectra=scene, wavelengths=nm)
    np.savez(folder / "spectral" / "odd.npz", spectra=scene[:95, :143], wavelengths=nm)
