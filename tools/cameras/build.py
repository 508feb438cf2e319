"""Build ``rawsim/cameras/cameras.json``: a profile for every camera LibRaw knows.

Run from the repository root, with snapshots of the upstream repositories as git
directories (``fetch`` gives them; any clone works) and darktable's noise profiles::

    python tools/cameras/build.py \\
        --libraw /work/.mirror/LibRaw+LibRaw/repo \\
        --rawspeed /work/.mirror/darktable-org+rawspeed/repo \\
        --sensors /work/.mirror/openMVG+CameraSensorSizeDatabase/repo \\
        --rawtherapee /work/.mirror/Beep6581+RawTherapee/repo \\
        --noiseprofiles /usr/share/darktable/noiseprofiles.json --darktable release-4.2.1

Only figures are carried, each with the upstream file, commit and line it came from
(``upstream.py`` reads the tables). For each camera in LibRaw's list:

- make, model, aliases: LibRaw's list and alias tables, plus rawspeed's aliases; the
  Make and Model its files write (``exif``): rawspeed's, else the maker's usual form
  (assumed, and said);
- D65 XYZ→camera matrix: LibRaw's ``adobe_coeff`` (its own prefix rule, under the name
  LibRaw's alias tables file the camera under), else rawspeed's;
- CFA: rawspeed, else assumed RGGB;
- white level and bit depth: rawspeed (the camera's deepest mode), else LibRaw's table,
  else RawTherapee's camconst.json; black level: rawspeed or LibRaw's table. What none
  gives is inferred from the cameras nearest it that one does (``infer.py``: its line,
  its series, its family, its maker) and marked "assumed";
- ISO range: the ISOs darktable's noise profiles were measured at, else inferred as
  the levels are (with the sensor size among the groups) and marked "assumed";
- noise: a bundled profile's when one names the camera (ELD, PMN, PMRID calibrations);
  otherwise estimated (``rawsim.cameras.estimate``), the constants fitted on the five
  cameras ELD calibrated, with the leave-one-out error stored beside them;
- sensor size and pixel area: openMVG/digicamdb (size and resolution), else lensfun's crop
  factor (size) with the median pixel area of cameras of that size (assumed).

Cameras left out, with the count of each reason: no colour matrix in either table,
Foveon or monochrome sensors, four-colour (CMYG) sensors.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import statistics
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from infer import line_bases  # noqa: E402
from levels import fill, known_entry, sourced  # noqa: E402
from names import alias_names, colour_entry, exif_names, maker_forms, share_exif  # noqa: E402
from upstream import (  # noqa: E402
    adobe_coeff,
    camconst_whites,
    camera_list,
    darktable_isos,
    keys_of,
    libraw_aliases,
    maker_key,
    norm,
    rawspeed_cameras,
    sensor_sizes,
)

from rawsim.cameras import estimate  # noqa: E402
from rawsim.cameras.profiles import list_profiles, load_profile  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "rawsim" / "cameras" / "cameras.json"
#: Bundled profiles whose noise is a published calibration, and the study that made it.
CALIBRATED = {
    "canon_eos_5d_mark_iv": "ELD (Wei et al., CVPR 2020)",
    "canon_eos_700d": "ELD (Wei et al., CVPR 2020)",
    "canon_eos_70d": "ELD (Wei et al., CVPR 2020)",
    "nikon_d850": "ELD (Wei et al., CVPR 2020)",
    "sony_a7s2": "ELD (Wei et al., CVPR 2020) and PMN (Feng et al., 2022)",
    "nikon_d800e": "a public measurement at ISO 100 (see the profile's source)",
    "oppo_reno10x": "PMRID (Wang et al., ECCV 2020)",
    "sony_imx686": "PMN (Feng et al., ACM MM 2022)",
}
#: The cameras the estimate is fitted and checked on: those ELD calibrated.
ELD = ("canon_eos_5d_mark_iv", "canon_eos_700d", "canon_eos_70d", "nikon_d850", "sony_a7s2")
#: ISOs of the leave-one-out check (the issue's range).
CHECK_ISO = (400, 800, 1600, 3200, 6400)
MAKER_NAMES = {"FujiFilm": "Fujifilm", "PhaseOne": "Phase One", "BlackMagic": "Blackmagic"}
#: Layouts no table gives, from the maker's specification.
CFA_FROM_SPEC = {
    ("Fujifilm", "X-T50"): (
        "XTRANS",
        "Fujifilm's specification: X-Trans CMOS 5 HR (the layout of rawspeed's X-T5)",
    ),
}
#: Makers of medium-format digital backs and bodies only (sensor diagonals over 50 mm).
MEDIUM_FORMAT = ("leaf", "phaseone", "sinar", "imacon", "mamiya", "hasselblad")
FOVEON = re.compile(r"^(SD\d|SD Quattro|DP\d|dp\d|sd Quattro)", re.I)


def git_text(repo: str, path: str) -> str:
    return subprocess.run(
        ["git", "--git-dir", repo, "show", f"HEAD:{path}"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def git_head(repo: str) -> str:
    return subprocess.run(
        ["git", "--git-dir", repo, "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()


def slug(make: str, model: str) -> str:
    text = model if model.casefold().startswith(make.casefold()) else f"{make} {model}"
    return re.sub(r"[^0-9a-z]+", "_", text.casefold()).strip("_")


def leave_one_out() -> tuple[dict, list[dict]]:
    """The constants from all five ELD cameras, and each one predicted from the others."""
    cams = [estimate.calibrated_camera(load_profile(n), CHECK_ISO) for n in ELD]
    rows = []
    for i, c in enumerate(cams):
        k = estimate.fit(cams[:i] + cams[i + 1 :])
        for iso, true_k, true_s in c["points"]:
            est_k = estimate.gain(iso, c["span"], c["area"], k["eta"])
            est_s = estimate.read_sigma(est_k, c["span"], k["read_e"], k["floor_dn14"])
            rows.append(
                {
                    "camera": c["name"],
                    "iso": iso,
                    "k_measured": round(true_k, 5),
                    "k_estimated": round(est_k, 5),
                    "k_error": round(est_k / true_k - 1, 4),
                    "read_sigma_measured": round(true_s, 3),
                    "read_sigma_estimated": round(est_s, 3),
                    "read_sigma_error": round(est_s / true_s - 1, 4),
                }
            )
    return estimate.fit(cams), rows


class Sizes:
    """Sensor size and pixel area by camera: digicamdb's (via openMVG), else lensfun's crop
    factor with an assumed pixel area, else an assumed pixel area alone.

    Each assumption's own error is measured on the digicamdb cameras whose area is known
    (``errors``): the assumed area against the true one, median and 90th percentile.
    """

    def __init__(self, table: dict, lensfun_cameras: list):
        self.table = table
        self.crop = {}
        for c in lensfun_cameras:
            first = c.maker.split()[0]
            model = c.model
            if model.casefold().startswith(first.casefold()):
                model = model[len(first) :].strip()
            for key in keys_of(c.maker, [model]):
                self.crop.setdefault(key, c.crop_factor)
        known = [s for s in {id(v): v for v in table.values()}.values() if s.resolution]
        by_size, by_maker = defaultdict(list), defaultdict(list)
        for s in known:
            area = estimate.pixel_area(s.size_mm, s.resolution)
            by_size[self.size_class(s.size_mm)].append(area)
            by_maker[maker_key(s.make)].append(area)
        self.size_area = {k: statistics.median(v) for k, v in by_size.items() if len(v) >= 3}
        self.maker_area = {k: (statistics.median(v), len(v)) for k, v in by_maker.items()}
        self.maker_area = {k: v for k, v in self.maker_area.items() if v[1] >= 5}
        every = [a for v in by_maker.values() for a in v]
        self.any_area = (statistics.median(every), len(every))
        medium = [self._true(s) for s in known if math.hypot(*s.size_mm) > 50]
        self.medium_area = (statistics.median(medium), len(medium))
        self.errors = {
            "size": _spread([self._by_size(s.size_mm, s.make) / self._true(s) for s in known]),
            "none": _spread([self._by_maker(s.make)[0] / self._true(s) for s in known]),
            "medium format": _spread([self.medium_area[0] / a for a in medium]),
        }

    @staticmethod
    def _true(s) -> float:
        return estimate.pixel_area(s.size_mm, s.resolution)

    @staticmethod
    def size_class(size_mm) -> int:
        """Sensor diagonals within about 4 % share a class."""
        return round(math.log(math.hypot(*size_mm)) / math.log(1.04))

    def _sibling(self, make: str, model: str):
        """(size, how) of the camera this one succeeds or varies in its line ("Z 6 II" →
        "Z 6", "ILCE-9M3" → "ILCE-9", "EOS R5 C" → "EOS R5", "D810A" → "D810"): a line
        keeps its sensor format. None if no such camera has a size."""
        for base in line_bases(model):
            for key in keys_of(make, [base]):
                if key in self.table:
                    s = self.table[key]
                    return s.size_mm, f"openmvg:{s.make};{s.model} (size of the {base} of its line)"
                if key in self.crop:
                    cf = self.crop[key]
                    how = f"lensfun crop factor {cf:g} of the {base} of its line, aspect assumed"
                    return _crop_size(cf), how
        return None

    def _by_size(self, size_mm, make: str) -> float:
        cls = self.size_class(size_mm)
        near = [self.size_area[c] for c in (cls, cls - 1, cls + 1) if c in self.size_area]
        return near[0] if near else self._by_maker(make)[0]

    def _by_maker(self, make: str) -> tuple[float, str]:
        key = maker_key(make)
        area, n = self.maker_area.get(key, self.any_area)
        whose = "the maker's" if key in self.maker_area else "all"
        return area, f"the median of {whose} {n} digicamdb cameras"

    def find(self, make: str, model: str, keys: list[tuple[str, str]]):
        """(size mm or None, resolution or None, area µm², basis, how it was found)."""
        s = next((self.table[k] for k in keys if k in self.table), None)
        if s and s.resolution:
            return s.size_mm, s.resolution, self._true(s), "pitch", f"openmvg:{s.make};{s.model}"
        if s:
            size, how = s.size_mm, f"openmvg:{s.make};{s.model} (size only)"
        elif cf := next((self.crop[k] for k in keys if k in self.crop), None):
            size, (aw, ah) = _crop_size(cf), _aspect(cf)
            how = f"lensfun crop factor {cf:g}, aspect {aw}:{ah} assumed"
        elif sibling := self._sibling(make, model):
            size, how = sibling
        elif maker_key(make) in MEDIUM_FORMAT and maker_key(make) not in self.maker_area:
            area, n = self.medium_area
            err = self.errors["medium format"]
            return (
                None,
                None,
                area,
                "none",
                (
                    f"no sensor size found; {make} makes medium-format backs only: pixel area "
                    f"assumed, the median of digicamdb's {n} medium-format cameras (this "
                    f"assumption alone: median error {err['median']:.0%}, 90th percentile "
                    f"{err['p90']:.0%})"
                ),
            )
        else:
            area, whose = self._by_maker(make)
            err = self.errors["none"]
            return (
                None,
                None,
                area,
                "none",
                (
                    f"no sensor size found; pixel area assumed: {whose} (this assumption alone: "
                    f"median error {err['median']:.0%}, 90th percentile {err['p90']:.0%})"
                ),
            )
        err = self.errors["size"]
        return (
            size,
            None,
            self._by_size(size, make),
            "size",
            (
                f"{how}; pixel area assumed: the median of digicamdb cameras of this size "
                f"(this assumption alone: median error {err['median']:.0%}, "
                f"90th percentile {err['p90']:.0%})"
            ),
        )


def _aspect(crop_factor: float) -> tuple[int, int]:
    """The aspect assumed for a crop factor: 4:3 from Four Thirds (about 2) down, else 3:2."""
    return (4, 3) if crop_factor >= 1.9 else (3, 2)


def _crop_size(crop_factor: float) -> tuple[float, float]:
    """Sensor (width, height) in mm of a crop factor: the diagonal of 36 × 24 mm over it,
    at :func:`_aspect`."""
    aspect = _aspect(crop_factor)
    unit = math.hypot(36, 24) / crop_factor / math.hypot(*aspect)
    return round(aspect[0] * unit, 2), round(aspect[1] * unit, 2)


def _spread(ratios: list[float]) -> dict:
    """Median and 90th percentile of |assumed/true − 1| in log terms (as fractions)."""
    logs = sorted(abs(math.log(r)) for r in ratios)
    return {
        "median": math.exp(logs[len(logs) // 2]) - 1,
        "p90": math.exp(logs[int(0.9 * len(logs))]) - 1,
        "cameras": len(logs),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--libraw", required=True, help="git directory of LibRaw")
    ap.add_argument("--rawspeed", required=True, help="git directory of darktable-org/rawspeed")
    ap.add_argument(
        "--sensors", required=True, help="git directory of openMVG/CameraSensorSizeDatabase"
    )
    ap.add_argument("--rawtherapee", required=True, help="git directory of Beep6581/RawTherapee")
    ap.add_argument("--noiseprofiles", required=True, type=Path, help="darktable's file")
    ap.add_argument(
        "--darktable", required=True, help="the darktable release the file is from (its tag)"
    )
    ap.add_argument("-o", "--output", type=Path, default=OUT)
    args = ap.parse_args()

    upstream = _upstream(args)
    libraw_text = git_text(args.libraw, "src/tables/cameralist.cpp")
    listed = camera_list(libraw_text)
    coeffs = adobe_coeff(git_text(args.libraw, "src/tables/colordata.cpp"))
    groups = libraw_aliases(git_text(args.libraw, "src/metadata/normalize_model.cpp"))
    rawspeed = rawspeed_cameras(git_text(args.rawspeed, "data/cameras.xml"))
    whites = camconst_whites(git_text(args.rawtherapee, "rtengine/camconst.json"))
    isos = darktable_isos(args.noiseprofiles.read_text(encoding="utf-8"))
    forms = maker_forms(rawspeed)
    import lensfunpy

    sizes = Sizes(
        sensor_sizes(git_text(args.sensors, "sensor_database_detailed.csv")),
        lensfunpy.Database().cameras,
    )
    constants, loo = leave_one_out()
    bundled = {}
    for name in list_profiles():
        p = load_profile(name)
        bundled[(maker_key(p.make), norm(p.model))] = p

    cameras, skipped, seen = [], Counter(), set()
    known = defaultdict(list)  # sourced levels and ISO ranges, for the inference
    for cam in listed:
        entry = _camera(cam, coeffs, groups, rawspeed, whites, isos, forms, sizes, bundled)
        if isinstance(entry, str):
            skipped[entry] += 1
            continue
        if entry["name"] in seen:  # "P 20" and "P 20+", "M (Typ 240)" and "M (Typ 262)"
            name = slug(entry["make"], cam.text.replace("+", " plus"))
            if name in seen:
                skipped["listed twice"] += 1
                continue
            entry["name"], entry["model"] = name, cam.text
        seen.add(entry["name"])
        mine = known_entry(entry["make"], cam.model, entry["levels"], _size_class(entry))
        for pool, value in mine.items():
            known[pool].append(value)
        cameras.append(entry)

    for entry in cameras:
        lv = entry.pop("levels")
        fill(lv, entry["make"], entry["model"], known, _size_class(entry))
        entry.update(
            bit_depth=lv.bits, black_level=lv.black, white_level=lv.white, iso_range=list(lv.iso)
        )
        entry["source"].update(lv.source)
        if "bundled" not in entry:
            entry["noise"] = estimate.noise_spec(
                lv.white - lv.black, entry["pixel_area_um2"], constants, lv.iso
            )
        entry["source"] = {k: entry["source"][k] for k in SOURCE_ORDER if k in entry["source"]}
    twins = defaultdict(list)
    for entry in cameras:
        if entry["rawspeed"]:
            twins[entry["rawspeed"]].append(entry)
    for (_, model), entries in twins.items():
        share_exif(entries, model, forms)
    for entry in cameras:
        del entry["rawspeed"], entry["list_names"]
    _drop_shared_aliases(cameras)

    out = {
        "about": (
            "Generated by tools/cameras/build.py; do not edit. "
            "Figures only, each with its upstream line."
        ),
        "upstream": upstream,
        "estimate": {
            "constants": {k: round(v, 6) for k, v in constants.items()},
            "fitted_on": [f"{n} ({CALIBRATED[n]})" for n in ELD],
            "pixel_area_assumed_error": {
                k: {m: round(v, 3) for m, v in e.items()} for k, e in sizes.errors.items()
            },
            "leave_one_out": loo,
        },
        "bundled": {
            name: {
                "noise_kind": "measured" if name in CALIBRATED else "estimated",
                "noise_source": CALIBRATED.get(name, "derived in the profile (see its sources)"),
            }
            for name in list_profiles()
        },
        "makers": _makers(cameras, forms),
        "skipped": dict(skipped),
        "cameras": cameras,
    }
    text = json.dumps(out, indent=1, ensure_ascii=False)
    # One camera per line keeps the file small and its diffs readable.
    args.output.write_text(_compact(out) + "\n")
    errors = [abs(r["k_error"]) for r in loo]
    print(f"{len(cameras)} cameras written to {args.output} ({len(text) // 1024} kB indented)")
    print(f"skipped: {dict(skipped)}")
    assumed = Counter(k for c in cameras for k, v in c["source"].items() if v.startswith("assumed"))
    print(f"assumed: {dict(assumed)}")
    print(f"constants: {constants}; leave-one-out |K error| max {max(errors):.1%}")
    for row in loo:
        if row["iso"] in (400, 6400):
            print(
                f"  {row['camera']:<22} ISO {row['iso']:>5}: K {row['k_estimated']:.4g} vs "
                f"{row['k_measured']:.4g} ({row['k_error']:+.1%}); read σ "
                f"{row['read_sigma_estimated']:.3g} vs {row['read_sigma_measured']:.3g} "
                f"({row['read_sigma_error']:+.1%})"
            )


#: The order of an entry's sources.
SOURCE_ORDER = (
    "xyz_to_camera",
    "cfa_pattern",
    "bit_depth",
    "black_level",
    "white_level",
    "iso_range",
    "sensor",
    "noise",
    "exif",
)


def _upstream(args) -> dict:
    """Each upstream table: repository, commit (or release), licence and files."""
    import lensfunpy

    return {
        "libraw": {
            "repo": "github.com/LibRaw/LibRaw",
            "commit": git_head(args.libraw),
            "licence": "LGPL-2.1 or CDDL-1.0 (figures only carried)",
            "files": {
                "list": "src/tables/cameralist.cpp",
                "colour": "src/tables/colordata.cpp",
                "normalize": "src/metadata/normalize_model.cpp",
            },
        },
        "rawspeed": {
            "repo": "github.com/darktable-org/rawspeed",
            "commit": git_head(args.rawspeed),
            "licence": "CC-BY-SA 3.0 (figures only carried)",
            "files": {"cameras": "data/cameras.xml"},
        },
        "rawtherapee": {
            "repo": "github.com/Beep6581/RawTherapee",
            "commit": git_head(args.rawtherapee),
            "licence": "GPL-3.0 (figures only carried)",
            "files": {"camconst": "rtengine/camconst.json"},
        },
        "darktable": {
            "repo": "github.com/darktable-org/darktable",
            "commit": args.darktable,
            "licence": "GPL-3.0 (figures only carried)",
            "files": {"noise": "data/noiseprofiles.json"},
            "read_from": f"{args.noiseprofiles}, as darktable {args.darktable} installs it",
        },
        "openmvg": {
            "repo": "github.com/openMVG/CameraSensorSizeDatabase",
            "commit": git_head(args.sensors),
            "licence": "MPL-2.0; figures from digicamdb.com",
            "files": {"sizes": "sensor_database_detailed.csv"},
        },
        "lensfun": {
            "repo": "the lensfun database bundled with lensfunpy",
            "commit": f"lensfunpy {lensfunpy.__version__}",
            "licence": "CC-BY-SA 3.0 (figures only carried)",
            "files": {"cameras": "db/*.xml (crop factors)"},
        },
    }


def _camera(cam, coeffs, groups, rawspeed, whites, isos, forms, sizes, bundled):
    """One listed camera's entry (its levels still to fill: ``levels``), or why it is
    left out."""
    make = MAKER_NAMES.get(cam.make, cam.make)
    keys = keys_of(cam.make, [cam.model, *cam.aliases])
    r = next((rawspeed[k] for k in keys if k in rawspeed), None)
    co, via = colour_entry(cam, coeffs, groups)
    src = {}
    if co and co.matrix and co.matrix[0] and len(co.matrix) in (9, 12):
        if len(co.matrix) == 12 and any(co.matrix[9:]):
            return "four-colour (CMYG) sensor"
        m = co.matrix[:9]
        how = co.note if co.note and not co.note.startswith("same CMs") else "Adobe DNG Converter"
        via = f"; {via}" if via else ""
        src["xyz_to_camera"] = f"libraw:colour:{co.line} (prefix {co.prefix!r}; {how}{via})"
    elif r and r.matrix and len(r.matrix) == 9:
        m = r.matrix
        src["xyz_to_camera"] = f"rawspeed:cameras:{r.line}"
    else:
        return "no colour matrix in LibRaw's or rawspeed's tables"
    if (make == "Sigma" and FOVEON.match(cam.model)) or "monochrom" in cam.model.casefold():
        return "Foveon or monochrome sensor"
    if r and r.cfa and set(r.cfa) - set("RGB/"):
        return "four-colour (CMYG) sensor"
    cfa, src["cfa_pattern"] = _cfa(cam, make, r, rawspeed)
    level_source = co if co and not via else None  # an alias's levels are another body's
    profile = bundled.get((maker_key(make), norm(cam.model)))
    levels = sourced(
        r,
        level_source,
        next((whites[k] for k in keys if k in whites), None),
        next((isos[k] for k in keys if k in isos), None),
        profile,
    )
    size, res, area, basis, src["sensor"] = sizes.find(cam.make, cam.model, keys)
    exif, src["exif"] = exif_names(make, cam.model, r, forms)
    names = cam.aliases + (r.aliases if r else []) + alias_names(cam.make, cam.model, groups)
    entry = {
        "name": slug(make, cam.model),
        "make": make,
        "model": cam.model,
        "libraw": f"{cam.make} {cam.text}",  # the line of LibRaw's list
        "aliases": sorted(set(names) - {cam.model}),
        "exif": exif,
        "cfa_pattern": cfa,
        "xyz_to_camera": [[v / 10000 for v in m[i : i + 3]] for i in (0, 3, 6)],
        "sensor_size_mm": list(size) if size else None,
        "resolution": list(res) if res else None,
        "pixel_area_um2": round(area, 3),
        "pixel_area_from": basis,
        "levels": levels,
        "rawspeed": (r.make, r.model) if r else None,
        "list_names": cam.aliases,
    }
    if profile:
        entry["bundled"] = profile.name
        entry["noise_kind"] = "measured" if profile.name in CALIBRATED else "estimated"
        src["noise"] = f"bundled profile {profile.name}: " + CALIBRATED.get(
            profile.name, "see its sources"
        )
    else:
        entry["noise_kind"] = "estimated"
    entry["source"] = src
    return entry


def _cfa(cam, make: str, r, rawspeed) -> tuple[str, str]:
    """(CFA, its source): rawspeed's, the maker's specification, an edition's base model's
    ("X-T1 Graphite Silver" is an X-T1), else assumed RGGB."""
    if r and r.cfa:
        return r.cfa, f"rawspeed:cameras:{r.line}"
    if (make, cam.model) in CFA_FROM_SPEC:
        return CFA_FROM_SPEC[(make, cam.model)]
    words = cam.model.split(" ")
    stems = keys_of(cam.make, [" ".join(words[:n]) for n in range(len(words) - 1, 0, -1)])
    base = next((rawspeed[k] for k in stems if k in rawspeed), None)
    if base and base.cfa and " " in cam.model:
        return base.cfa, f"rawspeed:cameras:{base.line} (its {base.model}, an edition of it)"
    return "RGGB", "assumed: RGGB (no table gives it; the raw file records it)"


def _size_class(entry: dict) -> int | None:
    size = entry.get("sensor_size_mm")
    return Sizes.size_class(size) if size else None


def _drop_shared_aliases(cameras: list[dict]) -> None:
    """Drop an alias that is another camera's model ("V-LUX (Typ 114)", LibRaw's name for
    the Panasonic DMC-FZ1000's Leica twin, stays the Leica's): a name finds one camera."""
    models = defaultdict(set)
    for c in cameras:
        models[(maker_key(c["make"]), norm(c["model"]))].add(c["name"])
        models[norm(c["model"])].add(c["name"])
    for c in cameras:
        c["aliases"] = [a for a in c["aliases"] if not (models.get(norm(a), set()) - {c["name"]})]


def _makers(cameras: list[dict], forms: dict) -> dict[str, list[str]]:
    """Each maker of the database → the Makes its cameras' files write (rawspeed's
    spellings: "NIKON CORPORATION", "RICOH IMAGING COMPANY, LTD." for Pentax)."""
    out = defaultdict(set)
    for c in cameras:
        form = forms.get(maker_key(c["make"]))
        out[c["make"]].update(form.every_make if form else ())
        out[c["make"]].update(make for make, _ in c["exif"])
    return {k: sorted(v - {k}) for k, v in sorted(out.items())}


def _compact(data: dict) -> str:
    head = {k: v for k, v in data.items() if k != "cameras"}
    lines = json.dumps(head, indent=1, ensure_ascii=False)[:-2]
    rows = ",\n".join("  " + json.dumps(c, ensure_ascii=False) for c in data["cameras"])
    return f'{lines},\n "cameras": [\n{rows}\n ]\n}}'


if __name__ == "__main__":
    main()
