"""Readers of the public camera tables that ``build.py`` combines.

Each reader takes the text of one upstream file and returns plain figures; none
carries upstream code. The tables:

- LibRaw ``src/tables/cameralist.cpp``: the cameras LibRaw supports, one string each
  (``"Sony ILCE-7M3 (A7 III)"``, ``"Canon EOS 700D / Rebel T5i / Kiss X7i"``).
- LibRaw ``src/tables/colordata.cpp``, ``adobe_coeff``: per maker, a model prefix, black,
  maximum and the D65 XYZ→camera matrix ×10000 (Adobe DNG Converter's unless a comment
  names another source). LibRaw takes the first entry whose prefix starts the model.
- rawspeed ``data/cameras.xml`` (CC-BY-SA 3.0): per camera and mode, the canonical make
  and model, aliases, the CFA layout, sensor black and white levels, a colour matrix.
- openMVG CameraSensorSizeDatabase ``sensor_database_detailed.csv`` (MPL-2.0): sensor
  width and height (mm) and resolution (pixels), from digicamdb.com.
"""

from __future__ import annotations

import csv
import io
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

#: LibRaw's maker spellings in cameralist.cpp → its ``LIBRAW_CAMERAMAKER_*`` names.
MAKER_ENUM = {
    "fujifilm": "Fujifilm",
    "omnivision": "OmniVison",
    "om": "OmDigital",
    "konica": "Minolta",
    "yuneec": "Yuneec",
    "xiaoyi": "XIAOYI",
    "huawei": "HUAWEI",
    "vivo": "VIVO",
}
#: Makers written as two words in cameralist.cpp.
TWO_WORD_MAKERS = ("Phase One", "Konica Minolta", "Digital Bolex", "JK Imaging", "HMD Global")


def norm(text: str) -> str:
    """A name folded for matching: lower case, letters and digits only."""
    return re.sub(r"[^0-9a-z]", "", text.casefold())


_ROMAN = {"II": 2, "III": 3, "IV": 4, "V": 5, "VI": 6, "VII": 7}


def maker_key(make: str) -> str:
    """A maker folded for matching: "Nikon Corporation", "NIKON" → "nikon"."""
    words = make.replace("_", " ").split()
    if words[0].casefold() == "eastman" and len(words) > 1:
        words = words[1:]
    if words[0].casefold() == "phase":
        return "phaseone"
    return norm(words[0])


def model_keys(model: str) -> set[str]:
    """A model folded for matching, with Sony's and others' "M2" for "II" and "Mark II"."""
    keys = {norm(model)}
    m = re.match(r"^(.*?)\s*(?:Mark\s*|Mk\s*|M)?(II|III|IV|V|VI|VII)$", model.strip())
    if m:
        n = _ROMAN[m.group(2)]
        keys |= {norm(f"{m.group(1)}M{n}"), norm(f"{m.group(1)} Mark {m.group(2)}")}
    return keys


def keys_of(make: str, names: list[str]) -> list[tuple[str, str]]:
    """The (maker, model) keys under which any of ``names`` of ``make`` is filed."""
    return [(maker_key(make), k) for n in names for k in sorted(model_keys(n))]


@dataclass
class ListedCamera:
    """One cameralist.cpp line: maker, the model and the other names it gives."""

    make: str
    model: str
    aliases: list[str] = field(default_factory=list)


def camera_list(text: str) -> list[ListedCamera]:
    """The cameras of ``cameralist.cpp`` (generic "Adobe Digital Negative" left out)."""
    body = text.split("static_camera_list[]", 1)[1]
    out = []
    for line in re.findall(r'^\s*"([^"]+)",', body, flags=re.M):
        if line.startswith("Adobe Digital Negative"):
            continue
        make = next((m for m in TWO_WORD_MAKERS if line.startswith(m + " ")), line.split(" ")[0])
        rest = line[len(make) :].strip()
        if not rest:
            continue
        names = []
        for part in re.split(r" / |, ", rest):
            m = re.match(r"^(.*?)\s*\(([^)]*)\)\s*$", part)
            if m:
                names.append(m.group(1).strip())
                names.extend(
                    a.strip() for a in m.group(2).split(",") if a.strip() and "CHDK" not in a
                )
            else:
                names.append(part.strip())
        model = names[0]
        # "Canon EOS 700D / Rebel T5i / Kiss X7i": the later names lack the family word.
        family = model.split(" ")[0] if " " in model else ""
        aliases = []
        for a in names[1:]:
            aliases.append(a)
            if family and not a.startswith(family) and family.isalpha() and family.isupper():
                aliases.append(f"{family} {a}")
        out.append(ListedCamera(make, model, aliases))
    return out


@dataclass
class Coefficients:
    """One adobe_coeff entry: ×10000 matrix rows and LibRaw's black and maximum (0: per file)."""

    maker: str
    prefix: str
    black: int
    maximum: int
    matrix: list[int]
    note: str
    line: int


