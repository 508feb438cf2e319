"""A sensor profile for the camera that took one raw (``rawsim profiles from-raw``).

What the raw itself holds comes from LibRaw, through :func:`rawsim.io.raw.read_raw`:
the CFA layout, the black and white levels (hence the bit depth), the XYZ → camera
matrix ``process`` renders the raw with (:func:`rawsim.io.raw.xyz_to_camera_of`:
LibRaw's table for the camera, else a DNG's own ColorMatrix, else LibRaw's camera →
sRGB matrix inverted) and the daylight white balance. One raw cannot say how the noise
changes with ISO, so the noise is, in this order:

1. the camera database's (:mod:`rawsim.cameras`), when it knows the camera: the
   bundled profile's calibration for a measured camera, else the physics estimate,
   each with its ``noise_kind``;
2. else estimated from the raw's own flattest blocks at its ISO, by the estimate
   ``process --denoise profiled`` uses (:func:`rawsim.denoise.noise_model.estimate`),
   written as K(ISO) = K·ISO/ISO₀ through the origin and a read-σ table of its one
   point, ``noise_kind`` "estimated".

Every key's ``source`` names the file and what LibRaw reported. A raw that ``process``
renders without a colour matrix, without a CFA mosaic (a linear DNG) or of one colour is
refused with an :class:`~rawsim.errors.UnsupportedInputError` naming the file, the
reason and the fix.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from rawsim import cameras
from rawsim.errors import ParameterError, UnsupportedInputError, shown

#: The ISO a raw that records none is taken to be shot at (for K(ISO)); said in its source.
ASSUMED_ISO = 100.0
#: The first words of the noise sources, one per origin (see :func:`noise_origin`).
FROM_MEASURED = "camera database, measured"
FROM_ESTIMATED = "camera database, estimated"
FROM_RAW = "estimated from the raw"


def profile_from_raw(path: str | Path) -> dict:
    """The profile (rawsim's JSON format, as :func:`rawsim.cameras.profiles.profile_from_dict`
    reads it) of the camera that took the raw at ``path``; see the module's doc.

    Raises :class:`~rawsim.errors.UnsupportedInputError` for a raw that LibRaw cannot
    read or that holds no CFA mosaic or colour matrix, and for a raw of an unknown
    camera whose flat regions show no shot noise to estimate.
    """
    import rawpy

    from rawsim.io.raw import read_raw, xyz_to_camera_of

    path = Path(path)
    raw = read_raw(path)
    file = path.name
    libraw = "LibRaw " + ".".join(str(v) for v in rawpy.libraw_version[:2])
    camera = _camera_text(raw.make, raw.model)
    xyz, xyz_from = xyz_to_camera_of(raw)
    _refuse_unusable(raw, path, camera, xyz is not None)

    cam = cameras.find_camera(raw.make, raw.model)
    blacks = sorted({float(v) for v in raw.black_level.ravel()})
    black = sum(float(v) for v in raw.black_level.ravel()) / raw.black_level.size
    white = float(raw.white_level)
    bits = max(int(math.ceil(white)).bit_length(), 1)
    if blacks[0] != blacks[-1]:
        black_note = (
            f"; its per-site blacks {', '.join(f'{b:g}' for b in blacks)} differ, "
            "the profile holds their mean"
        )
    else:
        black_note = ""
    span = white - black
    make = raw.make if raw.make != "unknown" or cam is None else cam.data["make"]
    model = _without_maker(raw.model, make)
    source = {
        "camera": (
            f"Make {raw.make!r} and Model {raw.model!r} of {file}"
            + (f"; the camera database's {cam.label}" if cam is not None else "")
            + ("; the maker from the database" if make != raw.make else "")
            + (f"; the model without the maker, {model!r}" if model != raw.model else "")
        ),
        "cfa_pattern": f"{libraw} raw_colors of {file}'s visible area ({raw.cfa.name})",
        "black_level": f"{libraw} black_level_per_channel of {file}{black_note}",
        "white_level": f"{libraw} white_level of {file}",
        "bit_depth": f"the fewest bits that hold {libraw}'s white level {white:g} of {file}",
        "xyz_to_camera": f"{file} through {libraw}, as 'rawsim process' renders it: {xyz_from}",
    }
    profile: dict = {
        "name": cam.name if cam is not None else _slug(camera, path.stem),
        "make": make,
        "model": model,
        "cfa_pattern": raw.cfa.pattern,
        "bit_depth": bits,
        "black_level": _number(black),
        "white_level": _number(white),
        "xyz_to_camera": [[_float32(v) for v in row] for row in xyz],
    }
    if raw.daylight_wb is not None:
        profile["white_balance"] = [_float32(v) for v in raw.daylight_wb]
        source["white_balance"] = (
            f"{libraw} daylight_whitebalance (pre_mul) of {file}, divided by green"
        )
    else:
        source["white_balance"] = "the daylight gains of the matrix (the raw holds none)"

    if cam is not None and cam.bundled:
        noise = _bundled_noise(cam, bits)
    elif cam is not None:
        noise = _database_noise(cam, span)
    else:
        noise = _raw_noise(raw, file)
    profile.update(noise["keys"])
    source.update(noise["source"])
    profile["source"] = source
    return profile


def noise_origin(profile: dict) -> str:
    """Where a :func:`profile_from_raw` profile's noise came from: :data:`FROM_MEASURED`,
    :data:`FROM_ESTIMATED` or :data:`FROM_RAW`."""
    return profile["source"]["noise.gain"].split(":", 1)[0]


def noise_summary(profile: dict) -> str:
    """One line saying where a :func:`profile_from_raw` profile's noise came from."""
    return "noise: " + profile["source"]["noise"]


