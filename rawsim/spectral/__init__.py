"""Spectral colour: the CIE's observer and illuminants, rawtoaces' training reflectances
(:mod:`~rawsim.spectral.tables`), and what is fitted from a camera's measured spectral
sensitivities (:mod:`~rawsim.spectral.fit`: DNG colour matrices for any light, the ACES
input transform as rawtoaces makes it).

Every spectrum here is sampled on one grid, 380–780 nm in 5 nm steps (81 samples:
:data:`~rawsim.spectral.tables.WAVELENGTHS`), the grid of rawtoaces-data; a camera's
curves are in :mod:`rawsim.cameras.spectra`. NumPy only.
"""
