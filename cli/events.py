"""``rawsim events``: a frame sequence → DVS event count maps."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rawsim_cli.options import PathType, output_options, usage_errors


@click.command("events")
@output_options
@click.argument("frames", nargs=-1, required=True, type=PathType("input"))
@click.option(
    "-o",
    "--output",
    "out_dir",
    required=True,
    type=PathType("out_folder"),
    help="Output folder (made when the first output is written): events.<format> "
    "(and preview/ with --preview).",
)
@click.option(
    "--fps",
    type=click.FloatRange(min=0, min_open=True),
    required=True,
    help="Frame rate of the sequence (dt = 1/fps).",
)
@click.option(
    "--threshold-pos",
    type=float,
    default=0.2,
    show_default=True,
    help="Contrast threshold θ+ (log intensity).",
)
@click.option(
    "--threshold-neg",
    type=float,
    default=0.2,
    show_default=True,
    help="Contrast threshold θ− (log intensity).",
)
@click.option(
    "--sigma-threshold",
    type=float,
    default=0.03,
    show_default=True,
    help="σ of the threshold noise |N(0, σ)| per pixel and step (0 = exact).",
)
@click.option(
    "--cutoff-hz",
    type=float,
    default=0.0,
    show_default=True,
    help="Temporal high-pass cut-off (0 = off).",
)
@click.option(
    "--leak-rate-hz",
    type=float,
    default=0.0,
    show_default=True,
    help="Leak events per pixel per second (positive).",
)
@click.option(
    "--shot-noise-rate-hz",
    type=float,
    default=0.0,
    show_default=True,
    help="Shot-noise events per pixel per second (both polarities).",
)
@click.option(
    "--refractory-s",
    type=click.FloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Refractory period: crossings this soon after a pixel's event are absorbed.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the randomness.")
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["npz", "h5", "txt"]),
    default="npz",
    show_default=True,
    help="Event stream file: npz (arrays t, x, y, p and the count maps), h5 (v2e's "
    "layout; needs h5py) or txt (ESIM/RPG: 't x y p' per line, seconds).",
)
@click.option(
    "--voxel-bins",
    type=click.IntRange(min=1),
    default=None,
    help="Also write voxels.npy: per step, a voxel grid of this many time bins.",
)
@click.option(
    "--preview",
    is_flag=True,
    help="Also write preview/step_NNNN.png: red positive, blue negative events.",
)
@click.option("--overwrite", is_flag=True, help="Replace existing outputs.")
@click.option(
    "-j",
    "--jobs",
    type=click.IntRange(min=1),
    default=None,
    help="Threads of the simulator (default: every core). Events do not depend on it.",
)
@click.option(
    "--device",
    type=click.Choice(["auto", "cpu", "cuda"]),
    default="cpu",
    show_default=True,
    help="cpu: the compiled engine; cuda: the torch reference on the GPU; auto: cuda if "
    "there is one. The same events, bit for bit, on each.",
)
@click.option("--json", "as_json", is_flag=True, help="Print a JSON record of the run on stdout.")
@click.pass_context
@usage_errors
def command(
    ctx,
    frames,
    out_dir,
    fps,
    threshold_pos,
    threshold_neg,
    sigma_threshold,
    cutoff_hz,
    leak_rate_hz,
    shot_noise_rate_hz,
    refractory_s,
    seed,
    fmt,
    voxel_bins,
    preview,
    overwrite,
    jobs,
    device,
    as_json,
):
    """Simulate an event camera watching FRAMES and write its event stream.

    FRAMES is a folder (its images in name order) or a list of image files, in
    time order, frame k at k/FPS seconds. 8/16-bit frames are sRGB-decoded to
    linear light; float frames (EXR) are linear; RGB becomes Rec. 709 luminance.

    Each pixel remembers the log intensity of its last event; between frames
    the log intensity is interpolated linearly, and each crossing of that
    reference ± θ is an event (x, y, t, polarity) at the crossing time (ESIM's
    model). Thresholds vary per pixel by N(0, --sigma-threshold) (fixed
    pattern, as v2e); --refractory-s, --leak-rate-hz, --shot-noise-rate-hz and
    --cutoff-hz add v2e's non-idealities. Randomness comes from a counter-based
    generator keyed by --seed: the same events for any --jobs.

    OUT/events.<format> holds the stream (see --format); events.npz also holds
    the count maps `events` (steps, 2, H, W), channel 0 ON.
    Existing outputs are skipped unless --overwrite.

    \b
    Example:
      rawsim events clip/ -o clip_events --fps 240 --format h5 --refractory-s 1e-4
    """
    from rawsim.errors import shown
    from rawsim.events.files import SUFFIX
    from rawsim.io.images import IMAGE_EXTENSIONS
    from rawsim.run.batch import discover

    # The usage errors first, before the simulator and its libraries are imported.
    paths = []
    for item in frames:
        found = discover([item], IMAGE_EXTENSIONS).found
        paths += [p for p, _ in found]
    if len(paths) < 2:
        given = ", ".join(shown(f) for f in frames)
        raise click.UsageError(
            f"{given}: {len(paths)} frame{'s' * (len(paths) != 1)} found, events need at "
            "least 2: give a folder of frames, or two or more image files in time order",
            ctx,
        )
    out = Path(out_dir)
    target = out / f"events{SUFFIX[fmt]}"
    if target.exists() and not overwrite:  # the same policy as every command: skip
        click.echo(f"skip: {target} exists (use --overwrite to replace it)", err=True)
        return

    import numpy as np

    from rawsim.events.files import EventFile
    from rawsim.events.stream import EventParams, EventStream, voxel_grid
    from rawsim.io.atomic import atomic_output
    from rawsim.io.images import write_image

    params = EventParams(
        threshold_pos, threshold_neg, sigma_threshold, cutoff_hz, leak_rate_hz, shot_noise_rate_hz
    )
    if jobs:
        from rawsim.engine import set_threads

        set_threads(jobs)
    where = None  # the compiled engine
    if device != "cpu":
        from rawsim.device import resolve_device

        where = None if resolve_device(device).type == "cpu" else "cuda"
    frames_in = _log_frames(paths, params.eps)
    first = next(frames_in)
    stream = EventStream(params, first.shape, seed, refractory_s, device=where)
    stream.start(first, 0.0)
    meta = {"fps": fps, "seed": seed, "refractory_s": refractory_s, **params.to_dict()}
    totals = np.zeros(2, dtype=np.int64)
    voxels, previews = [], []
    with EventFile(target, fmt, first.shape, meta) as sink:
        sink.start(0.0)
        for k, frame in enumerate(frames_in, start=1):
            t0 = stream.time
            batch = stream.step(frame, k / fps)
            sink.add(batch, k / fps)
            totals += batch.counts.reshape(2, -1).sum(axis=1)
            if voxel_bins:
                voxels.append(voxel_grid(batch, t0, 1.0 / fps, voxel_bins))
            if preview:
                previews.append(batch.counts)
        sink.close([str(p) for p in paths])
    written = [str(target)]
    if voxel_bins:
        with atomic_output(out / "voxels.npy") as tmp, open(tmp, "wb") as fh:
            np.save(fh, np.stack(voxels))
        written.append(str(out / "voxels.npy"))
    if preview:
        folder = out / "preview"  # made by the first preview written
        peak = max(max(int(c.max()) for c in previews), 1)
        for t, counts in enumerate(previews):
            level = np.round(counts * (255.0 / peak)).astype(np.uint8)
            rgb = np.stack([level[0], np.zeros_like(level[0]), level[1]], axis=-1)
            with atomic_output(folder / f"step_{t + 1:04d}.png") as tmp:
                write_image(tmp, rgb, "png")
    if as_json:
        record = {
            "frames": len(paths),
            "outputs": written,
            "events": {"on": int(totals[0]), "off": int(totals[1])},
            "seed": seed,
            "params": meta,
            "warnings": [],
        }
        click.echo(json.dumps(record))
    click.echo(
        f"rawsim: {len(paths)} frames → {target}: {int(totals[0])} positive, "
        f"{int(totals[1])} negative events",
        err=True,
    )


def _log_frames(paths, eps, ahead: int = 2):
    """Each frame's log luminance (H, W) float64, read ``ahead`` frames in advance by as
    many threads (PNG decoding costs about as much as simulating a quiet step)."""
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    from rawsim.errors import ParameterError
    from rawsim.events.stream import log_luminance

    with ThreadPoolExecutor(ahead, thread_name_prefix="rawsim-frames") as pool:
        pending = deque(pool.submit(log_luminance, p, eps) for p in paths[:ahead])
        shape = None
        for k in range(len(paths)):
            frame = pending.popleft().result()
            if k + ahead < len(paths):
                pending.append(pool.submit(log_luminance, paths[k + ahead], eps))
            if shape is not None and frame.shape != shape:
                raise ParameterError(
                    f"{paths[k]}: size {frame.shape[1]}×{frame.shape[0]} differs from "
                    f"{paths[0]} ({shape[1]}×{shape[0]})"
                )
            shape = frame.shape
            yield frame