def _refuse_unusable(raw, path: Path, camera: str, has_matrix: bool) -> None:
    """Refuse, in one line, a raw that cannot give a CFA profile."""
    name = shown(path)
    if raw.cfa is None and raw.data.ndim == 3 and raw.data.shape[2] == 1:
        raise UnsupportedInputError(
            f"{name}: a monochrome raw ({camera}, one colour, no colour filter), so it has "
            "no CFA or colour matrix for a profile; unprocess takes '--sensor mono' with "
            "any profile for such a sensor"
        )
    if raw.cfa is None:
        raise UnsupportedInputError(
            f"{name}: no CFA mosaic ({camera}; LibRaw gives it as full-colour pixels, e.g. "
            "a linear DNG), so there is no sensor layout, levels or noise to read; give a "
            "raw straight from the camera, or a DNG converted without demosaicking"
        )
    if not has_matrix:
        raise UnsupportedInputError(
            f"{name}: no colour matrix for {camera} (none in the file, LibRaw's table or "
            "LibRaw's built-in ones; 'rawsim process' renders it as sRGB), so the profile "
            "would have no colour; convert it with Adobe DNG Converter (which writes a "
            "ColorMatrix), or copy the matrix of a similar camera ('rawsim profiles show "
            "NAME --json') into a profile by hand"
        )


def _camera_text(make: str, model: str) -> str:
    if make == "unknown" and model == "unknown":
        return "an unknown camera"
    if make == "unknown" or model.casefold().startswith(make.casefold()):
        return model
    return f"{make} {model}" if model != "unknown" else make


def _without_maker(model: str, make: str) -> str:
    """The model as profiles write it, without the maker: "Canon EOS 60D" → "EOS 60D",
    "NIKON D850" of "NIKON CORPORATION" → "D850"."""
    first = make.split()[0] if make != "unknown" and make.split() else ""
    if first and model.casefold().startswith(first.casefold() + " "):
        return model[len(first) + 1 :].strip() or model
    return model


