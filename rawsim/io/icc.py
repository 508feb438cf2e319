"""ICC profiles of rawsim's output encodings, built from the primaries, white and transfer.

:func:`icc_profile` writes an ICC.1 version 4.3 display profile of the matrix/TRC
form every colour-managed reader understands (LittleCMS, ColorSync, Windows
WCS, skcms in browsers):

- header: class ``mntr``, data colour space ``RGB `` (``GRAY`` for grey
  outputs), PCS ``XYZ ``, the D50 PCS illuminant, perceptual intent, a fixed
  creation date (:data:`PROFILE_DATE`) and the MD5 profile ID, so the same
  encoding always gives the same bytes;
- ``desc`` and ``cprt`` (``mluc``, English);
- ``wtpt``: D50, as ICC.1 asks of v4 display profiles, and ``chad``: the Bradford
  adaptation from the space's white to D50 (``sf32``; the identity for ProPhoto);
- ``rXYZ``/``gXYZ``/``bXYZ``: the primaries' XYZ adapted to D50 (the columns of
  ``chad · RGB→XYZ``), whose sum is D50;
- ``rTRC``/``gTRC``/``bTRC`` (one shared ``para`` curve) or ``kTRC`` for grey: the
  decoding, ICC parametric curve type 3 for the toe curves (sRGB, BT.2020, ROMM),
  type 0 (a pure power) for ``gamma:G`` and ``linear`` (g = 1).

CIE XYZ output (D65-relative, Y = 1 at white) is described by the same form:
its "primaries" are the X, Y and Z axes, so the colorants are the columns of
the D65 → D50 adaptation; XYZ values above 1 (Z of white is 1.089) are clipped
by integer outputs, as they always were. Camera RGB has no profile: see
:class:`rawsim.colorspaces.Encoding`.

Numbers are ICC's s15Fixed16 (1/65536 steps); the curves' parameters therefore
round at about 1e-5, well below a 16-bit code.
"""

from __future__ import annotations

import functools
import hashlib
import struct

import numpy as np

from rawsim.color import XYZ_D50, XYZ_D65, chromatic_adaptation
from rawsim.colorspaces import Encoding

#: ICC.1:2022 (profile version 4.3.0.0).
ICC_VERSION = 0x04300000
#: The creation date every profile carries (year, month, day, hour, minute, second,
#: UTC): fixed, so that profiles and the files holding them are byte-reproducible.
PROFILE_DATE = (2025, 1, 1, 0, 0, 0)
COPYRIGHT = "No copyright, use freely (CC0 1.0). Made by rawsim from the published primaries."
_HEADER_SIZE = 128


def _s15f16(value: float) -> bytes:
    """A number as ICC's s15Fixed16Number (big-endian, 1/65536 steps)."""
    fixed = round(float(value) * 65536)
    if not -(2**31) <= fixed < 2**31:
        raise ValueError(f"{value} is outside ICC's s15Fixed16 range")
    return struct.pack(">i", fixed)


def _xyz_tag(xyz) -> bytes:
    """``XYZ `` type: one XYZNumber."""
    return b"XYZ \0\0\0\0" + b"".join(_s15f16(v) for v in xyz)


def _sf32_tag(matrix: np.ndarray) -> bytes:
    """``sf32`` type: the 3 × 3 matrix, row by row."""
    return b"sf32\0\0\0\0" + b"".join(_s15f16(v) for v in np.asarray(matrix).ravel())


def _mluc_tag(text: str) -> bytes:
    """``mluc`` type: one record, en-US, UTF-16BE."""
    body = text.encode("utf-16-be")
    return b"mluc\0\0\0\0" + struct.pack(">II2s2sII", 1, 12, b"en", b"US", len(body), 28) + body


