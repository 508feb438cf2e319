"""Values no table gives a camera, inferred from the cameras nearest it that one does.

``build.py`` uses this for levels (bit depth, black) and ISO ranges. The nearest cameras
are tried in turn, and the first group that holds any answers:

1. its line: the camera it succeeds or varies ("EOS R6 Mark II" → "EOS R6", "ILCE-9M3"
   → "ILCE-9", "D810A" → "D810"; :func:`line_bases`);
2. the maker's series: the model up to its first digit ("EOS R" of "EOS R6", "ILCE-" of
   "ILCE-7M3", "X-T" of "X-T5");
3. the maker's family: the model's first letters ("EOS", "ILCE", "X", "DC");
4. for ISO ranges, the maker's cameras of the same sensor size, then any maker's;
5. the maker;
6. every camera.

The caller takes the group's commonest value (a bit depth, a black pedestal: makers
use a few) or its median (an ISO). The description names the group, its size and up to
four of its cameras, so that each assumed figure says what it was taken from.
"""

from __future__ import annotations

import re
import statistics
from collections import Counter
from dataclasses import dataclass

from upstream import maker_key, norm

_ROMAN = ("", "I", "II", "III", "IV", "V", "VI", "VII")


def line_bases(model: str) -> list[str]:
    """The models ``model`` succeeds or varies in its line, nearest first: the earlier
    generations of a numbered one ("ILCE-7M5" → "ILCE-7M4", …, "ILCE-7M2", "ILCE-7";
    "Z 6 III" → "Z 6 II", "Z 6"; "EOS R6 Mark II" → "EOS R6"), then that model without
    a final letter after a digit ("ILCE-7R" → "ILCE-7", "D810A" → "D810", "EOS R5 C" →
    "EOS R5")."""
    out, base = [], model
    m = re.match(r"^(.+?)(\s*(?:Mark\s*|Mk\s*)?)(II|III|IV|V|VI|VII)$", model)
    if m:
        stem, sep, n = m.group(1), m.group(2), _ROMAN.index(m.group(3))
        out = [f"{stem}{sep}{_ROMAN[k]}" for k in range(n - 1, 1, -1)] + [stem]
    elif m := re.match(r"^(.*\d[A-Z]?)M(\d)$", model):  # ILCE-7M3, ILCE-7RM3, DSC-RX100M7
        stem, n = m.group(1), int(m.group(2))
        out = [f"{stem}M{k}" for k in range(n - 1, 1, -1)] + [stem]
    base = out[-1] if out else model
    shorter = re.sub(r"(?<=\d)\s?[A-Za-z]$", "", base)
    if shorter != base and shorter:
        out.append(shorter)
    return out


def series(model: str) -> str:
    """The model up to its first digit ("EOS R6" → "EOS R"), folded."""
    return norm(re.match(r"^\D*", model).group(0))


def family(model: str) -> str:
    """The model's first letters ("EOS R6" → "EOS", "ILCE-7M3" → "ILCE"), folded; the
    series where it starts with no letter."""
    return norm(re.match(r"^[A-Za-z]*", model).group(0)) or series(model)


@dataclass(frozen=True)
class Known:
    """A camera whose value a table gives: maker, model, value, its source, and its
    sensor size class (or None)."""

    make: str
    model: str
    value: object
    source: str
    size_class: int | None = None


def nearest(
    make: str,
    model: str,
    known: list[Known],
    size_class: int | None = None,
    every_maker: bool = True,
):
    """(group, how): the first group of :data:`known` cameras near ``make`` ``model``
    (the module's order) and a description of it; the camera itself is left out.
    Without ``every_maker`` the groups stop at the maker's own cameras."""
    mk, own = maker_key(make), norm(model)
    same = [k for k in known if maker_key(k.make) == mk and norm(k.model) != own]
    for base in line_bases(model):
        hit = [k for k in same if norm(k.model) == norm(base)]
        if hit:
            return hit[:1], f"as the {hit[0].model} of its line ({hit[0].source})"
    groups = [
        ([k for k in same if series(k.model) == series(model)], f"{make}'s {_series(model)}"),
        ([k for k in same if family(k.model) == family(model)], f"{make}'s {_family(model)}"),
    ]
    if size_class is not None:
        near = (size_class - 1, size_class, size_class + 1)
        groups += [
            ([k for k in same if k.size_class in near], f"{make}'s of its sensor size"),
        ]
        anyone = [k for k in known if k.size_class in near]
        if every_maker and len(anyone) >= 3:  # one or two would stand for a whole class
            groups.append((anyone, "any maker's of its sensor size"))
    groups.append((same, f"{make}'s"))
    if every_maker:
        groups.append((known, "all makers'"))
    for group, what in groups:
        if group:
            names = ", ".join(f"{k.make} {k.model}" for k in group[:4])
            more = ", …" if len(group) > 4 else ""
            return group, f"{what}, {len(group)} cameras with one ({names}{more})"
    return [], "no camera with one"


def _series(model: str) -> str:
    return re.match(r"^\D*", model).group(0).strip(" -") + " series"


def _family(model: str) -> str:
    name = re.match(r"^[A-Za-z]*", model).group(0)
    return f"{name} family" if name else _series(model)


def median(values) -> float:
    """The lower middle value (one of the values)."""
    return statistics.median_low(sorted(values))


def commonest(values) -> float:
    """The most frequent value; of several as frequent, their :func:`median`."""
    counts = Counter(values)
    top = max(counts.values())
    return median(v for v, n in counts.items() if n == top)


def taken(how: str, kind: str) -> str:
    """How a value was taken from :func:`nearest`'s group: "as the EOS R6 of its line
    (…)", or "the {kind} of Canon's EOS family, 5 cameras with one (…)"."""
    return how if how.startswith("as ") else f"the {kind} of {how}"