def _bundled_noise(cam, bits: int) -> dict:
    """The noise of the bundled profile that holds the camera's calibration."""
    import json

    from rawsim.cameras.profiles import load_profile

    p = load_profile(cam.bundled)
    data = json.loads(Path(p.path).read_text(encoding="utf-8"))
    kind = p.noise_kind or cam.noise_kind
    head = FROM_MEASURED if kind == "measured" else FROM_ESTIMATED
    noise = {k: v for k, v in data["noise"].items() if k != "dark_shading"}
    sources = {
        k: v
        for k, v in data["source"].items()
        if k.startswith("noise.") and k != "noise.dark_shading"
    }
    note = f"{head}: the bundled profile {cam.bundled} of {cam.label}"
    if "dark_shading" in data["noise"]:
        note += " (its dark shading, a file beside it, is left out)"
    factor = 2.0 ** (bits - int(data["bit_depth"]))
    if factor != 1:  # the same electrons in DN of another step: K and σ scale
        keep = ("gain", "read_sigma")
        noise = _scaled({k: noise[k] for k in keep}, factor)
        sources = {f"noise.{k}": sources[f"noise.{k}"] for k in keep}
        note += (
            f", its {data['bit_depth']}-bit DN scaled ×{factor:g} to this raw's {bits} bits "
            "(the physics terms left out)"
        )
    sources = {k: f"{note}: {v}" for k, v in sources.items()}
    sources["iso_range"] = f"the bundled profile {cam.bundled}: {data['source']['iso_range']}"
    what = "a calibration" if kind == "measured" else "derived in that profile"
    sources["noise"] = f"{head} ({what}): {cam.label}, the bundled profile {cam.bundled}" + (
        f", scaled ×{factor:g} to {bits}-bit DN" if factor != 1 else ""
    )
    keys = {
        "iso_range": data["iso_range"],
        "noise": noise,
        "noise_kind": kind,
    }
    if "base_iso" in data:
        keys["base_iso"] = data["base_iso"]
    return {"keys": keys, "source": sources}


def _database_noise(cam, span: float) -> dict:
    """The database's physics estimate for the camera, at this raw's full scale."""
    data = cam.profile_data()
    db_span = float(data["white_level"]) - float(data["black_level"])
    factor = span / db_span
    noise = _scaled(data["noise"], factor)
    src = data["source"]
    note = f"{FROM_ESTIMATED}: the camera database's {cam.label}"
    summary = f"{FROM_ESTIMATED} (the sensor's physics): {cam.label}"
    if abs(factor - 1) > 1e-9:  # K and read σ are both ∝ the span (rawsim.cameras.estimate)
        note += (
            f", at this raw's full scale ({span:g} DN) instead of the table's ({db_span:g} DN): "
            f"K and read σ ×{factor:.4g}"
        )
        summary += f", at this raw's full scale of {span:g} DN"
    return {
        "keys": {
            "iso_range": data["iso_range"],
            "base_iso": data["base_iso"],
            "noise": noise,
            "noise_kind": cam.noise_kind,
        },
        "source": {
            "iso_range": src["iso_range"],
            "noise.gain": f"{note}; {src['noise.gain']}",
            "noise.read_sigma": f"{note}; {src['noise.read_sigma']}",
            "noise": summary,
        },
    }


