"""Colour constants and camera-matrix maths (no image tensors here).

Matrices act on column vectors: ``out = M @ rgb``. For images (B, 3, H, W)
use :func:`rawsim.isp.color_matrix.apply_color_matrix`.
"""

from __future__ import annotations

import numpy as np

from rawsim.errors import ParameterError

#: Linear sRGB → CIE XYZ, D65 white (IEC 61966-2-1).
SRGB_TO_XYZ = np.array(
    [
        [0.4124564, 0.3575761, 0.1804375],
        [0.2126729, 0.7151522, 0.0721750],
        [0.0193339, 0.1191920, 0.9503041],
    ],
    dtype=np.float64,
)
#: CIE XYZ of the D65 white point (Y = 1), the row sums of :data:`SRGB_TO_XYZ`.
XYZ_D65 = SRGB_TO_XYZ.sum(axis=1)
#: DNG CalibrationIlluminant code of D65 (EXIF LightSource 21).
ILLUMINANT_D65 = 21
#: CIE XYZ of D50 as ICC.1 gives it (the profile connection space's illuminant,
#: ICC.1:2022 7.2.16; also ROMM RGB's white, ISO 22028-2).
XYZ_D50 = np.array([0.9642, 1.0, 0.8249], dtype=np.float64)
#: The Bradford cone-response matrix (Lam 1985; ICC.1 Annex E), XYZ → "sharpened" LMS.
BRADFORD = np.array(
    [
        [0.8951, 0.2664, -0.1614],
        [-0.7502, 1.7135, 0.0367],
        [0.0389, -0.0685, 1.0296],
    ],
    dtype=np.float64,
)
#: The CAT02 cone-response matrix (CIE 159:2004, CIECAM02), XYZ → LMS: the
#: adaptation rawtoaces and the ACES input transforms use.
CAT02 = np.array(
    [
        [0.7328, 0.4296, -0.1624],
        [-0.7036, 1.6975, 0.0061],
        [0.0030, 0.0136, 0.9834],
    ],
    dtype=np.float64,
)


def as_matrix(values, name: str = "matrix", shape: tuple[int, int] = (3, 3)) -> np.ndarray:
    """Convert nested lists or an array to a float64 matrix of ``shape``, checking it."""
    if not isinstance(values, np.ndarray) and hasattr(values, "tolist"):  # a torch tensor
        values = values.tolist()
    m = np.array(values, dtype=np.float64)
    if tuple(m.shape) != shape:
        raise ParameterError(f"{name} must be {shape[0]}×{shape[1]}, got {tuple(m.shape)}")
    if not np.isfinite(m).all():
        raise ParameterError(f"{name} contains NaN or infinite values")
    return m


def split_seed_matrix(values) -> tuple[np.ndarray, np.ndarray | None]:
    """The seed's ``color_matrix`` (3×3, or 4×3 whose last row is a bias) as a
    float64 (3, 3) matrix and a (3,) bias or None."""
    try:
        m = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"color matrix must be 3×3 or 4×3 numbers, got {values!r}") from None
    if m.shape == (3, 3):
        return m, None
    if m.shape == (4, 3):
        return m[:3], m[3]
    raise ParameterError(f"color matrix must be 3×3 or 4×3 (last row bias), got {m.shape}")


def camera_from_srgb(xyz_to_camera) -> np.ndarray:
    """Linear sRGB → white-balanced camera RGB, the way dcraw/LibRaw build it.

    ``rgb2cam = xyz2cam @ srgb2xyz`` with each row scaled to sum to 1, so that
    sRGB white maps to camera white (1, 1, 1) once white balance is applied.

    Args:
        xyz_to_camera: (3, 3) XYZ → camera matrix (DNG ``ColorMatrix``, LibRaw
            ``rgb_xyz_matrix``).

    Returns:
        (3, 3) float64 matrix.
    """
    m = as_matrix(xyz_to_camera, "xyz_to_camera") @ SRGB_TO_XYZ
    sums = m.sum(axis=1, keepdims=True)
    if (np.abs(sums) < 1e-8).any():
        raise ParameterError("xyz_to_camera maps white to zero in some channel")
    return m / sums


