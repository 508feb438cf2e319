"""The parameters shared by the event models: the count-map model
(:mod:`rawsim.events.sensor`) and the event-stream simulator (:mod:`rawsim.events.stream`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from rawsim.errors import ParameterError

#: Rec. 709 luminance weights for RGB frames.
LUMA = (0.2126, 0.7152, 0.0722)


@dataclass(frozen=True)
class EventParams:
    """Parameters of :class:`rawsim.events.sensor.EventSensor` and
    :class:`rawsim.events.stream.EventStream`
    (SPEC defaults).

    Attributes:
        threshold_pos, threshold_neg: contrast thresholds θ+ and θ− (log units).
        sigma_threshold: σ of the threshold noise: |N(0, σ)| added per pixel and step
            (EventSensor), or N(0, σ) per pixel once, a fixed pattern (EventStream).
        cutoff_hz: cut-off frequency of the temporal high-pass, 0 = off.
        leak_rate_hz: rate of leak events (positive), per pixel.
        shot_noise_rate_hz: rate of shot-noise events, per pixel, split evenly
            between the polarities.
        eps: offset inside the logarithm, log(I + eps).
    """

    threshold_pos: float = 0.2
    threshold_neg: float = 0.2
    sigma_threshold: float = 0.03
    cutoff_hz: float = 0.0
    leak_rate_hz: float = 0.0
    shot_noise_rate_hz: float = 0.0
    eps: float = 1e-7

    def __post_init__(self) -> None:
        for name in ("threshold_pos", "threshold_neg"):
            if not getattr(self, name) > 0:
                raise ParameterError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("sigma_threshold", "cutoff_hz", "leak_rate_hz", "shot_noise_rate_hz"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise ParameterError(f"{name} must be a finite number ≥ 0, got {value}")
        if not self.eps > 0:
            raise ParameterError(f"eps must be > 0, got {self.eps}")

    @property
    def random(self) -> bool:
        """Whether the model draws random numbers."""
        return self.sigma_threshold > 0 or self.leak_rate_hz > 0 or self.shot_noise_rate_hz > 0

    def to_dict(self) -> dict:
        return asdict(self)