def _para_tag(encoding: Encoding) -> bytes:
    """``para`` type: the decoding (encoded value → linear light) of the transfer."""
    transfer = encoding.transfer
    if transfer.curve is not None:
        kind, params = 3, transfer.curve.icc_parameters()
    elif transfer.kind == "gamma":
        kind, params = 0, (transfer.gamma,)
    elif transfer.kind == "linear":
        kind, params = 0, (1.0,)
    else:  # TransferSpec.parse admits nothing else
        raise ValueError(f"no ICC curve for transfer {transfer}")
    return b"para\0\0\0\0" + struct.pack(">HH", kind, 0) + b"".join(map(_s15f16, params))


def colorants(encoding: Encoding) -> tuple[np.ndarray, np.ndarray]:
    """(chad, colorants) of ``encoding``: the (3, 3) Bradford adaptation from its white to
    D50, and the (3, 3) D50-adapted linear RGB → PCS XYZ matrix (columns: red, green,
    blue colorants). For ``xyz`` the "RGB" is X, Y, Z themselves (D65)."""
    rgb = encoding.rgb_space
    if rgb is None:  # CIE XYZ, D65-relative: identity to XYZ, then adapted
        to_xyz, white = np.eye(3), XYZ_D65
    else:
        to_xyz, white = rgb.to_xyz, np.asarray(rgb.white)
    chad = chromatic_adaptation(white, XYZ_D50)
    return chad, chad @ to_xyz


def _balanced(matrix: np.ndarray) -> np.ndarray:
    """The colorants rounded to s15Fixed16 steps so that each row still sums to D50's
    (as written): RGB (1, 1, 1) is then exactly the PCS white, and greys stay neutral
    through the profile. The rounding error goes to each row's largest entry."""
    steps = np.round(matrix * 65536)
    target = np.round(XYZ_D50 * 65536)
    for row in range(3):
        steps[row, np.argmax(np.abs(matrix[row]))] += target[row] - steps[row].sum()
    return steps / 65536


@functools.lru_cache(maxsize=32)
def icc_profile(encoding: Encoding, grey: bool = False) -> bytes:
    """The ICC v4.3 display profile of ``encoding`` (see the module doc): ``RGB`` with
    matrix and curves, or with ``grey`` a ``GRAY`` profile of the transfer alone.
    Deterministic: the same encoding gives the same bytes."""
    chad, matrix = colorants(encoding)
    trc = _para_tag(encoding)
    tags: list[tuple[bytes, bytes]] = [
        (b"desc", _mluc_tag(encoding.describe() + (" (grey)" if grey else ""))),
        (b"cprt", _mluc_tag(COPYRIGHT)),
        (b"wtpt", _xyz_tag(XYZ_D50)),
        (b"chad", _sf32_tag(chad)),
    ]
    if grey:
        tags.append((b"kTRC", trc))
    else:
        fixed = _balanced(matrix) if encoding.rgb_space else matrix
        tags += [(sig, _xyz_tag(fixed[:, i])) for i, sig in enumerate((b"rXYZ", b"gXYZ", b"bXYZ"))]
        tags += [(b"rTRC", trc), (b"gTRC", trc), (b"bTRC", trc)]  # one element, shared
    table = bytearray(struct.pack(">I", len(tags)))
    data = bytearray()
    at = _HEADER_SIZE + 4 + 12 * len(tags)
    placed: dict[bytes, int] = {}
    for sig, element in tags:
        if element not in placed:
            placed[element] = at + len(data)
            data += element + b"\0" * (-len(element) % 4)
        table += sig + struct.pack(">II", placed[element], len(element))
    size = _HEADER_SIZE + len(table) + len(data)
    header = bytearray(_HEADER_SIZE)
    struct.pack_into(
        ">I4sI4s4s4s",
        header,
        0,
        size,
        b"\0" * 4,
        ICC_VERSION,
        b"mntr",
        b"GRAY" if grey else b"RGB ",
        b"XYZ ",
    )
    struct.pack_into(">6H", header, 24, *PROFILE_DATE)
    header[36:40] = b"acsp"
    header[68:80] = b"".join(_s15f16(v) for v in XYZ_D50)  # the PCS illuminant
    profile = bytearray(header + table + data)
    profile[84:100] = hashlib.md5(profile).digest()  # ICC.1 7.2.18, over the zeroed fields
    return bytes(profile)
