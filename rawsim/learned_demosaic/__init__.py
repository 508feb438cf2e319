"""The ``learned`` demosaic: ``wcd`` and a learned linear correction (Bayer).

:mod:`~rawsim.learned_demosaic.correction` holds the correction (the torch
reference; the engine's twin is ``rawsim.engine.process._correct``),
:mod:`~rawsim.learned_demosaic.filters` the filters as arrays (their form, and the
weights the engine takes), ``weights/`` the shipped filters (``bayer.safetensors``)
and ``training/`` the script that fits them and the list of the photos it fitted
them on (none from the Kodak set, which the benchmarks check them on).
"""