def srgb_from_camera(xyz_to_camera) -> np.ndarray:
    """White-balanced camera RGB → linear sRGB: the inverse of :func:`camera_from_srgb`."""
    return np.linalg.inv(camera_from_srgb(xyz_to_camera))


def xyz_to_camera_from_ccm(camera_to_srgb, daylight=None) -> np.ndarray:
    """XYZ → camera matrix equivalent to a camera → linear sRGB CCM (rows normalised).

    With ``daylight`` gains (R, G, B) the rows are scaled as LibRaw's are (its
    ``pre_mul`` is the reciprocal of each row's response to white), so that
    :func:`daylight_gains` of the result gives them back; without, as the CCM gives
    them (a CCM that keeps white answers D65 white alike in every row)."""
    rgb2cam = np.linalg.inv(as_matrix(camera_to_srgb, "color matrix"))
    m = rgb2cam @ np.linalg.inv(SRGB_TO_XYZ)
    if daylight is not None:
        gains = np.asarray(daylight, dtype=np.float64)[:3, None]
        m = m / (m @ XYZ_D65)[:, None] / gains
    return m / m.sum(axis=1, keepdims=True).mean()


def daylight_gains(xyz_to_camera) -> np.ndarray:
    """White-balance gains (R, G, B), G = 1, that neutralise a D65 white for this camera.

    The camera's raw response to D65 white is ``xyz2cam @ XYZ_D65``; the gains are
    its reciprocal normalised to green. Returns a (3,) float64 array.
    """
    response = as_matrix(xyz_to_camera, "xyz_to_camera") @ XYZ_D65
    if (response <= 0).any():
        raise ParameterError("xyz_to_camera gives a non-positive response to D65 white")
    return response[1] / response


def xy_to_xyz(x: float, y: float) -> np.ndarray:
    """CIE xy chromaticity → XYZ with Y = 1, a (3,) float64 array; ``y`` must be > 0."""
    if not y > 0:
        raise ParameterError(f"chromaticity y must be > 0, got {y}")
    return np.array([x / y, 1.0, (1.0 - x - y) / y], dtype=np.float64)


def rgb_to_xyz_matrix(primaries, white) -> np.ndarray:
    """Linear RGB → CIE XYZ (3, 3) of an RGB space (SMPTE RP 177): each primary's XYZ
    direction (from its xy; y may be ≤ 0 for an imaginary primary) scaled so that RGB
    (1, 1, 1) is ``white``.

    Args:
        primaries: (3, 2) xy chromaticities of red, green and blue.
        white: (3,) XYZ of the white, Y = 1 for relative colorimetry.

    Returns:
        (3, 3) float64 matrix whose columns are the primaries' XYZ; its row sums are ``white``.
    """
    xy = as_matrix(primaries, "primaries", (3, 2))
    # a primary's XYZ direction: Y = 1 where it can be, else (x, y, z) itself (an
    # imaginary primary below the xy plane's y = 0 line, ACES's AP0 blue)
    directions = np.stack(
        [xy_to_xyz(x, y) if y > 0 else np.array([x, y, 1.0 - x - y]) for x, y in xy], axis=1
    )
    if abs(np.linalg.det(directions)) < 1e-12:
        raise ParameterError("primaries are collinear: they span no RGB space")
    scale = np.linalg.solve(directions, np.asarray(white, dtype=np.float64))
    return directions * scale


