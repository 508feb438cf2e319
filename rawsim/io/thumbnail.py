"""The preview a camera embeds in its raw file (``rawsim process --thumbnail``).

LibRaw finds it (``extract_thumb``): most cameras store a JPEG, written out here
as it is, byte for byte, with the raw's metadata put into its EXIF; some old
ones a small bitmap, encoded as a JPEG. The preview is not rotated (LibRaw
leaves it as stored), so its Orientation tag carries the raw's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rawsim.errors import UnsupportedInputError
from rawsim.io.clibs import collected_stderr, openable_name
from rawsim.io.raw import _FLIP_TO_ORIENTATION


@dataclass(frozen=True)
class Thumbnail:
    """An embedded preview: ``jpeg`` bytes, or ``bitmap`` (H, W, 3) uint8 samples; and
    the raw's EXIF orientation (1–8), which applies to it."""

    jpeg: bytes | None
    bitmap: np.ndarray | None
    orientation: int


def read_thumbnail(path: str | Path) -> Thumbnail:
    """The raw's embedded preview. Raises :class:`UnsupportedInputError` when it has none."""
    import rawpy

    path = Path(path)
    said: list[str] = []
    try:
        with collected_stderr(said), openable_name(path) as name, rawpy.imread(name) as raw:
            orientation = _FLIP_TO_ORIENTATION.get(int(raw.sizes.flip), 1)
            thumb = raw.extract_thumb()
    except rawpy.LibRawNoThumbnailError:
        raise UnsupportedInputError(
            f"{path}: the raw holds no embedded preview; render it without --thumbnail "
            "(--half-size is the fast preview)"
        ) from None
    except (rawpy.LibRawError, OSError) as err:
        reason = " ".join(str(err).strip("b'\"").split())
        raise UnsupportedInputError(f"{path}: cannot read its preview (LibRaw: {reason})") from None
    if thumb.format == rawpy.ThumbFormat.JPEG:
        return Thumbnail(bytes(thumb.data), None, orientation)
    bitmap = np.ascontiguousarray(thumb.data)
    if bitmap.ndim == 2:
        bitmap = np.repeat(bitmap[:, :, None], 3, axis=2)
    return Thumbnail(None, bitmap.astype(np.uint8), orientation)
