"""Sensor noise: the models and the counter-based random numbers they draw.

Two forms of one design, bit-equal (``tests/test_engine.py``):

* :mod:`rawsim.noise.models`: the noise models (``NoiseLevels``, ``add_noise``)
  in torch, the differentiable reference;
* :mod:`rawsim.noise.reference`: the torch form of the counter-based draws
  (Philox 4×32-10 keyed by the file seed: normals, Tukey-lambda, exact Poisson);
* :mod:`rawsim.noise.kernels`: the compiled (numba) form of the same draws, inlined
  into the engine's kernels.

Shared by both, torch-free: :mod:`~rawsim.noise.philox` (constants and keys),
:mod:`~rawsim.noise.seeds` (per-file seeds), :mod:`~rawsim.noise.exact_math`
(functions with the same bits everywhere) and :mod:`~rawsim.noise.poisson_table`
(the exact Poisson alias tables).
"""
