"""Build rawsim's spectral data from the Academy's ``rawtoaces-data`` (release v1.1.0).

Run from the repository root with a snapshot of the repository as a git directory
(``fetch`` gives one; any clone works) and colour-science installed (for the CIE's
tabulated illuminants only)::

    python tools/spectra/build.py \\
        --rawtoaces-data /work/.mirror/AcademySoftwareFoundation+rawtoaces-data/repo

Writes two files; only figures are carried, each with its file, commit and licence:

- ``rawsim/cameras/spectra.json``: the measured RGB spectral sensitivities of the
  cameras of ``data/camera/`` (380–780 nm, 5 nm), each under the name the camera
  database (:mod:`rawsim.cameras`) files the camera under, found by its make and model
  or by the repository's own ``data/aliases.json``; every file's ``license`` is checked
  (Apache-2.0, or the build stops).
- ``rawsim/spectral/tables.json``: the CIE 1931 2° observer (``data/cmf``, CC-BY-4.0,
  resampled to 5 nm by taking every fifth nm), the 190 training reflectances and the
  ISO 7589 studio tungsten (``data/training``, ``data/illuminant``, Apache-2.0), and
  the CIE's tabulated S0, S1, S2 of the daylight series and fluorescents F2 and F11
  (CIE 15:2004 Tables T.2 and T.6, as colour-science 0.4 tabulates them).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from rawsim import cameras  # noqa: E402

GRID = list(range(380, 781, 5))
RELEASE = "v1.1.0"


def git(repo: Path, *args: str) -> str:
    """The output of ``git args`` in the git directory ``repo``."""
    run = subprocess.run(["git", f"--git-dir={repo}", *args], check=True, capture_output=True)
    return run.stdout.decode()


def git_json(repo: Path, path: str) -> dict:
    return json.loads(git(repo, "show", f"HEAD:{path}"))


def camera_files(repo: Path) -> list[str]:
    """The paths of the repository's camera files (``data/camera/*.json``)."""
    return git(repo, "ls-tree", "--name-only", "HEAD", "data/camera/").split()


def camera_file(repo: Path, path: str) -> dict:
    """A camera file of the repository, read; the build stops on any licence but
    Apache-2.0."""
    d = git_json(repo, path)
    licence = d["header"].get("license")
    if licence != "Apache-2.0":
        sys.exit(f"{path}: licence {licence!r}, not Apache-2.0: stopped")
    return d


def sig(x: float) -> float:
    return float(f"{x:.6g}")


def on_grid(main: dict, columns: int) -> list[list[float]]:
    """Columns of a spectral_data.data.main table on :data:`GRID` (one list per column)."""
    rows = [main[str(w)] for w in GRID]
    return [[sig(r[c]) for r in rows] for c in range(columns)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rawtoaces-data", type=Path, required=True)
    a = ap.parse_args()
    repo = a.rawtoaces_data
    commit = git(repo, "rev-parse", "HEAD").strip()
    files = camera_files(repo)
    aliases = git_json(repo, "data/aliases.json")["data"]["camera"]["model"]
    # the repository's own model → its other names ("EOS R5m2" → "EOS R5 Mark II")
    other = {}
    for names in aliases.values():
        for name, to in names.items():
            other.setdefault((to["make"], to["model"]), []).append(name)
    out, unmatched = {}, []
    for path in files:
        d = camera_file(repo, path)
        h = d["header"]
        make, model = h["manufacturer"], h["model"]
        cam = None
        for name in (model, *other.get((make, model), ())):
            cam = cameras.find(f"{make} {name}")
            if cam:
                break
        if cam is None:
            unmatched.append(f"{make} {model}")
            continue
        sd = d["spectral_data"]
        assert sd["index"]["main"] == ["R", "G", "B"], path
        out[cam.name] = {
            "file": path,
            "make": make,
            "model": model,
            "creator": h.get("document_creator"),
            "licence": h["license"],
            "rgb": on_grid(sd["data"]["main"], 3),
        }
    spectra = {
        "source": {
            "repository": "https://github.com/AcademySoftwareFoundation/rawtoaces-data",
            "release": RELEASE,
            "commit": commit,
            "licence": "Apache-2.0",
            "built_by": "tools/spectra/build.py",
        },
        "wavelengths_nm": GRID,
        "unmatched": unmatched,
        "cameras": dict(sorted(out.items())),
    }
    (ROOT / "rawsim/cameras/spectra.json").write_text(json.dumps(spectra, indent=1) + "\n")

    cmf = git_json(repo, "data/cmf/cmf_1931.json")
    training = git_json(repo, "data/training/training_spectral.json")
    tungsten = git_json(repo, "data/illuminant/iso7589_stutung_380_780_5.json")
    import colour  # the CIE's tables, as colour-science tabulates them

    basis = colour.colorimetry.SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES
    cie = lambda sd: [sig(sd[w]) for w in GRID]  # noqa: E731
    tables = {
        "wavelengths_nm": GRID,
        "cmf_1931": {
            "source": f"rawtoaces-data {RELEASE} ({commit}) data/cmf/cmf_1931.json, every "
            "fifth nm: CIE 2019, colour-matching functions of the CIE 1931 standard "
            "colorimetric observer, DOI 10.25039/CIE.DS.xvudnb9b",
            "licence": cmf["header"]["license"],
            "xyz": on_grid(cmf["spectral_data"]["data"]["main"], 3),
        },
        "training_190": {
            "source": f"rawtoaces-data {RELEASE} ({commit}) data/training/"
            "training_spectral.json: rawtoaces' 190 training patches (reflectances)",
            "licence": training["header"]["license"],
            "reflectance": on_grid(training["spectral_data"]["data"]["main"], 190),
        },
        "iso7589": {
            "source": f"rawtoaces-data {RELEASE} ({commit}) data/illuminant/"
            "iso7589_stutung_380_780_5.json: ISO 7589 studio tungsten, the Academy's variant",
            "licence": tungsten["header"]["license"],
            "power": on_grid(tungsten["spectral_data"]["data"]["main"], 1)[0],
        },
        "d_series_basis": {
            "source": "CIE 15:2004 Table T.2 (S0, S1, S2 of the daylight series), as "
            f"colour-science {colour.__version__} tabulates them",
            "s": [cie(basis[k]) for k in ("S0", "S1", "S2")],
        },
        "fluorescent": {
            "source": "CIE 15:2004 Table T.6 (F2, F11), as colour-science "
            f"{colour.__version__} tabulates them",
            **{k: cie(colour.SDS_ILLUMINANTS[f"FL{k[1:]}"]) for k in ("F2", "F11")},
        },
    }
    (ROOT / "rawsim/spectral").mkdir(exist_ok=True)
    (ROOT / "rawsim/spectral/tables.json").write_text(json.dumps(tables) + "\n")
    print(f"{len(out)} cameras matched; unmatched: {unmatched or 'none'}")


if __name__ == "__main__":
    main()
