"""Event streams: (x, y, t, polarity) from frames, torch-free (see :class:`EventStream`).

The count-map model of the Python API, :class:`rawsim.events.sensor.EventSensor`, shares
:class:`~rawsim.events.params.EventParams`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from rawsim.errors import ParameterError
from rawsim.events.params import LUMA, EventParams


@dataclass
class EventBatch:
    """The events of one frame step, in time order, and their count maps.

    ``t`` float64 seconds, ``x``/``y`` uint16 pixel columns/rows, ``p`` int8 (1 ON,
    0 OFF); ``counts`` (2, H, W) int32, channel 0 ON.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    counts: np.ndarray


class EventStream:
    """An event camera watching frames: (x, y, t, polarity) events with their times.

    The model of ESIM (Rebecq et al., CoRL 2018) with v2e's non-idealities (Hu et
    al., CVPR-W 2021): each pixel remembers the log intensity of its last event;
    between frames the log intensity is interpolated linearly in time, and each
    crossing of the reference ± θ is an event at the crossing time (see
    :mod:`rawsim.events.kernels`). Per pixel, θ+ and θ− are the nominal thresholds
    plus N(0, ``sigma_threshold``) drawn once (fixed-pattern mismatch, at least
    0.01) from the counter-based generator keyed by ``seed``: unlike
    :class:`rawsim.events.sensor.EventSensor`'s fresh draw per step. ``refractory_s`` absorbs
    crossings that follow an event too soon; ``leak_rate_hz`` lowers the
    reference by that many θ+ per second (ON events in a still scene);
    ``shot_noise_rate_hz`` adds random events; ``cutoff_hz`` scales each step's
    change by 1 − τ/(τ + dt), as :meth:`rawsim.events.sensor.EventSensor.log_change`.

    With no mismatch, leak, refractory period or noise, a step from a fresh
    pixel gives :class:`rawsim.events.sensor.EventSensor`'s counts exactly; later steps keep the
    remainders that it drops.

    ``device`` None runs the compiled engine (:mod:`rawsim.events.kernels`); a torch
    device (``"cuda"``, ``"cpu"``) runs the torch reference there
    (:func:`rawsim.events.sensor.stream_step`). Both give the same events, bit for bit.
    """

    def __init__(
        self,
        params: EventParams,
        shape: tuple[int, int],
        seed: int = 0,
        refractory_s: float = 0.0,
        device: str | None = None,
    ) -> None:
        from rawsim.noise.philox import split_key

        if not (refractory_s >= 0 and math.isfinite(refractory_s)):
            raise ParameterError(f"refractory_s must be a finite number ≥ 0, got {refractory_s}")
        self.params, self.refractory = params, float(refractory_s)
        self.device = device
        h, w = shape
        if device is None:  # the compiled engine
            from rawsim.events import kernels as ee
            from rawsim.noise.kernels import np_key

            self.key = np_key(seed)
            jitter = np.empty((h, w, 2))
            ee.threshold_normals(*self.key, jitter)
            maximum = np.maximum
        else:  # the torch reference, on that device
            import torch

            from rawsim.events.sensor import threshold_normals

            self.key = split_key(seed)
            jitter = threshold_normals((h, w), self.key, device)
            maximum = lambda a, b: torch.clamp(a, min=b)  # noqa: E731
        sigma = params.sigma_threshold
        self.on = maximum(params.threshold_pos + sigma * jitter[..., 0], 0.01)
        self.off = maximum(params.threshold_neg + sigma * jitter[..., 1], 0.01)
        self.shape = (h, w)
        self.level = self.raw = self.ref = self.last = None
        self.time, self.steps = 0.0, 0

    def start(self, log_frame: np.ndarray, t: float) -> None:
        """The first frame (log intensity, (H, W) float64) at time ``t`` (s)."""
        self._check(log_frame)
        log_frame = self._here(log_frame)
        self.raw = self.level = log_frame  # read only: the frames are not changed
        self.ref = log_frame.clone() if self.device else log_frame.copy()
        if self.device:
            import torch

            self.last = torch.full_like(self.ref, -math.inf)
        else:
            self.last = np.full(self.shape, -np.inf)
        self.time, self.steps = float(t), 0

    def step(self, log_frame: np.ndarray, t: float) -> EventBatch:
        """Events from the previous frame to ``log_frame`` at time ``t`` (> the previous).

        ``log_frame`` is kept until the next step, not copied: do not change it.
        """
        if self.ref is None:
            raise ParameterError("EventStream.step before start: give the first frame to start")
        self._check(log_frame)
        log_frame = self._here(log_frame)
        dt = float(t) - self.time
        if not dt > 0:
            raise ParameterError(f"frame times must increase, got {t} after {self.time}")
        p = self.params
        gain = 1.0
        if p.cutoff_hz > 0:
            tau = 1.0 / (2 * math.pi * p.cutoff_hz)
            gain = 1 - tau / (tau + dt)
        level = log_frame if gain == 1.0 else self.level + gain * (log_frame - self.raw)
        p_half = p.shot_noise_rate_hz * dt / 2
        if p_half > 0.5:
            raise ParameterError(f"shot-noise probability per step {2 * p_half:g} > 1: lower it")
        run = (p.leak_rate_hz, self.refractory, self.time, dt, p_half)
        out = (self._step_engine if self.device is None else self._step_torch)(level, run)
        self.raw, self.level = log_frame, level
        self.time, self.steps = float(t), self.steps + 1
        return out

    def _step_engine(self, level: np.ndarray, run: tuple) -> EventBatch:
        import numba

        from rawsim.events import kernels as ee

        args = (self.level, level, self.ref, self.on, self.off, self.last, *run)
        args += (*self.key, self.steps)
        h, w = self.shape
        counts = np.empty((2, h, w), dtype=np.int32)
        rows = np.empty(h, dtype=np.int64)
        ee.count_events(*args, counts, rows)
        offsets = np.concatenate([[0], np.cumsum(rows)])
        n = int(offsets[-1])
        t_, x, y = np.empty(n), np.empty(n, np.uint16), np.empty(n, np.uint16)
        pol = np.empty(n, np.int8)
        ee.emit_events(*args, offsets[:-1], t_, x, y, pol)
        out = EventBatch(
            np.empty(n), np.empty_like(x), np.empty_like(y), np.empty_like(pol), counts
        )
        buckets, chunks = max(1, n // ee.SLOT_EVENTS), numba.get_num_threads()
        _, _, t0, dt, _ = run
        ee.time_order(t_, x, y, pol, t0, dt, buckets, chunks, out.t, out.x, out.y, out.p)
        return out

    def _step_torch(self, level, run: tuple) -> EventBatch:
        from rawsim.events.sensor import stream_step

        state = {"l0": self.level, "ref": self.ref, "on": self.on, "off": self.off}
        state["last"] = self.last
        t, x, y, p, counts = stream_step(state, level, *run, self.key, self.steps)
        return EventBatch(*(v.cpu().numpy() for v in (t, x, y, p, counts)))

    def _here(self, log_frame):
        """A frame where the state lives: a tensor on the torch device, or as given."""
        if self.device is None:
            return log_frame
        import torch

        return torch.as_tensor(log_frame, dtype=torch.float64).to(self.device)

    def _check(self, log_frame: np.ndarray) -> None:
        if log_frame.shape != self.shape:
            raise ParameterError(
                f"frame size {log_frame.shape[1]}×{log_frame.shape[0]} differs from the "
                f"first frame's {self.shape[1]}×{self.shape[0]}"
            )


def voxel_grid(batch: EventBatch, t0: float, dt: float, bins: int) -> np.ndarray:
    """One step's events → (bins, H, W) float32: each event's polarity (±1) split
    linearly between the two bins nearest its time (t − t0)/dt · (bins − 1)."""
    h, w = batch.counts.shape[1:]
    grid = np.zeros(bins * h * w, dtype=np.float64)
    if batch.t.size:
        pos = np.clip((batch.t - t0) / dt, 0, 1) * (bins - 1)
        lo = np.floor(pos).astype(np.int64)
        frac = pos - lo
        sign = np.where(batch.p == 1, 1.0, -1.0)
        site = batch.y.astype(np.int64) * w + batch.x
        grid += np.bincount(lo * h * w + site, sign * (1 - frac), grid.size)
        hi = np.minimum(lo + 1, bins - 1)
        grid += np.bincount(hi * h * w + site, sign * frac, grid.size)
    return grid.reshape(bins, h, w).astype(np.float32)


def log_luminance(path, eps: float) -> np.ndarray:
    """log(luminance + eps) of an image file, (H, W) float64: 8/16-bit images sRGB-decoded,
    float images linear, RGB as Rec. 709 luminance (alpha ignored)."""
    from rawsim.events import kernels as ee
    from rawsim.io.images import read_image

    decoded = read_image(path)
    pixels = decoded.pixels
    if pixels.shape[-1] not in (1, 3):
        pixels = pixels[..., :3] if pixels.shape[-1] > 3 else pixels[..., :1]
    out = np.empty(pixels.shape[:2])
    luma = np.array(LUMA)
    if decoded.is_float:
        ee.log_luma_float(np.ascontiguousarray(pixels, dtype=np.float64), luma, eps, out)
    else:
        ee.log_luma(np.ascontiguousarray(pixels), _srgb_table(decoded.code_max), luma, eps, out)
    return out


@functools.lru_cache(maxsize=4)
def _srgb_table(code_max: int) -> np.ndarray:
    """IEC 61966-2-1 decode of every code, (3, code_max + 1) float64."""
    from rawsim.isp.curves import _SRGB_A, _SRGB_DECODE_KNEE, _SRGB_GAMMA, _SRGB_SLOPE

    v = np.arange(code_max + 1, dtype=np.float64) / code_max
    power = ((np.maximum(v, _SRGB_DECODE_KNEE) + _SRGB_A) / (1 + _SRGB_A)) ** _SRGB_GAMMA
    table = np.where(v <= _SRGB_DECODE_KNEE, v / _SRGB_SLOPE, power)
    return np.ascontiguousarray(np.broadcast_to(table, (3, table.size)))
