"""Everything rawsim knows about cameras, in one package.

- :mod:`~rawsim.cameras.profiles`: the sensor profile (levels, CFA, colour matrix,
  noise), its file format, and loading one by name or path; the bundled profiles are
  ``sensor_profiles/*.json`` beside it.
- :mod:`~rawsim.cameras.database`: every camera LibRaw knows (``cameras.json``), found
  by any of its names; its functions are this package's (``cameras.find("Sony
  ILCE-7M3")``), and :mod:`~rawsim.cameras.estimate` estimates the noise of the
  cameras no calibration covers.
- :mod:`~rawsim.cameras.spectra`: the measured spectral sensitivities of 49 of them
  (``spectra.json``); what is fitted from them is :mod:`rawsim.spectral`'s.
- :mod:`~rawsim.cameras.from_raw`: a profile from one raw file.
- :mod:`~rawsim.cameras.calibrate` and :mod:`~rawsim.cameras.dark_calibration`:
  a camera's noise and dark shading measured from its frames (``rawsim calibrate``).

Importing the package loads only the database's code (no NumPy, no torch).
"""

from rawsim.cameras.database import (
    Camera,
    about,
    bundled_noise,
    cameras,
    closest,
    find,
    find_camera,
    matches,
    ref,
    search,
)

__all__ = [
    "Camera",
    "about",
    "bundled_noise",
    "cameras",
    "closest",
    "find",
    "find_camera",
    "matches",
    "ref",
    "search",
]