def _raw_noise(raw, file: str) -> dict:
    """K and read σ fitted to the raw's own flattest blocks, at its ISO."""
    from rawsim.cameras.estimate import ISO_RANGE
    from rawsim.denoise.noise_model import estimate

    try:
        model = estimate(raw)
    except ParameterError as err:
        raise UnsupportedInputError(
            f"{err}".split("; give --noise-profile")[0]
            + "; the camera is not in the database, so measure its noise with "
            "'rawsim calibrate' instead"
        ) from None
    k = float(model.a[0])
    if not k > 0:
        why = model.warnings[0] if model.warnings else "no shot noise found"
        raise UnsupportedInputError(
            f"{shown(raw.path)}: the camera ({_camera_text(raw.make, raw.model)}) is not in "
            f"the database and its flat regions show no shot noise to estimate K from ({why}); "
            "give a raw of it straight from the camera with smooth areas of several "
            "brightnesses, or measure it with 'rawsim calibrate'"
        )
    # the estimate's variance at black is read σ² plus the rounding's 1/12 DN²
    read = math.sqrt(max(float(model.b[0]) - 1 / 12, 0.0))
    iso = float(raw.iso) if raw.iso > 0 else ASSUMED_ISO
    at = f"at ISO {iso:g}" if raw.iso > 0 else f"at ISO {iso:g}, assumed (the raw records none)"
    sure = (
        "the fit is sure"
        if not model.warnings
        else "the fit is unsure: "
        + re.sub(r"^ISO [0-9.]+: ", "", model.warnings[0].split("unsure: ", 1)[-1])
    )
    if not read > 0:
        read = math.sqrt(1 / 12)
        sure += "; no read noise above the rounding's was found: σ set to the rounding's"
    lo, hi = min(ISO_RANGE[0], iso), max(ISO_RANGE[1], iso)
    where = f"{FROM_RAW}: {file}'s flat regions {at}"
    return {
        "keys": {
            "iso_range": [lo, hi],
            "base_iso": iso,
            "noise": {
                "gain": {"model": "linear", "slope": k / iso, "intercept": 0.0},
                "read_sigma": {"model": "table", "iso": [iso], "sigma": [read]},
            },
            "noise_kind": "estimated",
        },
        "source": {
            "iso_range": (
                "assumed: a raw does not record its camera's ISO range; the range assumed "
                "for a camera nothing is known of (rawsim.cameras.estimate.ISO_RANGE)"
                + (f", widened to the raw's ISO {iso:g}" if (lo, hi) != ISO_RANGE else "")
            ),
            "noise.gain": (
                f"{where}, by the patch method of 'rawsim calibrate' "
                f"(rawsim.denoise.noise_model.estimate): K {k:.4g} DN/e⁻, taken as "
                f"proportional to ISO; {sure}"
            ),
            "noise.read_sigma": (
                f"{where}: read σ {read:.4g} DN, held at that value at every ISO "
                f"(one raw measures one ISO); {sure}"
            ),
            "noise": (
                f"{FROM_RAW}'s flat regions {at}: K {k:.4g} DN/e⁻, read σ {read:.4g} DN, "
                f"the fit {'sure' if sure == 'the fit is sure' else 'unsure'}; the camera is "
                "not in the database"
            ),
        },
    }


def _scaled(noise: dict, factor: float) -> dict:
    """``noise.gain`` and ``noise.read_sigma`` (and the rest as they are) with K and σ
    in DN ``factor`` times as fine."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in noise.items()}
    if factor == 1:
        return out
    gain, read = out["gain"], out["read_sigma"]
    if gain["model"] == "linear":
        gain["slope"] = gain["slope"] * factor
        gain["intercept"] = gain.get("intercept", 0.0) * factor
    else:
        gain["k"] = [v * factor for v in gain["k"]]
    if read["model"] == "table":
        read["sigma"] = [v * factor for v in read["sigma"]]
    else:  # ln σ = s·ln K + b: σ·f at K·f
        read["bias"] = read["bias"] + (1 - read["slope"]) * math.log(factor)
    return out


def _float32(value: float) -> float:
    """A float32 figure (what LibRaw holds) as its shortest decimal: 0.6719, not
    0.6718999743461609; it reads back as the same float32."""
    import numpy as np

    return float(str(np.float32(value)))


def _number(value: float) -> int | float:
    return int(value) if float(value).is_integer() else float(value)


def _slug(camera: str, stem: str) -> str:
    """A profile name from the camera's name, or the file's stem for an unknown camera."""
    if camera == "an unknown camera":
        return stem
    return re.sub(r"[^0-9a-z]+", "_", camera.casefold()).strip("_") or stem
