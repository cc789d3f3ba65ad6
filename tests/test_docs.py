"""The README and ``docs/`` against the code: the two commands, links, code paths and the map of the house.

- The README opens with its two commands; the second is the test command ``.ci/run`` runs.
- Every relative link of ``README.md`` and ``docs/*.md`` reaches a file (and a heading, for ``#anchor``).
- Every repository path the text names in code (``geoloc/localize/query.py``, ``service/viewer/``) exists, a
  ``path.py: name`` names something that file defines, and so does a dotted ``geoloc.vision.features.NAME``.
- The README links every docs page, and every page links back to the README in its opening paragraph.
- ``docs/layout.md`` has a row for every package folder and lists every module (``__init__.py`` aside):
  when a module is added, split or moved, its line there must follow.
"""

from __future__ import annotations

import json
import re
from functools import cache
from pathlib import Path

import pytest

from geoloc.evaluation.suite.report import README_COMMAND, readme_table
from geoloc.evaluation.suite.worlds import load_suite

ROOT = Path(__file__).resolve().parents[1]
PAGES = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
PACKAGES = (
    "contracts",
    "client",
    "geoloc",
    "db",
    "workers",
    "service",
    "cli",
    "testbed",
    "benchmarks",
    "research",
    "tests",
)
FOLDERS = (*PACKAGES, "docker", "docs", ".ci")
"""Top-level folders whose paths the docs name; a token starting with one of them is checked."""
FENCE = re.compile(r"^```.*?^```", re.M | re.S)
PATH = re.compile(r"(?<![\w./=-])((?:" + "|".join(re.escape(f) for f in FOLDERS) + r")/[\w./-]*[\w/])")
PATH_NAME = re.compile(r"`((?:" + "|".join(PACKAGES) + r")/[\w/]+\.py): (\w+)")
DOTTED = re.compile(r"`((?:" + "|".join(PACKAGES) + r")(?:\.\w+){2,})`")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _page_id(page: Path) -> str:
    return str(page.relative_to(ROOT))


@cache
def _anchors(page: Path) -> frozenset[str]:
    """The GitHub anchors of a page's headings (lower case, punctuation dropped, spaces as hyphens)."""
    counts: dict[str, int] = {}
    anchors = set()
    for heading in re.findall(r"^#+ (.+)$", FENCE.sub("", page.read_text()), re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        anchors.add(f"{slug}-{counts[slug]}" if slug in counts else slug)
        counts[slug] = counts.get(slug, 0) + 1
    return frozenset(anchors)


def _defines(path: Path, name: str) -> bool:
    """Whether a module defines ``name`` at its top level or in a class (def, class or assignment)."""
    pattern = rf"^\s*(?:async def|def|class) {re.escape(name)}\b|^\s*{re.escape(name)}\s*[:=]"
    return path.is_file() and re.search(pattern, path.read_text(), re.M) is not None


def test_the_readme_opens_with_its_two_commands_and_ci_runs_the_second() -> None:
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"^```bash\n(.*?)\n```$", readme, re.M | re.S)
    head = readme.split("\n\n")
    assert head[0].startswith("# ") and head[1] == f"```bash\n{blocks[0]}\n```", "the first command must come first"
    assert head[2] == f"```bash\n{blocks[1]}\n```", "the test command must come second"
    assert blocks[0].startswith("python3.11 -m venv .venv && ") and "geoloc serve" in blocks[0]

    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    venv = next(line for line in ci if line.startswith("python3.11 -m venv"))
    command = next(line for line in ci if "pytest" in line and not line.startswith("#"))

    def steps(line: str) -> list[str]:
        return [" ".join(w for w in step.split() if w not in {"--quiet", "--clear"}) for step in line.split(" && ")]

    assert steps(blocks[1]) == steps(venv) + steps(command), "README's test command and .ci/run differ"


@pytest.mark.parametrize("page", PAGES, ids=_page_id)
def test_relative_links_reach_a_file_and_a_heading(page: Path) -> None:
    broken = []
    for target in LINK.findall(FENCE.sub("", page.read_text())):
        if re.match(r"[a-z]+:", target):
            continue
        file_part, _, anchor = target.partition("#")
        destination = (page.parent / file_part).resolve() if file_part else page
        if not destination.exists():
            broken.append(f"{target}: no such file")
        elif anchor and destination.suffix == ".md" and anchor not in _anchors(destination):
            broken.append(f"{target}: no heading #{anchor} in {destination.relative_to(ROOT)}")
    assert broken == []


