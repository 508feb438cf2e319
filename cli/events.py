"""``rawsim events``: a frame sequence → DVS event count maps."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rawsim_cli.options import output_options, usage_errors


@click.command("events")
@output_options
@click.argument("frames", nargs=-1, required=True, type=click.Path(exists=True))
@click.option(
    "-o",
    "--output",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False),
    help="Output folder: events.npz (and preview/ with --preview).",
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
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the randomness.")
@click.option(
    "--preview",
    is_flag=True,
    help="Also write preview/step_NNNN.png: red positive, blue negative events.",
)
@click.option("--overwrite", is_flag=True, help="Replace existing outputs.")
@usage_errors
def command(
    frames,
    out_dir,
    fps,
    threshold_pos,
    threshold_neg,
    sigma_threshold,
    cutoff_hz,
    leak_rate_hz,
    shot_noise_rate_hz,
    seed,
    preview,
    overwrite,
):
    """Simulate an event camera watching FRAMES and write its event count maps.

    FRAMES is a folder (its images in name order) or a list of image files, in
    time order. 8/16-bit frames are sRGB-decoded to linear light; float frames
    (EXR) are linear. Between consecutive frames each pixel fires
    ⌊Δ log I / θ⌋ events per polarity (EventSensor, see the README).

    OUT/events.npz holds `events`, int32 (T−1, 2, H, W) with channel 0 positive
    and 1 negative, `frames` (the inputs in order) and `params` (JSON).

    \b
    Example:
      rawsim events clip/ -o clip_events --fps 240 --sigma-threshold 0 --preview
    """
    import numpy as np
    import torch

    from rawsim.batch import discover
    from rawsim.errors import ParameterError
    from rawsim.events import EventParams, EventSensor
    from rawsim.io.atomic import atomic_output
    from rawsim.io.images import IMAGE_EXTENSIONS, read_image, to_samples, write_image
    from rawsim.sensors import display_to_linear

    out = Path(out_dir)
    target = out / "events.npz"
    if target.exists() and not overwrite:  # the same policy as every command: skip
        click.echo(f"skip: {target} exists (use --overwrite to replace it)", err=True)
        return
    paths = []
    for item in frames:
        found = discover([item], IMAGE_EXTENSIONS).found
        paths += [p for p, _ in found]
    if len(paths) < 2:
        raise ParameterError(f"need at least 2 frames, got {len(paths)}")
    params = EventParams(
        threshold_pos, threshold_neg, sigma_threshold, cutoff_hz, leak_rate_hz, shot_noise_rate_hz
    )
    sensor = EventSensor(params)
    generator = torch.Generator().manual_seed(seed)
    dt = 1.0 / fps

    def load(path):
        decoded = read_image(path)
        x = torch.from_numpy(decoded.pixels.astype(np.float32)).permute(2, 0, 1)[None]
        if not decoded.is_float:
            x = display_to_linear(x / decoded.code_max)
        return x

    previous = load(paths[0])
    steps = []
    for path in paths[1:]:
        frame = load(path)
        if frame.shape != previous.shape:
            raise ParameterError(
                f"{path}: size {frame.shape[-1]}×{frame.shape[-2]} differs from {paths[0]} "
                f"({previous.shape[-1]}×{previous.shape[-2]})"
            )
        steps.append(sensor(frame, previous, dt, generator)[0].to(torch.int32))
        previous = frame
    events = torch.stack(steps).numpy()
    out.mkdir(parents=True, exist_ok=True)
    meta = {"fps": fps, "seed": seed, **params.to_dict()}
    with atomic_output(target) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(
            fh,
            events=events,
            frames=np.array([str(p) for p in paths]),
            params=np.array(json.dumps(meta)),
        )
    if preview:
        folder = out / "preview"
        folder.mkdir(exist_ok=True)
        peak = max(int(events.max()), 1)
        for t, step in enumerate(torch.from_numpy(events).float() / peak):
            rgb = torch.stack([step[0], torch.zeros_like(step[0]), step[1]])
            with atomic_output(folder / f"step_{t + 1:04d}.png") as tmp:
                write_image(tmp, to_samples(rgb, "png", 8), "png")
    total = events.sum(axis=(0, 2, 3))
    click.echo(
        f"rawsim: {len(paths)} frames → {target}: {int(total[0])} positive, "
        f"{int(total[1])} negative events",
        err=True,
    )
