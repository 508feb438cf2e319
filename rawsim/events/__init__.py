"""Event cameras (DVS) simulated from frames.

* :mod:`rawsim.events.params`: :class:`EventParams`, shared by both models;
* :mod:`rawsim.events.sensor`: :class:`EventSensor`, count maps per frame step in
  torch (differentiable where the maths allows), and the torch reference of a
  stream step;
* :mod:`rawsim.events.stream`: :class:`EventStream`, (x, y, t, polarity) events,
  torch-free, on the compiled kernels (:mod:`rawsim.events.kernels`);
* :mod:`rawsim.events.files`: writing events as npz, HDF5 or text.

The classes are importable from here: ``from rawsim.events import EventStream``.
"""

from __future__ import annotations

from rawsim._lazy import lazy_exports

_EXPORTS = {
    "EventParams": "rawsim.events.params",
    "EventSensor": "rawsim.events.sensor",
    "EventStream": "rawsim.events.stream",
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(globals(), _EXPORTS)
