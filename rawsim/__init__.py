"""rawsim: raw image unprocessing and processing on a differentiable torch ISP.

Public API (shapes are (B, C, H, W); see each docstring for units and domains):

* profiles: :func:`load_profile`, :func:`list_profiles`, :class:`SensorProfile`
* sensors: :class:`RGBSensor`, :class:`MonoSensor`, :class:`Sensor`
* CFA patterns: :class:`CFA`
* parameters: :class:`UnprocessParams`, :func:`sample_params`
* noise: :class:`NoiseLevels`, :func:`add_noise`
* batches for training: :func:`unprocess` (B, 3, H, W) → (noisy, clean,
  metadata) with per-sample seeds and ISOs, bit-identical to ``rawsim
  unprocess``; :func:`process` back to RGB; :func:`file_seed`;
  :class:`UnprocessDataset` (random crops, on the fly, deterministic per index
  and epoch)
* events: :class:`EventSensor`
* whole images: :func:`unprocess_tensor`
* stages: :mod:`rawsim.isp`
"""

from rawsim._version import __version__
from rawsim.api import file_seed, process, unprocess
from rawsim.cfa import CFA
from rawsim.dataset import UnprocessDataset
from rawsim.errors import ParameterError, ProfileError, RawsimError, UnsupportedInputError
from rawsim.events import EventSensor
from rawsim.noise import NoiseLevels, add_noise
from rawsim.params import UnprocessParams, sample_params
from rawsim.pipelines.unprocess import unprocess_tensor
from rawsim.profiles import SensorProfile, list_profiles, load_profile
from rawsim.sensors import MonoSensor, RGBSensor, Sensor

__all__ = [
    "CFA",
    "EventSensor",
    "MonoSensor",
    "NoiseLevels",
    "ParameterError",
    "ProfileError",
    "RGBSensor",
    "RawsimError",
    "Sensor",
    "SensorProfile",
    "UnprocessParams",
    "UnprocessDataset",
    "UnsupportedInputError",
    "__version__",
    "add_noise",
    "file_seed",
    "list_profiles",
    "load_profile",
    "process",
    "sample_params",
    "unprocess",
    "unprocess_tensor",
]
