"""Processing: a camera raw file → an RGB image file, through the configurable ISP."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from rawsim._version import __version__
from rawsim.batch import Task
from rawsim.device import resolve_device
from rawsim.errors import ParameterError
from rawsim.io.atomic import atomic_output
from rawsim.io.images import OUTPUT_FORMATS, write_image
from rawsim.io.raw import RawImage, read_raw
from rawsim.isp.pipeline import build_isp, config_to_toml, default_config, validate_config


@dataclass(frozen=True)
class ProcessOptions:
    """Options of the files job.

    Attributes:
        config: validated ISP config (see :mod:`rawsim.isp.pipeline`).
        fmt: output format, one of ``OUTPUT_FORMATS``.
        bits: 8 or 16 (PNG/TIFF/JPEG), 16 (half) or 32 (float) for EXR.
        device: ``cpu``, ``cuda`` or ``auto``.
    """

    config: list = field(default_factory=default_config)
    fmt: str = "png"
    bits: int = 8
    device: str = "cpu"

    def output_suffixes(self) -> dict[str, str]:
        return {"image": OUTPUT_FORMATS[self.fmt], "json": ".json"}

    def effective_config(self) -> list[dict]:
        """EXR is scene-linear: its renders skip the tone curve, transfer and YCbCr."""
        if self.fmt != "exr":
            return self.config
        return [
            dict(s, enabled=False) if s["name"] in ("tone", "transfer", "ycbcr") else s
            for s in self.config
        ]


def raw_tensor(raw: RawImage, device) -> torch.Tensor:
    """The raw's data as float32 DN, (1, 1, H, W) for a mosaic or (1, 3, H, W)."""
    data = torch.from_numpy(raw.data.astype(np.float32)).to(device)
    return data[None, None] if raw.cfa is not None else data.permute(2, 0, 1)[None]


def render(raw: RawImage, config: list[dict], device="cpu") -> tuple[torch.Tensor, dict]:
    """Run the ISP of ``config`` on ``raw``: returns (1, 3, H, W) and the resolved values."""
    isp = build_isp(validate_config(config), raw).to(device)
    with torch.no_grad():
        out = isp(raw_tensor(raw, device))
    return out, isp.info


def process_file(task: Task, options: ProcessOptions) -> dict:
    """Render one raw file to ``task.outputs["image"]`` and its sidecar JSON."""
    if options.fmt not in OUTPUT_FORMATS:
        raise ParameterError(f"unknown format {options.fmt!r}; valid: {', '.join(OUTPUT_FORMATS)}")
    raw = read_raw(task.source)
    config = options.effective_config()
    device = resolve_device(options.device)
    rgb, info = render(raw, config, device)
    height, width = rgb.shape[-2:]
    enabled = {s["name"]: s for s in config if s["enabled"]}
    space = enabled["color_matrix"]["output_space"] if "color_matrix" in enabled else "camera"
    encoded = "transfer" in enabled and enabled["transfer"]["function"] == "srgb"
    srgb = space == "srgb" and "ycbcr" not in enabled and (options.fmt == "exr" or encoded)
    meta = {
        "rawsim_version": __version__,
        "input": task.key,
        "camera": {"make": raw.make, "model": raw.model},
        "cfa_pattern": None if raw.cfa is None else raw.cfa.pattern,
        "black_level": np.asarray(raw.black_level).tolist(),
        "white_level": raw.white_level,
        "iso": raw.iso,
        "orientation": raw.orientation,
        "width": width,
        "height": height,
        "format": options.fmt,
        "bits": options.bits,
        "config": config,
        "config_toml": config_to_toml(config),
        **info,
    }
    with atomic_output(task.outputs["image"]) as tmp:
        write_image(
            tmp, rgb[0], options.fmt, options.bits, srgb, {"Software": f"rawsim {__version__}"}
        )
    with atomic_output(task.outputs["json"]) as tmp:
        Path(tmp).write_text(json.dumps(meta, indent=2) + "\n")
    return meta