def chromatic_adaptation(source_white, target_white, cone=BRADFORD) -> np.ndarray:
    """Von Kries chromatic adaptation in the cone space ``cone`` (Bradford's, ICC.1
    Annex E, unless told; :data:`CAT02` for ACES's): the (3, 3) float64 matrix taking
    XYZ seen under ``source_white`` to corresponding XYZ under ``target_white`` (both
    (3,) XYZ, Y = 1). It maps ``source_white`` onto ``target_white`` exactly (to
    rounding); for equal whites it is the identity."""
    src = cone @ np.asarray(source_white, dtype=np.float64)
    dst = cone @ np.asarray(target_white, dtype=np.float64)
    if (src <= 0).any() or (dst <= 0).any():
        raise ParameterError("whites must have positive cone responses (XYZ of a real white)")
    return np.linalg.solve(cone, np.diag(dst / src) @ cone)


def xyz_to_lab(xyz, white) -> np.ndarray:
    """CIE XYZ (…, 3) → CIE L*a*b* (…, 3) relative to ``white`` (3,) XYZ (CIE 15:2004
    (8.1)–(8.3), the linear segment below (6/29)³)."""
    t = np.asarray(xyz, dtype=np.float64) / np.asarray(white, dtype=np.float64)
    e = (6 / 29) ** 3
    f = np.where(t > e, np.cbrt(np.maximum(t, e)), t / (3 * (6 / 29) ** 2) + 4 / 29)
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return np.stack([116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz)], axis=-1)


def delta_e_2000(lab1, lab2) -> np.ndarray:
    """CIEDE2000 colour difference (…,) between L*a*b* arrays (…, 3) (CIE 142:2001,
    kL = kC = kH = 1; Sharma, Wu and Dalal's 2005 notes on the hue terms)."""
    lab1, lab2 = np.asarray(lab1, dtype=np.float64), np.asarray(lab2, dtype=np.float64)
    l1, a1, b1 = np.moveaxis(lab1, -1, 0)
    l2, a2, b2 = np.moveaxis(lab2, -1, 0)
    c_mean = (np.hypot(a1, b1) + np.hypot(a2, b2)) / 2
    g = 0.5 * (1 - np.sqrt(c_mean**7 / (c_mean**7 + 25.0**7)))
    a1p, a2p = (1 + g) * a1, (1 + g) * a2
    c1p, c2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.degrees(np.arctan2(b1, a1p)) % 360
    h2p = np.degrees(np.arctan2(b2, a2p)) % 360
    dl, dc = l2 - l1, c2p - c1p
    dh = h2p - h1p
    dh = np.where(dh > 180, dh - 360, np.where(dh < -180, dh + 360, dh))
    dh = np.where(c1p * c2p == 0, 0.0, dh)
    dhh = 2 * np.sqrt(c1p * c2p) * np.sin(np.radians(dh / 2))
    l_mean, cp_mean = (l1 + l2) / 2, (c1p + c2p) / 2
    h_sum = h1p + h2p
    h_mean = np.where(
        np.abs(h1p - h2p) <= 180,
        h_sum / 2,
        np.where(h_sum < 360, (h_sum + 360) / 2, (h_sum - 360) / 2),
    )
    h_mean = np.where(c1p * c2p == 0, h_sum, h_mean)
    t = (
        1
        - 0.17 * np.cos(np.radians(h_mean - 30))
        + 0.24 * np.cos(np.radians(2 * h_mean))
        + 0.32 * np.cos(np.radians(3 * h_mean + 6))
        - 0.20 * np.cos(np.radians(4 * h_mean - 63))
    )
    sl = 1 + 0.015 * (l_mean - 50) ** 2 / np.sqrt(20 + (l_mean - 50) ** 2)
    sc = 1 + 0.045 * cp_mean
    sh = 1 + 0.015 * cp_mean * t
    rt = (
        -2
        * np.sqrt(cp_mean**7 / (cp_mean**7 + 25.0**7))
        * np.sin(np.radians(60 * np.exp(-(((h_mean - 275) / 25) ** 2))))
    )
    return np.sqrt((dl / sl) ** 2 + (dc / sc) ** 2 + (dhh / sh) ** 2 + rt * (dc / sc) * (dhh / sh))
