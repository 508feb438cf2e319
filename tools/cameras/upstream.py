"""Readers of the public camera tables that ``build.py`` combines.

Each reader takes the text of one upstream file and returns plain figures; none
carries upstream code. The tables:

- LibRaw ``src/tables/cameralist.cpp``: the cameras LibRaw supports, one string each
  (``"Sony ILCE-7M3 (A7 III)"``, ``"Canon EOS 700D / Rebel T5i / Kiss X7i"``).
- LibRaw ``src/tables/colordata.cpp``, ``adobe_coeff``: per maker, a model prefix, black,
  maximum and the D65 XYZ→camera matrix ×10000 (Adobe DNG Converter's unless a comment
  names another source). LibRaw takes the first entry whose prefix starts the model.
- LibRaw ``src/metadata/normalize_model.cpp``: its alias tables, the other names (EXIF
  spellings, re-badged twins) under which LibRaw files a model ("E-M1MarkIII" for
  Olympus's "E-M1 Mark III", Leica's "V-LUX (Typ 114)" for Panasonic's "DMC-FZ1000").
- rawspeed ``data/cameras.xml`` (CC-BY-SA 3.0): per camera and mode, the make and model
  as the files write them (EXIF Make/Model), the canonical make and model, aliases, the
  CFA layout, sensor black and white levels, a colour matrix.
- RawTherapee ``rtengine/camconst.json`` (GPL-3.0): per camera, measured white
  (clipping) levels, per ISO for some.
- darktable ``data/noiseprofiles.json`` (GPL-3.0): per camera, noise profiles measured
  at each ISO a contributor shot, so the ISOs the camera was set to.
- openMVG CameraSensorSizeDatabase ``sensor_database_detailed.csv`` (MPL-2.0): sensor
  width and height (mm) and resolution (pixels), from digicamdb.com.
"""

from __future__ import annotations

import csv
import io
import json
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

#: LibRaw's maker spellings in cameralist.cpp → the ``LIBRAW_CAMERAMAKER_*`` name its
#: colour table files them under (OM Digital Solutions under Olympus: LibRaw's
#: normalize_model.cpp sets the maker so).
MAKER_ENUM = {
    "fujifilm": "Fujifilm",
    "omnivision": "OmniVison",
    "om digital solutions": "Olympus",
    "konica": "Minolta",
    "yuneec": "Yuneec",
    "xiaoyi": "XIAOYI",
    "huawei": "HUAWEI",
    "vivo": "VIVO",
}
#: Makers written as more than one word in cameralist.cpp.
MULTI_WORD_MAKERS = (
    "Phase One",
    "Konica Minolta",
    "Digital Bolex",
    "JK Imaging",
    "HMD Global",
    "OM Digital Solutions",
)
#: LibRaw's alias tables in normalize_model.cpp: the cameralist makers (folded first
#: word) each table serves, and the maker of the colour table its names are filed under.
ALIAS_TABLES = {
    "fujialias": (("fujifilm",), "Fujifilm"),
    "kodakalias": (("kodak", "canon"), "Kodak"),
    "leafalias": (("leaf", "mamiya"), "Leaf"),
    "KonicaMinolta_aliases": (("minolta", "konica"), "Minolta"),
    "nikonalias": (("nikon",), "Nikon"),
    "olyalias": (("olympus", "om"), "Olympus"),
    "panalias": (("panasonic", "leica", "yuneec"), "Panasonic"),
    "phase1alias": (("phase", "phaseone", "mamiya"), "PhaseOne"),
    "SamsungPentax_aliases": (("pentax", "samsung"), "Pentax"),
    "samsungalias": (("samsung",), "Samsung"),
}


def norm(text: str) -> str:
    """A name folded for matching: lower case, letters and digits only, "+" as "plus"
    (Phase One's "P 25" and "P 25+" are two backs)."""
    return re.sub(r"[^0-9a-z]", "", text.replace("+", "plus").casefold())


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
    """One cameralist.cpp line: maker, the model and the other names it gives, the
    line's text after the maker, and its line number."""

    make: str
    model: str
    aliases: list[str] = field(default_factory=list)
    text: str = ""
    line: int = 0


