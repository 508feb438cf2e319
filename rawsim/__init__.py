"""rawsim: raw image unprocessing and processing on a differentiable torch ISP.

Public API (shapes are (B, C, H, W); see each docstring for units and domains):

* profiles: :func:`load_profile`, :func:`list_profiles`, :class:`SensorProfile`
* sensors: :class:`RGBSensor`, :class:`MonoSensor`, :class:`Sensor`
* CFA patterns: :class:`CFA`
* parameters: :class:`UnprocessParams`, :func:`sample_params`
* noise: :class:`NoiseLevels`, :func:`add_noise`
* whole images: :func:`unprocess_tensor`
* stages: :mod:`rawsim.isp`
"""

from rawsim._version import __version__
from rawsim.cfa import CFA
from rawsim.errors import ParameterError, ProfileError, RawsimError, UnsupportedInputError
from rawsim.noise import NoiseLevels, add_noise
from rawsim.params import UnprocessParams, sample_params
from rawsim.pipelines.unprocess import unprocess_tensor
from rawsim.profiles import SensorProfile, list_profiles, load_profile
from rawsim.sensors import MonoSensor, RGBSensor, Sensor

__all__ = [
    "CFA",
    "MonoSensor",
    "NoiseLevels",
    "ParameterError",
    "ProfileError",
    "RGBSensor",
    "RawsimError",
    "Sensor",
    "SensorProfile",
    "UnprocessParams",
    "UnsupportedInputError",
    "__version__",
    "add_noise",
    "list_profiles",
    "load_profile",
    "sample_params",
    "unprocess_tensor",
]
