"""Reading spectral scenes: hyperspectral images for ``rawsim unprocess``.

Two containers are read:

- a NumPy ``.npz`` holding ``spectra`` (H, W, N), float, and ``wavelengths`` (N,) in
  nm, increasing; optionally ``kind`` (``"reflectance"``, the default, or
  ``"radiance"``) and ``illuminant``: an (N,) spectrum on the same wavelengths, in the
  units of a radiance scene, or a name (``"D65"``, :data:`~rawsim.spectral.tables.ILLUMINANTS`);
- an OpenEXR whose every channel is named by its wavelength in nm: ``550``, ``550nm``,
  ``w550``, ``550.5nm`` (case-insensitive; any order), or the layout of Fichet et al.,
  "An OpenEXR Layout for Spectral Images" (JCGT 2021): ``S0.550nm`` or
  ``S0.550,000000nm`` (emissive: radiance), ``T.550nm`` (reflective: reflectance).
  Plain names are a reflectance unless the header's string attribute
  ``spectralKind`` says ``radiance``; a string attribute ``illuminant`` names the
  light (a name of :data:`~rawsim.spectral.tables.ILLUMINANTS`).

Values must be finite and ≥ 0 and the wavelengths must cover 400–700 nm (where a
camera sees); each refusal is one line naming the file, the reason and the fix
(:class:`~rawsim.errors.UnsupportedInputError`). An odd height or width is cropped to
even, as images are.

An uncompressed npz (``np.savez``) is the quickest to read: its ``spectra`` are mapped
from the file, not copied into memory; a compressed one (``np.savez_compressed``) is
decompressed whole first.
"""

from __future__ import annotations

import re
import struct
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rawsim.errors import UnsupportedInputError
from rawsim.io.clibs import collected_stderr, openable_name

#: Extensions picked up as spectral scenes when scanning folders (an EXR is one by
#: its channels, :func:`is_spectral`).
SPECTRAL_EXTENSIONS = (".npz",)
#: Scene kinds: what the values of ``spectra`` are.
KINDS = ("reflectance", "radiance")
#: An EXR channel named by a wavelength: an optional Fichet layer (S0., T.) or ``w``,
#: the number (decimal point or comma), an optional ``nm``.
_CHANNEL = re.compile(r"^(?:(S0|T)\.)?w?(\d+(?:[.,]\d+)?)(?:nm)?$", re.IGNORECASE)
_NPZ_FIX = (
    "give an npz with 'spectra' (H, W, N) and 'wavelengths' (N, nm), as "
    "tools/spectra/make_test_scene.py writes"
)


@dataclass(frozen=True)
class SpectralScene:
    """A spectral image as read.

    Attributes:
        spectra: (H, W, N) float32, H and W even, finite and ≥ 0: reflectance (0–1)
            or radiance (any unit; see :mod:`rawsim.spectral.render`). Read-only, any
            strides: an uncompressed npz's is mapped from the file, as it lies
            (cropped to even in place).
        wavelengths: (N,) float64 nm, increasing, spanning 400–700.
        kind: ``"reflectance"`` or ``"radiance"``.
        illuminant: the light the scene carries: an (N,) spectrum on ``wavelengths``,
            a name, or None.
        format_name: ``"NumPy npz"`` or ``"OpenEXR"``.
        source_size: (width, height) before the crop to even.
        dropped_channels: the file's arrays or channels not read.
    """

    spectra: np.ndarray
    wavelengths: np.ndarray
    kind: str
    illuminant: np.ndarray | str | None
    format_name: str
    source_size: tuple[int, int]
    dropped_channels: tuple[str, ...] = ()


def wavelength_of(channel: str) -> tuple[float, str | None] | None:
    """(nm, Fichet layer ``"S0"``/``"T"`` or None) of an EXR channel name, or None
    where the name is no wavelength."""
    m = _CHANNEL.match(channel.strip())
    if m is None:
        return None
    return float(m.group(2).replace(",", ".")), None if m.group(1) is None else m.group(1).upper()