def camera_list(text: str) -> list[ListedCamera]:
    """The cameras of ``cameralist.cpp`` (generic "Adobe Digital Negative" left out).

    Names joined by "/" without spaces share their last part's tail: "Alpha/Dynax/Maxxum
    5D" also gives "Alpha 5D", "Dynax 5D" and "Maxxum 5D" as aliases."""
    start = text.index("static_camera_list[]")
    offset = text.count("\n", 0, start)
    body = text[start:]
    out = []
    for hit in re.finditer(r'^\s*"([^"]+)",', body, flags=re.M):
        line = hit.group(1)
        if line.startswith("Adobe Digital Negative"):
            continue
        make = next((k for k in MULTI_WORD_MAKERS if line.startswith(k + " ")), line.split(" ")[0])
        rest = line[len(make) :].strip()
        if not rest:
            continue
        names = []
        for part in re.split(r" / |, ", rest):
            m = re.match(r"^(.*?)\s*\(([^)]*)\)\s*$", part)
            if m:
                names.append(m.group(1).strip())
                names.extend(
                    a.strip() for a in m.group(2).split(",") if not _NOTE.search(a.strip())
                )
            else:
                names.append(part.strip())
        model = names[0]
        # "Canon EOS 700D / Rebel T5i / Kiss X7i": the later names lack the family word.
        family = model.split(" ")[0] if " " in model else ""
        aliases = _slashed(model)
        for a in names[1:]:
            aliases.append(a)
            if family and not a.startswith(family) and family.isalpha() and family.isupper():
                aliases.append(f"{family} {a}")
        number = offset + body.count("\n", 0, hit.start()) + 1
        out.append(ListedCamera(make, model, aliases, rest, number))
    return out


#: What in a cameralist.cpp line's parentheses is a note, not a name: "CHDK hack",
#: "secret menu hack", "single shot only", "HE/HE* formats are not supported yet", "V".
_NOTE = re.compile(r"^.?$|CHDK|\b(hack|hacked|secret|only|supported)\b", re.I)


def _slashed(model: str) -> list[str]:
    """The names of "Alpha/Dynax/Maxxum 5D" or "K2000/K-m" (none for a plain model)."""
    if "/" not in model or " / " in model:
        return []
    parts = model.split("/")
    head, _, tail = parts[-1].partition(" ")
    if tail and all(" " not in p for p in parts[:-1]):
        return [f"{p} {tail}" for p in parts[:-1]] + [parts[-1]]
    return parts


@dataclass
class AliasGroup:
    """One group of a LibRaw alias table: the model LibRaw files the names under."""

    table: str
    head: str
    names: list[str]
    line: int


def libraw_aliases(text: str) -> list[AliasGroup]:
    """The groups of LibRaw's alias tables (:data:`ALIAS_TABLES`) in normalize_model.cpp:
    an entry "@HEAD" starts a group, the entries after it are its other names. Adjacent
    string literals join, as in C."""
    text = strip_comments(text)
    out = []
    for m in re.finditer(r"static const char (\w+)\[\]\[\d+\]\s*=\s*\{(.*?)\};", text, re.S):
        if m.group(1) not in ALIAS_TABLES:
            continue
        items, current, at = [], None, 0
        for tok in re.finditer(r'"((?:[^"\\]|\\.)*)"|,', m.group(2)):
            if tok.group(0) == ",":
                if current is not None:
                    items.append((current, at))
                current = None
            elif current is None:
                current, at = tok.group(1), m.start(2) + tok.start()
            else:
                current += tok.group(1)
        if current is not None:
            items.append((current, at))
        for value, pos in items:
            if value.startswith("@"):
                line = text.count("\n", 0, pos) + 1
                out.append(AliasGroup(m.group(1), value[1:], [], line))
            elif out and out[-1].table == m.group(1):
                out[-1].names.append(value)
    return out


