"""A camera's levels (bit depth, black, white in DN) and ISO range: from the public
tables where one gives them, else inferred (:mod:`infer`) and marked "assumed".

Sources, in order:

- white level (and so the bit depth: the fewest bits that hold it) and black level:
  rawspeed's ``Sensor`` of the camera's deepest mode; else LibRaw's ``adobe_coeff``
  maximum and black (0 means "read from each file"); else RawTherapee's camconst.json
  white level at its lowest listed ISO, the bit depth from the highest level it lists
  (``white_max``); else the bundled profile's, for a camera that has one;
- ISO range: the lowest and highest ISO of darktable's noise profiles for the camera;
  else of camconst.json's white levels listed per ISO; else the bundled profile's.

What none gives: the bit depth of the nearest cameras (:func:`infer.nearest`) with the
white level at its full scale; the black level of the nearest cameras with one, at this
camera's bit depth (a black of 512 at 14 bits is 128 at 12); the ISO range of the
nearest cameras, the sensor size counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from infer import Known, commonest, median, nearest, taken


@dataclass
class Levels:
    """A camera's levels in DN and ISO range, each with its source (None: not known)."""

    white: int | None = None
    black: int | None = None
    bits: int | None = None
    iso: tuple[float, float] | None = None
    source: dict[str, str] = field(default_factory=dict)


def sourced(r, co, cc, dt, bundled) -> Levels:
    """What the tables give one camera: ``r`` rawspeed's entry, ``co`` LibRaw's
    coefficients, ``cc`` camconst's white, ``dt`` darktable's ISO range, ``bundled`` its
    bundled profile (each None where absent)."""
    out = Levels()
    if r is not None and r.white:
        mode = f", its {r.levels_mode} mode" if r.levels_mode else ""
        where = f"rawspeed:cameras:{r.levels_line}{mode}"
        out.white, out.black, out.bits = r.white, r.black, r.white.bit_length()
        out.source.update(white_level=where, black_level=where, bit_depth=where)
    elif co is not None and co.maximum > 0:
        where = f"libraw:colour:{co.line}"
        out.white, out.bits = co.maximum, co.maximum.bit_length()
        out.source.update(white_level=where, bit_depth=where)
        if co.black:
            out.black, out.source["black_level"] = abs(co.black), where
    elif cc is not None:
        where = f"rawtherapee:camconst:{cc.line}"
        out.white, out.bits = cc.white, max(cc.top, cc.white).bit_length()
        at = " (at the lowest ISO it lists)" if cc.isos else ""
        out.source["white_level"] = f"{where}{at}"
        out.source["bit_depth"] = f"{where} (the highest level it lists, {cc.top})"
    elif bundled is not None:
        where = f"the bundled profile {bundled.name}"
        out.white, out.black = int(bundled.white_level), int(bundled.black_level)
        out.bits = bundled.bit_depth
        for key in ("white_level", "black_level"):
            out.source[key] = f"{where}: {bundled.source[key]}"
        out.source["bit_depth"] = f"{where}, {bundled.bit_depth}-bit"
    if out.black is None and bundled is not None and out.white is not None:
        if bundled.bit_depth == out.bits:
            out.black = int(bundled.black_level)
            out.source["black_level"] = (
                f"the bundled profile {bundled.name}: {bundled.source['black_level']}"
            )
    if dt is not None:
        out.iso = (dt.low, dt.high)
        out.source["iso_range"] = (
            f"darktable:noise:{dt.line} (the lowest and highest ISO of darktable's noise "
            f"profiles for the {dt.make} {dt.model})"
        )
    elif cc is not None and cc.isos is not None:
        out.iso = cc.isos
        out.source["iso_range"] = (
            f"rawtherapee:camconst:{cc.line} (the lowest and highest ISO it lists white levels for)"
        )
    elif bundled is not None and bundled.iso_range:
        out.iso = tuple(bundled.iso_range)
        out.source["iso_range"] = (
            f"the bundled profile {bundled.name}: {bundled.source['iso_range']}"
        )
    return out


def fill(levels: Levels, make: str, model: str, known: dict, size_class: int | None) -> None:
    """Infer what ``levels`` lacks from ``known`` ("bits", "black", "iso": lists of
    :class:`Known`; black values are (black, bits)) and mark it assumed."""
    if levels.white is None:
        group, how = nearest(make, model, known["bits"])
        levels.bits = int(commonest(k.value for k in group)) if group else 12
        levels.white = (1 << levels.bits) - 1
        levels.source["bit_depth"] = f"assumed: {levels.bits} bits, {taken(how, 'commonest')}"
        levels.source["white_level"] = (
            f"assumed: the full scale of {levels.bits} bits (the raw file records its own)"
        )
    if levels.black is None:
        # A maker's pedestal changes between generations, not in proportion to the bit
        # depth (Canon: 128 at 12 bits, 2048 or 512 at 14): the maker's cameras of the
        # same depth first, then any depth, scaled to this one.
        deep = [k for k in known["black"] if k.value[1] == levels.bits]
        group, how = nearest(make, model, deep, every_maker=False)
        scaled = ""
        if not group:
            group, how = nearest(make, model, known["black"])
            scaled = f", each scaled to {levels.bits} bits"
        blacks = [round(b * 2 ** (levels.bits - bits)) for b, bits in (k.value for k in group)]
        levels.black = int(commonest(blacks)) if blacks else 0
        levels.source["black_level"] = (
            f"assumed: {levels.black} DN, {taken(how, 'commonest')}{scaled} (the raw "
            "file records its own)"
        )
    if levels.iso is None:
        group, how = nearest(make, model, known["iso"], size_class)
        lo = median(k.value[0] for k in group) if group else 100
        hi = median(k.value[1] for k in group) if group else 6400
        levels.iso = (lo, hi)
        levels.source["iso_range"] = f"assumed: ISO {lo:g}–{hi:g}, {taken(how, 'medians')}"


def known_entry(make: str, model: str, levels: Levels, size_class: int | None) -> dict:
    """The :class:`Known` values one camera's sourced levels add to each pool."""
    out = {}
    if levels.bits and "assumed" not in levels.source.get("bit_depth", "assumed"):
        out["bits"] = Known(make, model, levels.bits, levels.source["bit_depth"])
    if levels.black is not None and levels.bits:
        src = levels.source.get("black_level", "")
        if not src.startswith("assumed"):
            out["black"] = Known(make, model, (levels.black, levels.bits), src)
    if levels.iso is not None:
        out["iso"] = Known(make, model, levels.iso, levels.source["iso_range"], size_class)
    return out
