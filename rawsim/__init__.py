"""rawsim: raw image unprocessing and processing on a differentiable torch ISP.

Public API (shapes are (B, C, H, W); see each docstring for units and domains):

* profiles: :func:`load_profile`, :func:`list_profiles`, :class:`SensorProfile`
* sensors: :class:`RGBSensor`, :class:`MonoSensor`, :class:`Sensor`
* CFA patterns: :class:`CFA`
* parameters: :class:`UnprocessParams`, :func:`sample_params`
* noise: :class:`NoiseLevels`, :func:`add_noise`
* batches for training: :func:`unprocess` (B, 3, H, W) → (noisy, clean,
  metadata) with per-sample seeds and ISOs, bit-identical to ``rawsim
  unprocess``; :func:`unprocess_spectral` for a spectral scene, as the CLI sees
  an ``.npz``; :func:`process` back to RGB; :func:`file_seed`;
  :class:`UnprocessDataset` (random crops, on the fly, deterministic per index
  and epoch)
* events: :class:`EventSensor` (count maps, torch), :class:`EventStream` (events,
  compiled), :class:`EventParams`
* Ray Data: :class:`RawPairs` (noisy/clean pairs for ``map_batches``)
* whole images: :func:`unprocess_tensor`
* stages: :mod:`rawsim.isp`

Names are imported on first use, so a command that needs no torch (``rawsim
process`` on the compiled engine) does not load it.
"""

from __future__ import annotations

from rawsim._lazy import lazy_exports
from rawsim._version import __version__

#: Public name → the module that defines it (imported on first use).
_EXPORTS = {
    "file_seed": "rawsim.api",
    "process": "rawsim.api",
    "unprocess": "rawsim.api",
    "unprocess_spectral": "rawsim.api",
    "CFA": "rawsim.cfa",
    "UnprocessDataset": "rawsim.dataset",
    "ParameterError": "rawsim.errors",
    "ProfileError": "rawsim.errors",
    "RawsimError": "rawsim.errors",
    "UnsupportedInputError": "rawsim.errors",
    "EventParams": "rawsim.events.params",
    "EventSensor": "rawsim.events.sensor",
    "EventStream": "rawsim.events.stream",
    "NoiseLevels": "rawsim.noise.models",
    "add_noise": "rawsim.noise.models",
    "UnprocessParams": "rawsim.params",
    "sample_params": "rawsim.params",
    "unprocess_tensor": "rawsim.pipelines.unprocess",
    "SensorProfile": "rawsim.cameras.profiles",
    "list_profiles": "rawsim.cameras.profiles",
    "load_profile": "rawsim.cameras.profiles",
    "RawPairs": "rawsim.ray_data",
    "MonoSensor": "rawsim.sensors",
    "RGBSensor": "rawsim.sensors",
    "Sensor": "rawsim.sensors",
}

__all__ = [
    "CFA",
    "EventParams",
    "EventSensor",
    "EventStream",
    "MonoSensor",
    "NoiseLevels",
    "ParameterError",
    "ProfileError",
    "RGBSensor",
    "RawPairs",
    "RawsimError",
    "Sensor",
    "SensorProfile",
    "UnprocessDataset",
    "UnprocessParams",
    "UnsupportedInputError",
    "__version__",
    "add_noise",
    "file_seed",
    "list_profiles",
    "load_profile",
    "process",
    "sample_params",
    "unprocess",
    "unprocess_spectral",
    "unprocess_tensor",
]


__getattr__, __dir__ = lazy_exports(globals(), _EXPORTS)
