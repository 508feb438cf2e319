"""Event camera (DVS) simulation from frames (SPEC "EventSensor").

A pixel fires an event each time its log intensity has changed by a contrast
threshold since the previous frame: positive for brightening, negative for
darkening. Counts per frame step are returned as (B, 2, H, W) maps, channel 0
positive and channel 1 negative. All randomness (threshold noise, leak and
shot-noise events) comes from an explicit ``torch.Generator``; with
``sigma_threshold = 0`` and no leak or shot noise the model is deterministic.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from rawsim.errors import ParameterError
from rawsim.events.params import LUMA, EventParams  # noqa: F401 - also the API's


def to_grey(frames: torch.Tensor) -> torch.Tensor:
    """(…, C, H, W) linear intensity → (…, 1, H, W): Rec. 709 luminance for C = 3."""
    c = frames.shape[-3]
    if c == 1:
        return frames
    if c != 3:
        raise ParameterError(f"frames must have 1 or 3 channels, got {c}")
    w = torch.tensor(LUMA, dtype=frames.dtype, device=frames.device).view(3, 1, 1)
    return (frames * w).sum(dim=-3, keepdim=True)


class EventSensor(nn.Module):
    """Events between frames of linear intensity (≥ 0, any scale: only ratios matter).

    Shapes: frames (B, C, H, W) with C = 1 or 3; events (B, 2, H, W) float counts,
    channel 0 positive, 1 negative. ``dt`` is the time between frames in seconds.
    """

    def __init__(self, params: EventParams | None = None, **kwargs) -> None:
        super().__init__()
        self.params = params if params is not None else EventParams(**kwargs)

    def log_change(self, frame: torch.Tensor, previous: torch.Tensor, dt: float) -> torch.Tensor:
        """Δ = log(I_t + ε) − log(I_{t−1} + ε) of the grey frames, (B, 1, H, W).

        With ``cutoff_hz`` > 0 it is scaled by (1 − α), α = τ/(τ + dt) and
        τ = 1/(2π f_c): changes slow against the cut-off are attenuated.
        """
        p = self.params
        delta = torch.log(to_grey(frame) + p.eps) - torch.log(to_grey(previous) + p.eps)
        if p.cutoff_hz > 0:
            tau = 1.0 / (2 * math.pi * p.cutoff_hz)
            delta = delta * (1 - tau / (tau + dt))
        return delta

    def forward(
        self,
        frame: torch.Tensor,
        previous: torch.Tensor,
        dt: float,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """Event counts from ``previous`` to ``frame`` (both (B, C, H, W)) → (B, 2, H, W).

        Counts are ⌊max(Δ, 0)/θ+⌋ and ⌊max(−Δ, 0)/θ−⌋, with |N(0, σ)| added to
        each threshold per pixel; then leak events, Bernoulli(leak_rate·dt), on
        the positive channel and shot-noise events, Bernoulli(rate·dt/2), on each.
        """
        p = self.params
        if frame.shape != previous.shape or frame.ndim != 4:
            raise ParameterError(
                f"frames must be two (B, C, H, W) tensors of one shape, got "
                f"{tuple(frame.shape)} and {tuple(previous.shape)}"
            )
        if not dt > 0:
            raise ParameterError(f"dt must be > 0 seconds, got {dt}")
        if p.random and generator is None:
            raise ParameterError(
                "threshold noise, leak and shot-noise events need a torch.Generator"
            )
        delta = self.log_change(frame, previous, dt)
        b, _, h, w = delta.shape
        theta = torch.tensor(
            [p.threshold_pos, p.threshold_neg], dtype=delta.dtype, device=delta.device
        ).view(1, 2, 1, 1)
        if p.sigma_threshold > 0:
            jitter = torch.randn(
                (b, 2, h, w), generator=generator, device=delta.device, dtype=delta.dtype
            )
            theta = theta + jitter.abs_() * p.sigma_threshold
        change = torch.cat([delta.clamp(min=0), (-delta).clamp(min=0)], dim=1)
        events = torch.floor(change / theta) + 0.0  # no negative zeros
        if p.leak_rate_hz > 0:
            events[:, :1] += self._bernoulli((b, 1, h, w), p.leak_rate_hz * dt, events, generator)
        if p.shot_noise_rate_hz > 0:
            events += self._bernoulli(
                (b, 2, h, w), p.shot_noise_rate_hz * dt / 2, events, generator
            )
        return events

    @staticmethod
    def _bernoulli(shape, prob: float, like: torch.Tensor, generator) -> torch.Tensor:
        if prob > 1:
            raise ParameterError(f"event probability per step {prob:g} > 1: lower the rate or dt")
        u = torch.rand(shape, generator=generator, device=like.device, dtype=like.dtype)
        return (u < prob).to(like.dtype)

    def forward_video(
        self, frames: torch.Tensor, dt: float, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Frames (B, T, C, H, W), T ≥ 2 → events (B, T−1, 2, H, W), step by step."""
        if frames.ndim != 5 or frames.shape[1] < 2:
            raise ParameterError(
                f"frames must have shape (B, T, C, H, W) with T ≥ 2, got {tuple(frames.shape)}"
            )
        steps = [
            self(frames[:, t], frames[:, t - 1], dt, generator) for t in range(1, frames.shape[1])
        ]
        return torch.stack(steps, dim=1)