def strip_comments(text: str) -> str:
    """``text`` with its C/JavaScript comments blanked (newlines kept, so that line
    numbers and offsets stay); string literals are left alone."""
    out, i, n, inside = [], 0, len(text), False
    while i < n:
        c = text[i]
        if inside:
            out.append(text[i : i + 2] if c == "\\" else c)
            i += 2 if c == "\\" else 1
            inside = c != '"'
            continue
        if c == '"':
            inside = True
        elif text.startswith("//", i) or text.startswith("/*", i):
            line = text[i + 1] == "/"
            end = text.find("\n" if line else "*/", i + 2)
            end = n if end < 0 else end if line else end + 2
            out.append(re.sub(r"[^\n]", " ", text[i:end]))
            i = end
            continue
        out.append(c)
        i += 1
    return "".join(out)


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
    """One rawspeed camera: names, CFA, levels, matrix, and the names its files write.

    ``cfa``, ``matrix`` and ``line`` are its first supported mode's; ``black``, ``white``,
    ``levels_line`` and ``levels_mode`` the deepest mode's (:func:`rawspeed_cameras`).
    ``exif``: the (Make, Model) pairs its files write, from every mode and alias, the
    unsupported cameras' too; ``exif_lines`` the line of each."""

    make: str
    model: str
    aliases: list[str]
    cfa: str | None
    black: int | None
    white: int | None
    matrix: list[int] | None
    line: int
    levels_line: int = 0
    levels_mode: str | None = None
    exif: list[tuple[str, str]] = field(default_factory=list)
    exif_lines: list[int] = field(default_factory=list)


_COLOURS = {"RED": "R", "GREEN": "G", "BLUE": "B"}
#: rawspeed modes whose levels do not describe the sensor's own raw: CHDK's hacked
#: files, Canon's sRaw/mRaw and Nikon's sNEF (demosaicked, scaled) ones.
_OTHER_MODES = re.compile(r"^(chdk|sraw|mraw|snef)", re.I)


def rawspeed_cameras(text: str) -> dict[tuple[str, str], RawspeedCamera]:
    """rawspeed cameras by folded (make, model), for the canonical ID and each alias.

    A camera's modes are merged: its names and file names from all of them; its CFA and
    matrix from the first supported mode; its levels from the mode with the highest
    white level (the camera's deepest raw: a Nikon's 14-bit mode over its 12-bit one),
    leaving out :data:`_OTHER_MODES` and, while another mode has levels, "dng". Sensor
    levels given only per ISO (``iso_list``) are left out: no single figure describes
    them. Cameras rawspeed marks unsupported give their names only.
    """
    lines = {}
    for i, line in enumerate(text.splitlines(), 1):
        m = re.search(r'<Camera make="([^"]*)" model="([^"]*)"(?: mode="([^"]*)")?', line)
        if m:
            lines.setdefault((m.group(1), m.group(2), m.group(3)), i)
    groups: dict[tuple[str, str], list] = {}
    for cam in ET.fromstring(text.encode()).iter("Camera"):
        ident = cam.find("ID")
        make = ident.get("make") if ident is not None else cam.get("make")
        model = ident.get("model") if ident is not None else cam.get("model")
        groups.setdefault((make, model), []).append(cam)
    out: dict[tuple[str, str], RawspeedCamera] = {}
    for (make, model), cams in groups.items():
        entry = _rawspeed_camera(make, model, cams, lines)
        for key in keys_of(make, [model, *entry.aliases]):
            out.setdefault(key, entry)
    return out


def _rawspeed_camera(make: str, model: str, cams: list, lines: dict) -> RawspeedCamera:
    """One camera from its ``<Camera>`` elements (one per mode)."""

    def line_of(cam) -> int:
        return lines.get((cam.get("make"), cam.get("model"), cam.get("mode")), 0)

    aliases, exif, exif_lines = [], [], []
    for cam in cams:
        for name in [cam.get("model")] + [a.text for a in cam.findall("Aliases/Alias")]:
            if name and (cam.get("make"), name) not in exif:
                exif.append((cam.get("make"), name))
                exif_lines.append(line_of(cam))
        for a in cam.findall("Aliases/Alias"):
            alias = a.get("id") or a.text
            if alias and alias not in aliases:
                aliases.append(alias)
    supported = [c for c in cams if c.get("supported") != "no"]
    first = supported[0] if supported else None
    entry = RawspeedCamera(
        make, model, aliases, _cfa(first), None, None, _matrix(first), line_of(first or cams[0])
    )
    entry.exif, entry.exif_lines = exif, exif_lines
    levels = []
    for cam in supported:
        mode = cam.get("mode") or ""
        sensor = [s for s in cam.findall("Sensor") if not {"iso_list", "iso_min"} & set(s.attrib)]
        if sensor and sensor[0].get("white") and not _OTHER_MODES.match(mode):
            white, black = int(sensor[0].get("white")), int(sensor[0].get("black") or 0)
            levels.append((mode == "dng", -white, black, line_of(cam), mode or None))
    if levels:
        _, white, entry.black, entry.levels_line, entry.levels_mode = min(levels)
        entry.white = -white
    return entry


