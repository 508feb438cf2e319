"""The documentation builds, and every command and code block in it runs.

* ``mkdocs build --strict`` (mkdocs, mkdocs-material, mkdocstrings and mkdocs-click
  come with the ``test`` extra, so a missing one fails here rather than skips).
* Every ```` ```sh ````, ```` ```bash ````, ```` ```console ```` and ```` ```python ````
  block in README.md and docs/**/*.md is a test, named ``file:line``. The blocks of a
  page run in order in one workspace (a temporary folder with the repository's
  ``examples/`` and ``tests/data/`` linked in), as a reader
  following the page would run them; running one block alone first runs the
  page's earlier blocks. Shell blocks run under ``bash -euo pipefail`` with this
  interpreter's ``bin`` first on PATH (so ``rawsim`` and ``python`` are the ones
  under test); ``console`` blocks run their ``$ `` lines.
* Not run: install commands (``pip install``, ``apt-get``, ``rawsim compile``: a line
  or ``&&`` segment starting with one is dropped, and a block of nothing else is
  skipped), and blocks preceded by ``<!-- doc-test: skip REASON -->`` (a Slurm
  script, a real bucket or cluster, a long training run), each with its reason
  shown in the skip. Output examples are ```` ```text ````, configs
  ```` ```toml ```` / ```` ```json ````; those are not code.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
RUN = {"sh", "bash", "console", "python"}
SKIP = re.compile(r"<!--\s*doc-test:\s*skip\s+(.+?)\s*-->")
INSTALL = re.compile(r"^\s*((sudo\s+)?(pip3?|python3? -m pip|apt-get|apt)\s|rawsim compile\s*$)")
TIMEOUT = 240  # seconds per block: a cold machine compiles the engine's kernels once


@dataclass
class Block:
    page: Path
    line: int  # of the opening fence, from 1
    lang: str
    code: str
    skip: str | None

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"


def blocks(page: Path) -> list[Block]:
    """The fenced blocks of a page (top-level or indented, as in lists and admonitions)."""
    found, lines, i = [], page.read_text(encoding="utf-8").splitlines(), 0
    while i < len(lines):
        m = re.match(r"^(\s*)(`{3,})\s*([\w-]*)", lines[i])
        if not m:
            i += 1
            continue
        indent, fence, lang = m.groups()
        body, j = [], i + 1
        while j < len(lines) and not lines[j].strip().startswith(fence):
            body.append(lines[j][len(indent) :] if lines[j].startswith(indent) else lines[j])
            j += 1
        before = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        skip = SKIP.search(before)
        found.append(Block(page, i + 1, lang, "\n".join(body) + "\n", skip and skip.group(1)))
        i = j + 1
    return found


def shell_script(block: Block) -> str:
    """The block's commands, without its install commands."""
    text = block.code
    if block.lang == "console":
        cmds, cont = [], False
        for line in text.splitlines():
            if line.startswith("$ ") or cont:
                cmds.append(line[2:] if line.startswith("$ ") else line)
                cont = line.rstrip().endswith("\\")
        text = "\n".join(cmds)
    kept = []
    for command in re.sub(r"\\\n", "\x00", text).splitlines():
        parts = [p for p in command.split(" && ") if not INSTALL.match(p.replace("\x00", " "))]
        if parts:
            kept.append(" && ".join(parts).replace("\x00", "\\\n"))
    return "\n".join(kept).strip()


ALL = [b for page in PAGES for b in blocks(page) if b.lang in RUN]


def test_found_blocks():
    """The collection is not silently empty: the pages hold many runnable blocks."""
    assert len([b for b in ALL if b.skip is None]) >= 40
    ids = [b.id for b in ALL]
    assert len(ids) == len(set(ids))


@dataclass
class Workspace:
    path: Path
    done: set[str] = field(default_factory=set)


@pytest.fixture(scope="session")
def workspaces(tmp_path_factory):
    made: dict[Path, Workspace] = {}

    def get(page: Path) -> Workspace:
        if page not in made:
            path = tmp_path_factory.mktemp(page.stem)
            (path / "tests").mkdir()
            (path / "tests" / "data").symlink_to(REPO / "tests" / "data")
            for name in ("examples", "constraints.txt"):
                (path / name).symlink_to(REPO / name)
            made[page] = Workspace(path)
        return made[page]

    return get


def run_block(block: Block, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    for name in ("SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_JOB_ID"):
        env.pop(name, None)
    if block.lang == "python":
        script = cwd / f"block_{block.line}.py"
        script.write_text(block.code, encoding="utf-8")
        argv = [sys.executable, script.name]
    else:
        argv = ["bash", "-euo", "pipefail", "-c", shell_script(block)]
    return subprocess.run(
        argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT, check=False
    )


@pytest.mark.slow
@pytest.mark.parametrize("block", ALL, ids=[b.id for b in ALL])
def test_block_runs(block: Block, workspaces):
    if block.skip:
        pytest.skip(f"not run: {block.skip}")
    if block.lang != "python" and not shell_script(block):
        pytest.skip("not run: install commands only")
    space = workspaces(block.page)
    for earlier in blocks(block.page):
        if earlier.line >= block.line:
            break
        if earlier.lang in RUN and not earlier.skip and earlier.id not in space.done:
            if earlier.lang == "python" or shell_script(earlier):
                run_block(earlier, space.path)  # its own test reports how it went
                space.done.add(earlier.id)
    done = run_block(block, space.path)
    space.done.add(block.id)
    assert done.returncode == 0, (
        f"{block.id} exited {done.returncode}\n--- stdout\n{done.stdout[-3000:]}"
        f"\n--- stderr\n{done.stderr[-3000:]}"
    )


@pytest.mark.slow
def test_site_builds_strict(tmp_path):
    """The site builds without a warning; the CLI reference lists every command."""
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=REPO,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-5000:]
    from rawsim_cli.main import COMMANDS

    cli = (tmp_path / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    for name in [*COMMANDS, "isp-show", "isp-check", "profiles-list", "profiles-show"]:
        assert f'id="rawsim-{name}"' in cli, name
    api = (tmp_path / "reference" / "api" / "index.html").read_text(encoding="utf-8")
    for name in ("rawsim.api.unprocess", "rawsim.dataset.UnprocessDataset", "rawsim.cfa.CFA"):
        assert f'id="{name}"' in api, name


def test_readme_links_resolve():
    """The README's relative links point at files that exist (they work on GitHub)."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    for target in re.findall(r"\]\((?!https?:|#)([^)#\s]+)", text):
        assert (REPO / target).exists(), target