def events_to_voxel_grid(events: torch.Tensor, num_bins: int) -> torch.Tensor:
    """Events (B, S, 2, H, W) over S steps → voxel grid (B, num_bins, H, W).

    Each step's net count (positive − negative) sits at normalised time
    t·(num_bins − 1)/(S − 1) and is split linearly between the two nearest
    bins, so every bin gets an even share of time and the total is kept.
    """
    if events.ndim != 5 or events.shape[2] != 2:
        raise ParameterError(f"events must have shape (B, S, 2, H, W), got {tuple(events.shape)}")
    if num_bins < 1:
        raise ParameterError(f"num_bins must be ≥ 1, got {num_bins}")
    b, s, _, h, w = events.shape
    net = events[:, :, 0] - events[:, :, 1]
    grid = net.new_zeros(b, num_bins, h, w)
    for t in range(s):
        pos = t * (num_bins - 1) / (s - 1) if s > 1 else 0.0
        lo = int(math.floor(pos))
        frac = pos - lo
        grid[:, lo] += net[:, t] * (1 - frac)
        if frac > 0:
            grid[:, lo + 1] += net[:, t] * frac
    return grid


def events_to_timestamp_image(events: torch.Tensor) -> torch.Tensor:
    """Events (B, S, 2, H, W) → (B, 2, H, W): the step (1…S) of each pixel's latest event.

    Each polarity channel is normalised by its maximum (0 where no event fired).
    """
    if events.ndim != 5 or events.shape[2] != 2:
        raise ParameterError(f"events must have shape (B, S, 2, H, W), got {tuple(events.shape)}")
    s = events.shape[1]
    steps = torch.arange(1, s + 1, dtype=events.dtype, device=events.device).view(1, s, 1, 1, 1)
    latest = ((events > 0).to(events.dtype) * steps).amax(dim=1)
    peak = latest.amax(dim=(-2, -1), keepdim=True)
    return torch.where(peak > 0, latest / peak.clamp(min=1), latest)


def threshold_normals(shape: tuple[int, int], key, device) -> torch.Tensor:
    """The torch reference of :func:`rawsim.events.kernels.threshold_normals`: standard
    normals (H, W, 2) float64, site 2·(i·W + j) + c of the ``threshold`` stream."""
    from rawsim.noise.reference import normal

    h, w = shape
    sites = torch.arange(2 * h * w, dtype=torch.int64, device=device)
    return normal(sites, key, "threshold").view(h, w, 2)


def stream_step(state: dict, l1: torch.Tensor, leak, refractory, t0, dt, p_half, key, step):
    """The torch reference of one :class:`~rawsim.events.stream.EventStream` step (the
    compiled :func:`rawsim.events.kernels.count_events` / ``emit_events`` /
    ``time_order``), for any device, the same bits.

    ``state`` holds (H, W) float64 tensors ``l0`` (the previous level), ``ref``,
    ``on``, ``off`` and ``last``; ``ref`` and ``last`` are updated in place.
    Returns (t, x, y, p, counts): the events in time order (ties in row-major pixel
    order, each pixel's crossings before its shot-noise event) and (2, H, W) counts.
    """
    from rawsim.noise.reference import uniforms

    l0, ref, on, off, last = (state[k] for k in ("l0", "ref", "on", "off", "last"))
    h, w = l0.shape
    d0 = l0 - ref
    m = l1 - l0 + leak * on * dt
    up = m > 0.0
    level = torch.where(up, on, off)
    beyond = torch.where(up, d0 + m, -d0 - m)
    crossings = torch.where(beyond >= level, torch.floor(beyond / level), 0.0)
    sign = torch.where(up, 1.0, -1.0)
    flat = [v.reshape(-1) for v in (d0, m, level, sign, crossings, last)]
    d0f, mf, levelf, signf, crossf, lastf = flat
    times, pixels, order = [], [], []
    live = torch.nonzero(crossf >= 1.0).squeeze(1)
    k = 1.0
    while live.numel():  # the k-th crossing of every pixel that has one
        t = t0 + dt * (signf[live] * k * levelf[live] - d0f[live]) / mf[live]
        fired = t - lastf[live] >= refractory
        times.append(t[fired])
        pixels.append(live[fired])
        order.append(torch.full_like(live[fired], int(k)))
        lastf[live[fired]] = t[fired]
        k += 1.0
        live = live[crossf[live] >= k]
    polarity = [up.reshape(-1)[p].to(torch.int8) for p in pixels]
    if p_half > 0.0:
        sites = torch.arange(h * w, dtype=torch.int64, device=l0.device)
        u0, u1 = uniforms(sites, "shot", key, step)
        noise = torch.nonzero((u0 < p_half) | (u0 > 1.0 - p_half)).squeeze(1)
        times.append(t0 + dt * u1[noise])
        pixels.append(noise)
        order.append(torch.full_like(noise, int(k)))
        polarity.append((u0[noise] < p_half).to(torch.int8))
    ref += sign * crossings * level - leak * on * dt
    last.copy_(lastf.view(h, w))
    t, pixel = torch.cat(times), torch.cat(pixels)
    rank = torch.cat(order)
    p = torch.cat(polarity) if polarity else torch.empty(0, dtype=torch.int8, device=l0.device)
    by_pixel = torch.argsort(pixel * (int(k) + 1) + rank)  # row-major, then per pixel
    by_time = torch.sort(t[by_pixel], stable=True).indices
    index = by_pixel[by_time]
    pixel, p = pixel[index], p[index]
    counts = torch.stack([torch.bincount(pixel[p == v], minlength=h * w) for v in (1, 0)]).to(
        torch.int32
    )
    x = (pixel % w).to(torch.uint16) if pixel.numel() else pixel.to(torch.uint16)
    y = (pixel // w).to(torch.uint16) if pixel.numel() else pixel.to(torch.uint16)
    return t[index], x, y, p, counts.view(2, h, w)