def _cfa(cam) -> str | None:
    """A rawspeed camera's CFA as rows joined by "/" (None without one)."""
    if cam is None:
        return None
    if (c := cam.find("CFA")) is not None:
        w, h = int(c.get("width")), int(c.get("height"))
        grid = [["?"] * w for _ in range(h)]
        for col in c.findall("Color"):
            grid[int(col.get("y"))][int(col.get("x"))] = _COLOURS.get(col.text, "?")
        return "/".join("".join(r) for r in grid)
    if (c := cam.find("CFA2")) is not None:
        return "/".join(r.text.strip() for r in c.findall("ColorRow"))
    return None


def _matrix(cam) -> list[int] | None:
    """A rawspeed camera's colour matrix, ×10000, row by row (None without one)."""
    if cam is None or (cm := cam.find("ColorMatrices/ColorMatrix")) is None:
        return None
    return [int(v) for row in cm.findall("ColorMatrixRow") for v in row.text.split()]


@dataclass
class CamconstWhite:
    """RawTherapee's white level for one camera (``ranges.white``): the level at its lowest
    listed ISO (the lowest channel's where channels differ), the highest level it lists
    (or ``white_max``), the lowest and highest ISO it lists levels for (None for one
    level at every ISO), and the line of its ``make_model``."""

    name: str
    white: int
    top: int
    line: int
    isos: tuple[float, float] | None = None


def camconst_whites(text: str) -> dict[tuple[str, str], CamconstWhite]:
    """camconst.json's white levels by folded (make, model), for each name an entry
    gives ("Canon EOS 550D", "Canon EOS Rebel T2i", …: the maker is the first word)."""
    clean = strip_comments(text)
    starts = [m.start() for m in re.finditer(r'"make_model"', clean)]
    entries = json.loads(clean)["camera_constants"]
    out: dict[tuple[str, str], CamconstWhite] = {}
    for entry, at in zip(entries, starts, strict=True):
        white = entry.get("ranges", {}).get("white")
        if white is None:
            continue
        isos = None
        if isinstance(white, list) and white and isinstance(white[0], dict):
            by_iso = sorted((min(_list(w["iso"])), _list(w["levels"])) for w in white)
            base, every = by_iso[0][1], [v for _, ls in by_iso for v in ls]
            listed = [i for w in white for i in _list(w["iso"])]
            isos = (min(listed), max(listed))
        else:
            base = every = _list(white)
        top = entry["ranges"].get("white_max") or max(every)
        names = _list(entry["make_model"])
        line = clean.count("\n", 0, at) + 1
        item = CamconstWhite(names[0], int(min(base)), int(top), line, isos)
        for name in names:
            make, _, model = name.partition(" ")
            for key in keys_of(make, [model]):
                out.setdefault(key, item)
    return out


def _list(value) -> list:
    return value if isinstance(value, list) else [value]


@dataclass
class IsoRange:
    """The ISOs darktable's noise profiles for a camera were measured at: lowest and
    highest, and the line of the camera's ``model``."""

    make: str
    model: str
    low: float
    high: float
    line: int


def darktable_isos(text: str) -> dict[tuple[str, str], IsoRange]:
    """darktable's noiseprofiles.json ISO ranges by folded (make, model); a model written
    with its maker ("Canon PowerShot SX160 IS") is filed without it too."""
    starts = [m.start() for m in re.finditer(r'"model"\s*:', text)]
    at = iter(starts)
    out: dict[tuple[str, str], IsoRange] = {}
    for maker in json.loads(text)["noiseprofiles"]:
        for cam in maker["models"]:
            line = text.count("\n", 0, next(at)) + 1
            isos = [p["iso"] for p in cam["profiles"] if p["iso"] > 0]
            if not isos:
                continue
            model = cam["model"]
            item = IsoRange(maker["maker"], model, min(isos), max(isos), line)
            first = maker["maker"].split()[0]
            names = [model]
            if model.casefold().startswith(first.casefold() + " "):
                names.append(model[len(first) + 1 :])
            for key in keys_of(maker["maker"], names):
                out.setdefault(key, item)
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