@pytest.mark.parametrize("page", PAGES, ids=_page_id)
def test_code_paths_and_names_exist(page: Path) -> None:
    text = page.read_text()
    missing = sorted({path for path in PATH.findall(text) if not (ROOT / path).exists()})
    missing += [f"{path}: {name}" for path, name in PATH_NAME.findall(text) if not _defines(ROOT / path, name)]
    for dotted in DOTTED.findall(text):
        parts = dotted.split(".")
        for cut in range(len(parts), 0, -1):
            module = ROOT.joinpath(*parts[:cut])
            file = module / "__init__.py" if module.is_dir() else module.with_suffix(".py")
            if file.exists():
                break
        if cut == len(parts) or not _defines(file, parts[cut]):
            missing.append(dotted)
    assert missing == [], f"the docs name code that is not there (moved? renamed?): {missing}"


def test_the_readme_links_every_page_and_every_page_links_back() -> None:
    readme = (ROOT / "README.md").read_text()
    unlinked = [page.name for page in PAGES[1:] if f"](docs/{page.name})" not in readme]
    assert unlinked == []
    for page in PAGES[1:]:
        opening = page.read_text().split("\n\n")[1]
        assert "](../README.md)" in opening, f"{page.name}: the opening paragraph should link back to the README"


def _layout_modules() -> dict[str, set[str]]:
    """``docs/layout.md``'s module list: for each ``### `folder/``` section, the module paths it names."""
    text = (ROOT / "docs" / "layout.md").read_text().split("\n## Modules\n", 1)[1]
    listed: dict[str, set[str]] = {}
    for folder, body in re.findall(r"^### `([\w/]+/)`\n(.*?)(?=^### |\Z)", text, re.M | re.S):
        items = [line for line in body.splitlines() if line.startswith("- ")]
        listed[folder] = {name for line in items for name in re.findall(r"`([\w/]+\.py)`", line.split(": ")[0])}
    return listed


def test_the_layout_page_lists_every_folder_and_module() -> None:
    layout = (ROOT / "docs" / "layout.md").read_text()
    table = {row.split("|")[1].strip(" `") for row in layout.splitlines() if row.startswith("| `")}
    folders = {f"{p}/" for p in (*PACKAGES, "docker") if p != "geoloc"}
    folders |= {f"geoloc/{d.name}/" for d in (ROOT / "geoloc").iterdir() if (d / "__init__.py").exists()}
    assert folders - table == set(), "docs/layout.md's folder table lacks these"

    listed = _layout_modules()
    sections = sorted(listed, key=len, reverse=True)
    unlisted, gone = [], []
    for path in sorted(p.relative_to(ROOT).as_posix() for package in PACKAGES for p in (ROOT / package).rglob("*.py")):
        section = next((s for s in sections if path.startswith(s)), None)
        name = path[len(section) :] if section else path
        if name.endswith("__init__.py") or (section == "tests/" and name.rpartition("/")[2].startswith("test_")):
            continue
        if section is None or name not in listed[section]:
            unlisted.append(path)
    for section, names in listed.items():
        gone += [f"{section}{name}" for name in names if not (ROOT / section / name).exists()]
    assert unlisted == [], f"modules missing from docs/layout.md's list: {unlisted}"
    assert gone == [], f"docs/layout.md lists modules that are not there: {gone}"


ACCURACY_TABLE = re.compile(r"<!-- accuracy-table: [^\n]*-->\n(.*?)<!-- end of accuracy-table -->", re.S)


def test_the_readme_accuracy_table_is_the_test_splits_report() -> None:
    """The README's accuracy table is ``readme_table`` of ``docs/accuracy/test.json``, and its command is shown.

    The report is of the test split the suite declares (its worlds, seeds and centres), pooled only.
    """
    readme = (ROOT / "README.md").read_text()
    report = json.loads((ROOT / "docs" / "accuracy" / "test.json").read_text())
    match = ACCURACY_TABLE.search(readme)
    assert match, "README: no accuracy table between its markers"
    assert match.group(1).strip() == readme_table(report).strip(), "README's accuracy table differs from test.json"
    assert README_COMMAND in readme
    suite = load_suite()
    assert report["split"] == "test" and report["suite_version"] == suite.version
    declared = [(w.name, w.seed, list(w.centre_wgs84), w.capture, w.form) for w in suite.split("test")]
    assert [(w["name"], w["seed"], w["centre_wgs84"], w["capture"], w["form"]) for w in report["worlds"]] == declared
    assert not any(g.startswith("world:") for g in report["figures"])
