"""A DNG's own colour tags, and the XYZ → camera matrix LibRaw renders the file with.

LibRaw reports a DNG's colour only as its camera → sRGB ``color_matrix`` where its own
table lacks the camera (``rgb_xyz_matrix`` is then zero). :class:`DngColour` reads the
tags themselves (ColorMatrix1/2, CalibrationIlluminant1/2, CameraCalibration1/2,
AnalogBalance; IFD0, where LibRaw takes them), picks the matrix as LibRaw does and
composes it as the DNG specification does; :func:`libraw_matrix` keeps it only where it
reproduces LibRaw's camera → sRGB matrix, so that :mod:`rawsim.io.raw` can hand it on
without changing how a file renders.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rawsim.color import srgb_from_camera
from rawsim.errors import ParameterError

#: DNG CalibrationIlluminant codes (EXIF LightSource), for messages.
_ILLUMINANTS = {
    0: "unknown illuminant",
    1: "daylight",
    4: "flash",
    17: "standard light A",
    18: "standard light B",
    19: "standard light C",
    20: "D55",
    21: "D65",
    22: "D75",
    23: "D50",
}
#: The correlated colour temperature (K) the DNG SDK gives each CalibrationIlluminant
#: code (dng_camera_profile.cpp, IlluminantToTemperature), for interpolating two
#: matrices; codes without one (0, other) are not interpolated.
_TEMPERATURES = {
    1: 5500, 2: 4150, 3: 2850, 4: 5500, 9: 5500, 10: 6500, 11: 7500, 12: 6430, 13: 5000,
    14: 4150, 15: 3450, 17: 2850, 18: 5500, 19: 6500, 20: 5500, 21: 6500, 22: 7500,
    23: 5000, 24: 3200,
}  # fmt: skip
#: Illuminants LibRaw takes for a DNG's colour when neither matrix is for D65 (its
#: identify.cpp, "Other daylight-type ill"): daylight, flash, D55, D75, D50.
_DAYLIGHT_LIKE = (1, 4, 20, 22, 23)


@dataclass(frozen=True)
class DngColour:
    """A DNG's colour tags (IFD0): ``matrices`` maps 1 and 2 (ColorMatrix1/2, XYZ →
    camera under CalibrationIlluminant1/2) to (illuminant code, (3, 3) matrix);
    ``calibration`` likewise CameraCalibration1/2; ``analog_balance`` the AnalogBalance
    gains, or None."""

    matrices: dict[int, tuple[int, np.ndarray]]
    calibration: dict[int, np.ndarray]
    analog_balance: np.ndarray | None

    def chosen(self) -> tuple[np.ndarray, str] | None:
        """The XYZ → camera matrix LibRaw renders the file with, and what it is; None
        without a 3×3 ColorMatrix.

        LibRaw's rule (src/metadata/identify.cpp and tiff.cpp): of two matrices with
        their illuminants, the D65 one, else a daylight-like one (:data:`_DAYLIGHT_LIKE`),
        else the last tag read (ColorMatrix2); one matrix is taken whatever its
        illuminant. As the DNG specification composes it, the matrix is
        AnalogBalance · CameraCalibration · ColorMatrix.
        """
        if not self.matrices:
            return None
        order = sorted(self.matrices)
        pick = order[-1]
        if len(order) == 2 and all(self.matrices[i][0] > 0 for i in order):
            for wanted in ((21,), _DAYLIGHT_LIKE):
                hit = [i for i in order if self.matrices[i][0] in wanted]
                if hit:
                    pick = hit[0]
                    break
        code = self.matrices[pick][0]
        name = _ILLUMINANTS.get(code, f"illuminant {code}")
        what = [f"ColorMatrix{pick} ({name})"]
        if pick in self.calibration and not np.allclose(self.calibration[pick], np.eye(3)):
            what.insert(0, f"CameraCalibration{pick}")
        if self.analog_balance is not None and not np.allclose(self.analog_balance, 1):
            what.insert(0, "AnalogBalance")
        return self.composed(pick), " · ".join(what)

    def composed(self, i: int) -> np.ndarray:
        """AnalogBalance · CameraCalibration``i`` · ColorMatrix``i``, (3, 3)."""
        m = self.matrices[i][1]
        if i in self.calibration:
            m = self.calibration[i] @ m
        return m if self.analog_balance is None else np.diag(self.analog_balance) @ m

    def interpolated(self, gains) -> tuple[np.ndarray, dict] | None:
        """The XYZ → camera matrix for a shot white-balanced by ``gains`` (R, G, B), as
        the DNG specification (1.6, chapter 6) finds it from two matrices: the white's
        xy and the matrix are solved together, starting from D50 — the matrix is the two
        composed matrices (:meth:`composed`) weighted linearly in inverse temperature
        between their illuminants' (clamped to the nearer outside them), the white is
        that matrix's inverse applied to the camera neutral (1 / gains). Temperatures
        are McCamy's (1992) from xy. Returns (matrix, {"cct", "weights"}); None
        without two matrices whose illuminants have temperatures (:data:`_TEMPERATURES`)
        that differ."""
        temps = {i: _TEMPERATURES.get(self.matrices[i][0]) for i in self.matrices}
        if len(temps) != 2 or None in temps.values() or len(set(temps.values())) != 2:
            return None
        (lo, t_lo), (hi, t_hi) = sorted(temps.items(), key=lambda kv: kv[1])
        neutral = 1.0 / np.asarray(gains, dtype=np.float64)
        cct, w = 5003.0, 0.5
        for _ in range(30):
            w = float(np.clip((1 / cct - 1 / t_hi) / (1 / t_lo - 1 / t_hi), 0.0, 1.0))
            matrix = w * self.composed(lo) + (1 - w) * self.composed(hi)
            xyz = np.linalg.solve(matrix, neutral)
            if not (xyz > 0).all():
                return None
            x, y = xyz[:2] / xyz.sum()
            n = (x - 0.3320) / (0.1858 - y)
            new = float(np.clip(449 * n**3 + 3525 * n**2 + 6823.3 * n + 5520.33, 1000, 50000))
            if abs(new - cct) < 0.5:
                break
            cct = new
        weights = {f"ColorMatrix{lo}": round(w, 6), f"ColorMatrix{hi}": round(1 - w, 6)}
        return matrix, {"cct": round(new), "weights": weights}


def read_dng_colour(tags) -> DngColour | None:
    """The colour tags of a DNG's IFD0 (tifffile tags), None where it has no 3×3
    ColorMatrix (a 4-colour one is LibRaw's to render)."""

    def matrix(code: int) -> np.ndarray | None:
        if code not in tags:
            return None
        v = np.asarray(tags[code].value, dtype=np.float64).ravel()
        if v.size == 18:  # (S)RATIONAL pairs
            v = v[0::2] / np.where(v[1::2] == 0, 1, v[1::2])
        return v.reshape(3, 3) if v.size == 9 and np.isfinite(v).all() else None

    matrices, calibration = {}, {}
    for i, (cm, ill, cc) in enumerate(((50721, 50778, 50723), (50722, 50779, 50724)), 1):
        m = matrix(cm)
        if m is not None and np.abs(m).sum() > 0:
            code = int(np.ravel(tags[ill].value)[0]) if ill in tags else 0
            matrices[i] = (code, m)
        c = matrix(cc)
        if c is not None:
            calibration[i] = c
    if not matrices:
        return None
    balance = None
    if 50727 in tags:
        v = np.asarray(tags[50727].value, dtype=np.float64).ravel()
        v = v[0::2] / np.where(v[1::2] == 0, 1, v[1::2]) if v.size == 6 else v
        balance = v if v.size == 3 and (v > 0).all() else None
    return DngColour(matrices, calibration, balance)


def libraw_matrix(colour: DngColour | None, libraw_to_srgb: np.ndarray):
    """(XYZ → camera matrix, its source) of a DNG whose colour LibRaw gives only as its
    camera → sRGB ``color_matrix``: the file's chosen matrix (:meth:`DngColour.chosen`)
    where it reproduces LibRaw's (so that rendering with it changes nothing); None
    otherwise."""
    picked = None if colour is None else colour.chosen()
    if picked is None:
        return None
    matrix, what = picked
    try:
        same = np.allclose(srgb_from_camera(matrix), libraw_to_srgb, rtol=0, atol=1e-4)
    except (ParameterError, np.linalg.LinAlgError):
        return None
    return (matrix, f"the file's {what} (DNG tags; LibRaw renders it with it)") if same else None
