"""Raw denoising driven by the sensor's noise model.

* :mod:`rawsim.denoise.noise_model`: the noise model of any raw (a profile, the
  camera's bundled profile, the DNG NoiseProfile tag, or an estimate from the raw).
* :mod:`rawsim.denoise.profiled`: the classical method (variance stabilisation, two
  passes of DCT shrinkage), the torch reference of :mod:`rawsim.engine.denoise`.
"""