def adobe_coeff(text: str) -> list[Coefficients]:
    """The entries of LibRaw's ``adobe_coeff`` table, in table order, with their line."""
    out = []
    # Entries commented out upstream are not LibRaw's: blank them, keeping line numbers.
    text = re.sub(r"^\s*//[^\n]*", "", text, flags=re.M)
    pattern = re.compile(
        r"\{\s*LIBRAW_CAMERAMAKER_(\w+)\s*,\s*\"([^\"]*)\"\s*,\s*(-?\w+)\s*,\s*(-?\w+)\s*,"
        r"[^{]*\{([^}]*)\}\s*\}\s*,?\s*((?:/\*.*?\*/|//[^\n]*)?)",
        flags=re.S,
    )
    for m in pattern.finditer(text):
        values = [int(v, 0) for v in m.group(5).replace("\n", " ").split(",") if v.strip()]
        note = m.group(6).strip().strip("/*").strip()
        line = text.count("\n", 0, m.start()) + 1
        black, maximum = (int(m.group(i), 0) for i in (3, 4))
        out.append(Coefficients(m.group(1), m.group(2), black, maximum, values, note, line))
    return out


def coefficients_for(table: list[Coefficients], maker: str, model: str) -> Coefficients | None:
    """LibRaw's own choice: the first entry of the maker whose prefix starts ``model``."""
    enum = MAKER_ENUM.get(maker.casefold(), maker)
    for entry in table:
        if entry.maker.casefold() == enum.casefold() and model.casefold().startswith(
            entry.prefix.casefold()
        ):
            return entry
    return None


@dataclass
class RawspeedCamera:
    """One rawspeed camera (its first listed mode): names, CFA, levels, matrix."""

    make: str
    model: str
    aliases: list[str]
    cfa: str | None
    black: int | None
    white: int | None
    matrix: list[int] | None
    line: int


_COLOURS = {"RED": "R", "GREEN": "G", "BLUE": "B"}


def rawspeed_cameras(text: str) -> dict[tuple[str, str], RawspeedCamera]:
    """rawspeed cameras by folded (make, model), for the canonical ID and each alias.

    The first mode listed for a camera wins (the default one). Sensor levels given
    only per ISO (``iso_list``) are left out: no single figure describes them.
    """
    lines = {}
    for i, line in enumerate(text.splitlines(), 1):
        m = re.search(r'<Camera make="([^"]*)" model="([^"]*)"', line)
        if m:
            lines.setdefault((m.group(1), m.group(2)), i)
    out: dict[tuple[str, str], RawspeedCamera] = {}
    for cam in ET.fromstring(text.encode()).iter("Camera"):
        if cam.get("supported") == "no":
            continue
        ident = cam.find("ID")
        make = ident.get("make") if ident is not None else cam.get("make")
        model = ident.get("model") if ident is not None else cam.get("model")
        cfa = None
        if (c := cam.find("CFA")) is not None:
            w, h = int(c.get("width")), int(c.get("height"))
            grid = [["?"] * w for _ in range(h)]
            for col in c.findall("Color"):
                grid[int(col.get("y"))][int(col.get("x"))] = _COLOURS.get(col.text, "?")
            cfa = "/".join("".join(r) for r in grid)
        elif (c := cam.find("CFA2")) is not None:
            cfa = "/".join(r.text.strip() for r in c.findall("ColorRow"))
        sensor = [s for s in cam.findall("Sensor") if "iso_list" not in s.attrib]
        black = int(sensor[0].get("black")) if sensor else None
        white = int(sensor[0].get("white")) if sensor else None
        matrix = None
        if (cm := cam.find("ColorMatrices/ColorMatrix")) is not None:
            matrix = [int(v) for row in cm.findall("ColorMatrixRow") for v in row.text.split()]
        aliases = [a.get("id") or a.text for a in cam.findall("Aliases/Alias")]
        entry = RawspeedCamera(
            make,
            model,
            aliases,
            cfa,
            black,
            white,
            matrix,
            lines.get((cam.get("make"), cam.get("model")), 0),
        )
        for key in keys_of(make, [model, *aliases]):
            out.setdefault(key, entry)
    return out


@dataclass
class SensorSize:
    """openMVG/digicamdb: sensor size (mm) and resolution (pixels), when given."""

    make: str
    model: str
    size_mm: tuple[float, float]
    resolution: tuple[int, int] | None


def sensor_sizes(text: str) -> dict[tuple[str, str], SensorSize]:
    """openMVG's detailed table by folded (make, model) for each name a row gives.

    A row such as ``EOS Rebel T5i / 700D`` is filed under each of its names, and under
    ``EOS 700D`` too (the family word of the first name carried to the later ones).
    """
    out: dict[tuple[str, str], SensorSize] = {}
    reader = csv.reader(io.StringIO(text.replace("\r", "")))
    next(reader)
    for row in reader:
        if len(row) < 7:
            continue
        make, model, _, w, h, px, py = row[:7]
        try:
            size = (float(w), float(h))
        except ValueError:
            continue
        res = (int(px), int(py)) if px.isdigit() and py.isdigit() else None
        entry = SensorSize(make, model, size, res)
        names = [n.strip() for n in model.split(" / ")]
        family = names[0].split(" ")[0] if " " in names[0] else ""
        for key in keys_of(make, names + [f"{family} {n}" for n in names[1:] if family]):
            out.setdefault(key, entry)
    return out