def is_spectral(path: str | Path) -> bool:
    """Whether ``path`` is a spectral scene by its name and header: an ``.npz``, or an
    EXR whose every channel is a wavelength (:func:`wavelength_of`); an EXR that
    cannot be opened is left to the image reader to refuse."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return True
    if suffix != ".exr" or not path.is_file():
        return False
    import OpenImageIO as oiio

    with collected_stderr([]), openable_name(path) as name:
        inp = oiio.ImageInput.open(name)
        if inp is None:
            oiio.geterror()
            return False
        names = tuple(inp.spec().channelnames)
        inp.close()
    return len(names) >= 2 and all(wavelength_of(n) is not None for n in names)


def read_spectral(path: str | Path) -> SpectralScene:
    """Read a spectral scene (see the module's notes); raises
    :class:`~rawsim.errors.UnsupportedInputError` naming the file, the reason and the fix."""
    path = Path(path)
    if not path.is_file():
        raise UnsupportedInputError(f"{path}: not a file")
    if path.suffix.lower() == ".npz":
        scene = _read_npz(path)
    else:
        scene = _read_exr(path)
    return checked(path, scene)


def _read_npz(path: Path) -> SpectralScene:
    if not zipfile.is_zipfile(path):  # np.load would take it for a pickle
        raise UnsupportedInputError(f"{path}: not an npz (no zip archive): {_NPZ_FIX}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            mapped = _mapped(path, npz.zip, "spectra.npy")
            arrays = {k: npz[k] for k in npz.files if not (k == "spectra" and mapped is not None)}
        if mapped is not None:
            arrays["spectra"] = mapped
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise UnsupportedInputError(f"{path}: not a readable npz ({err}): {_NPZ_FIX}") from None
    missing = [k for k in ("spectra", "wavelengths") if k not in arrays]
    if missing:
        what = "a rawsim unprocess output" if "mosaic" in arrays else "no spectral scene"
        raise UnsupportedInputError(
            f"{path}: {what}, it holds no {' or '.join(repr(k) for k in missing)}: {_NPZ_FIX}"
        )
    spectra, nm = arrays["spectra"], arrays["wavelengths"]
    if spectra.ndim != 3 or nm.ndim != 1 or spectra.shape[2] != nm.size:
        raise UnsupportedInputError(
            f"{path}: 'spectra' {spectra.shape} and 'wavelengths' {nm.shape} do not match: "
            "give spectra (H, W, N) and N wavelengths"
        )
    if spectra.dtype.kind not in "fiu" or nm.dtype.kind not in "fiu":
        raise UnsupportedInputError(f"{path}: 'spectra' and 'wavelengths' must be numbers")
    kind = str(arrays["kind"]) if "kind" in arrays else "reflectance"
    light = arrays.get("illuminant")
    if light is not None:
        if light.dtype.kind in "US":
            light = str(light)
        elif light.shape != nm.shape or light.dtype.kind not in "fiu":
            raise UnsupportedInputError(
                f"{path}: 'illuminant' must be a name or one value per wavelength "
                f"({nm.size}), got shape {light.shape}"
            )
        else:
            light = light.astype(np.float64)
    known = {"spectra", "wavelengths", "kind", "illuminant"}
    h, w = spectra.shape[:2]
    return SpectralScene(
        spectra=spectra,
        wavelengths=nm.astype(np.float64),
        kind=kind,
        illuminant=light,
        format_name="NumPy npz",
        source_size=(w, h),
        dropped_channels=tuple(sorted(set(arrays) - known)),
    )


def _mapped(path: Path, archive: zipfile.ZipFile, member: str) -> np.ndarray | None:
    """The array ``member`` of the npz ``archive`` (at ``path``) mapped read-only from
    the file where it lies, or None where it is compressed, encrypted or absent, or is
    not a plain array (np.load then reads it). An uncompressed member (``np.savez``)
    is the ``.npy`` bytes as they are: mapped, the scene is read where the kernel
    needs it, with no copy in memory (np.load's read is one, plus the zip's CRC).
    Raises ValueError where the member's header or size do not fit the file."""
    from numpy.lib import format as npy

    try:
        info = archive.getinfo(member)
    except KeyError:
        return None
    if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1:
        return None
    with open(path, "rb") as fh:
        fh.seek(info.header_offset)  # the local header: its own name and extra lengths
        local = fh.read(30)
        if len(local) < 30 or local[:4] != b"PK\x03\x04":
            raise ValueError(f"{member}: no local file header")
        name_size, extra_size = struct.unpack("<HH", local[26:30])
        start = info.header_offset + 30 + name_size + extra_size
        fh.seek(start)
        version = npy.read_magic(fh)
        if version not in ((1, 0), (2, 0)):
            return None
        read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
        shape, fortran, dtype = read_header(fh)
        offset = fh.tell()
    if dtype.hasobject or not shape:
        return None
    if offset - start + int(np.prod(shape)) * dtype.itemsize > info.file_size:
        raise ValueError(f"{member}: truncated")
    return np.memmap(path, dtype, "r", offset, shape, "F" if fortran else "C")


#: Rows of an EXR decoded at a time (:func:`_read_bands`): whole compressed blocks
#: (ZIP's 16 rows, PIZ's and B44's 32), which OpenEXR decodes on its threads.
EXR_STRIP_ROWS = 32


def _read_bands(inp, spec) -> np.ndarray | None:
    """The open EXR's every channel as (H, W, N) float32, or None if a read failed;
    by strips of :data:`EXR_STRIP_ROWS` rows into one array (``read_image`` decodes
    into its own buffer first, then copies: twice the scene's memory), a tiled file
    in one read."""
    import OpenImageIO as oiio

    if spec.tile_width:
        return inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    pixels = np.empty((spec.height, spec.width, spec.nchannels), np.float32)
    top, bottom = spec.y, spec.y + spec.height
    for y in range(top, bottom, EXR_STRIP_ROWS):
        end = min(y + EXR_STRIP_ROWS, bottom)
        strip = inp.read_scanlines(0, 0, y, end, 0, 0, spec.nchannels, oiio.FLOAT)
        if strip is None:
            return None
        pixels[y - top : end - top] = strip.reshape(end - y, spec.width, spec.nchannels)
    return pixels


def _read_exr(path: Path) -> SpectralScene:
    import OpenImageIO as oiio

    said: list[str] = []
    with collected_stderr(said), openable_name(path) as name:
        inp = oiio.ImageInput.open(name)
        if inp is None:
            reason = oiio.geterror().strip() or "; ".join(said) or "?"
            raise UnsupportedInputError(f"{path}: not a readable EXR ({reason})")
        try:
            spec = inp.spec()
            pixels = _read_bands(inp, spec)
            error = inp.geterror().strip()
        finally:
            inp.close()
    if pixels is None or error:
        raise UnsupportedInputError(f"{path}: cannot decode pixels ({error or 'truncated?'})")
    parsed = [wavelength_of(n) for n in spec.channelnames]
    layers = {layer for _, layer in parsed}
    if len(layers) > 1:
        raise UnsupportedInputError(
            f"{path}: mixes channel layers {sorted(map(str, layers))}: keep one of emissive "
            "(S0.) or reflective (T.) channels"
        )
    layer = layers.pop()
    said_kind = str(spec.getattribute("spectralKind") or "").strip().lower()
    kind = {"S0": "radiance", "T": "reflectance"}.get(layer) or said_kind or "reflectance"
    nm = np.array([p[0] for p in parsed])
    order = np.argsort(nm)
    pixels = np.asarray(pixels).reshape(spec.height, spec.width, spec.nchannels)
    if (np.diff(order) != 1).any():  # bands out of order in the file: a copy, sorted
        pixels = pixels[:, :, order]
    light = str(spec.getattribute("illuminant") or "").strip() or None
    return SpectralScene(
        spectra=pixels,
        wavelengths=nm[order],
        kind=kind,
        illuminant=light,
        format_name="OpenEXR",
        source_size=(spec.width, spec.height),
    )


def checked(path: Path | str, scene: SpectralScene) -> SpectralScene:
    """The scene's values checked (its kind, wavelengths and size; no NaN, infinite or
    negative value, in the spectra or the light), float32 and cropped to an even size;
    errors name ``path`` (a file, or what the Python API was given)."""
    if scene.kind not in KINDS:
        raise UnsupportedInputError(
            f"{path}: unknown kind {scene.kind!r}: give one of {', '.join(KINDS)}"
        )
    nm = scene.wavelengths
    if nm.size < 2 or not (np.diff(nm) > 0).all():
        raise UnsupportedInputError(
            f"{path}: its wavelengths must increase, without repeats: give them sorted, in nm"
        )
    if nm[0] > 400 or nm[-1] < 700:
        raise UnsupportedInputError(
            f"{path}: its wavelengths ({nm[0]:g}–{nm[-1]:g} nm) do not cover 400–700 nm, "
            "where cameras see: give bands from 400 nm or below to 700 nm or above"
        )
    w, h = scene.source_size
    if h < 2 or w < 2:
        raise UnsupportedInputError(f"{path}: image is too small ({w}×{h})")
    spectra = scene.spectra[: h - h % 2, : w - w % 2]  # a view: no copy
    if spectra.dtype != np.float32:
        spectra = spectra.astype(np.float32)
    spectra = spectra.view(np.ndarray)  # a memory map's data as a plain array
    spectra.flags.writeable = False
    # Two reductions at memory speed, no temporary: min is NaN where any value is.
    low, high = spectra.min(), spectra.max()
    if not (np.isfinite(low) and np.isfinite(high)):
        bad = int((~np.isfinite(spectra)).any(axis=2).sum())
        raise UnsupportedInputError(
            f"{path}: {bad} pixel(s) hold NaN or infinite values: fill or mask them before "
            "unprocessing"
        )
    if low < 0:
        bad = int((spectra < 0).any(axis=2).sum())
        raise UnsupportedInputError(
            f"{path}: {bad} pixel(s) hold negative values (a {scene.kind} is ≥ 0): clip "
            "them to 0 before unprocessing"
        )
    light = scene.illuminant
    if isinstance(light, np.ndarray) and (not np.isfinite(light).all() or (light < 0).any()):
        raise UnsupportedInputError(
            f"{path}: its 'illuminant' must be finite and ≥ 0 at every wavelength"
        )
    return replace(scene, spectra=spectra)
