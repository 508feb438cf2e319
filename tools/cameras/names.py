"""A listed camera's colour-table entry and names: the entry LibRaw's tables file it
under, its aliases from LibRaw's alias tables, and the Make and Model its files write.

LibRaw looks a camera's matrix up by a prefix of its model, after its alias tables
(normalize_model.cpp) have put a re-badged or differently spelt model under the name
its colour table uses: Leica's "V-LUX (Typ 114)" under Panasonic's "DMC-FZ1000",
Olympus's "E-M1MarkIII" under "E-M1 Mark III". The Make and Model a camera's files
write (what exiftool and ``rawsim info`` show) are rawspeed's, which matches files by
them; where rawspeed lacks the camera they are assumed in the maker's usual form,
learnt from rawspeed's cameras of that maker ("NIKON CORPORATION" / "NIKON D850").
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass

from upstream import (
    ALIAS_TABLES,
    AliasGroup,
    Coefficients,
    ListedCamera,
    RawspeedCamera,
    coefficients_for,
    maker_key,
    norm,
)


def colour_entry(
    cam: ListedCamera, table: list[Coefficients], groups: list[AliasGroup]
) -> tuple[Coefficients | None, str]:
    """LibRaw's ``adobe_coeff`` entry for ``cam`` and, where an alias table led to it, how
    ("LibRaw files it as 'DMC-FZ1000' (libraw:normalize:533)"); (None, "") for none.

    The model is tried, then the list's whole text ("M (Typ 240)", which LibRaw's
    prefix "M (Typ 2" matches), then the groups of the alias tables that serve its maker
    and hold one of its names."""
    for name in (cam.model, cam.text):
        found = coefficients_for(table, cam.make, name)
        if found:
            return found, ""
    first = cam.make.split()[0].casefold()
    names = {norm(n) for n in (cam.model, cam.text, *cam.aliases)}
    for group in groups:
        makers, colour_maker = ALIAS_TABLES[group.table]
        if first in makers and names & {norm(n) for n in group.names}:
            found = coefficients_for(table, colour_maker, group.head)
            if found:
                return found, f"LibRaw files it as {group.head!r} (libraw:normalize:{group.line})"
    return None, ""


def alias_names(make: str, model: str, groups: list[AliasGroup]) -> list[str]:
    """The other names LibRaw's alias tables give ``model`` of ``make`` (those of the
    group headed by it, in a table that serves the maker)."""
    first = make.split()[0].casefold()
    out = []
    for group in groups:
        if first in ALIAS_TABLES[group.table][0] and norm(group.head) == norm(model):
            out += [n for n in group.names if "," not in n]  # "C70Z,C7000Z": a list
    return out


@dataclass(frozen=True)
class MakerForm:
    """How a maker's files write Make and Model, learnt from rawspeed: the commonest
    Make, the word their Models start with (None if most do not), and the counts."""

    make: str
    prefix: str | None
    cameras: int
    every_make: tuple[str, ...]

    def model(self, model: str) -> str:
        """``model`` as this maker's files write it."""
        if self.prefix and not model.casefold().startswith(self.prefix.casefold() + " "):
            return f"{self.prefix} {model}"
        return model


def maker_forms(rawspeed: dict[tuple[str, str], RawspeedCamera]) -> dict[str, MakerForm]:
    """:class:`MakerForm` by folded maker, from every rawspeed camera's file names."""
    seen = {id(r): r for r in rawspeed.values()}.values()
    makes, words, counts = defaultdict(Counter), defaultdict(Counter), Counter()
    for r in seen:
        key = maker_key(r.make)
        counts[key] += 1
        for exif_make, exif_model in r.exif:
            makes[key][exif_make] += 1
            first = exif_model.split(" ")[0]
            words[key][first if norm(first) == key else None] += 1
    out = {}
    for key, n in counts.items():
        if not makes[key]:
            continue
        word, uses = words[key].most_common(1)[0]
        out[key] = MakerForm(
            makes[key].most_common(1)[0][0],
            word if word and uses * 2 > sum(words[key].values()) else None,
            n,
            tuple(sorted(makes[key])),
        )
    return out


def exif_names(
    make: str, model: str, r: RawspeedCamera | None, forms: dict[str, MakerForm]
) -> tuple[list[list[str]], str]:
    """The (Make, Model) pairs ``model``'s files write and where they come from:
    rawspeed's (every mode and alias), else the maker's usual form, assumed."""
    if r is not None and r.exif:
        return [list(pair) for pair in r.exif], f"rawspeed:cameras:{r.exif_lines[0]}"
    form = forms.get(maker_key(make))
    if form is None:
        return [[make, model]], "assumed: the maker and model as LibRaw lists them"
    return [[form.make, form.model(model)]], (
        f"assumed: {form.make}'s usual form, as the files of rawspeed's {form.cameras} "
        f"{make} cameras write Make and Model"
    )


def share_exif(entries: list[dict], rawspeed_model: str, forms: dict[str, MakerForm]) -> None:
    """Share one rawspeed camera's file names among LibRaw's separate entries for its
    twins ("ILCE-7RM3" and "ILCE-7RM3A", which rawspeed files as one camera with an
    alias): each name goes to the entry it names; a name none names ("CFV-50c/SWC") to
    the entry of rawspeed's own model, else the first. An entry left with none takes
    the maker's usual form (assumed). ``entries`` hold ``exif`` and ``source``."""
    if len(entries) < 2:
        return
    pairs, where = entries[0]["exif"], entries[0]["source"]["exif"]
    own = {id(e): [] for e in entries}
    home = next((e for e in entries if norm(e["model"]) == norm(rawspeed_model)), entries[0])
    for pair in pairs:
        named = [e for e in entries if _names(pair, e)]
        own[id(named[0] if len(named) == 1 else home)].append(pair)
    for e in entries:
        if own[id(e)]:
            e["exif"] = own[id(e)]
        else:
            e["exif"], e["source"]["exif"] = exif_names(e["make"], e["model"], None, forms)
            continue
        e["source"]["exif"] = where


def _names(pair: list[str], entry: dict) -> bool:
    """Whether a file's (Make, Model) names the entry: its model, without a leading maker
    word, is the entry's model or one of LibRaw's list names for it."""
    make, model = pair
    head, _, rest = model.partition(" ")
    if rest and (norm(head) == maker_key(entry["make"]) or head == make.split()[0]):
        model = rest
    names = {norm(entry["model"]), *(norm(a) for a in entry.get("list_names", ()))}
    return norm(model) in names
