"""The licence table (:mod:`contracts.licenses`): real dependencies, real sources, the same as docs/licenses.md."""

from __future__ import annotations

import re
import tomllib
from importlib import metadata

from contracts.licenses import LICENSES, OSM_ATTRIBUTION, about_document, licenses_markdown, map_attribution
from contracts.settings import shared_path
from tests import REPO_ROOT


def _requirement_name(requirement: str) -> str:
    return re.split(r"[\[<>=!~; ]", requirement, maxsplit=1)[0].lower()


def test_every_listed_dependency_is_a_runtime_dependency_and_installed() -> None:
    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]
    declared = {_requirement_name(r) for r in project["dependencies"]}
    listed = [e.name for e in LICENSES if e.kind == "dependency"]
    assert listed and len(listed) == len(set(listed))
    assert set(listed) <= declared, sorted(set(listed) - declared)
    for name in listed:
        assert metadata.version(name)  # installed: its licence was read from its metadata


def test_the_models_data_sets_and_map_data_are_listed_with_their_stated_licences() -> None:
    by_name = {e.name.split(" (")[0]: e for e in LICENSES}
    assert by_name["ESPNetv2 segmentation weights"].license == "MIT"
    assert by_name["ALIKED keypoint weights"].license == "BSD-3-Clause"
    assert "CC BY-NC 4.0" in by_name["CamVid"].license
    assert "ODbL" in by_name["OpenStreetMap map data"].license
    assert {e.kind for e in LICENSES} == {"model", "dataset", "map data", "dependency"}
    sources = shared_path("models", "SOURCES.md")
    if sources.is_file():  # the commits named are those SOURCES.md gives
        text = sources.read_text()
        for entry in (e for e in LICENSES if e.kind == "model"):
            repo, commit = re.match(r"github\.com/([^@]+)@([0-9a-f]+)", entry.source).groups()  # type: ignore[union-attr]
            assert f"{repo}@{commit}" in text, entry


def test_docs_licenses_md_holds_the_table() -> None:
    page = (REPO_ROOT / "docs" / "licenses.md").read_text()
    table = page.split("<!-- licenses:start -->\n", 1)[1].split("<!-- licenses:end -->", 1)[0]
    assert table == licenses_markdown()
    assert "docs/licenses.md" in (REPO_ROOT / "README.md").read_text()


def test_a_map_without_a_stated_attribution_carries_openstreetmaps() -> None:
    assert OSM_ATTRIBUTION == "© OpenStreetMap contributors"
    assert map_attribution(None) == map_attribution("") == OSM_ATTRIBUTION
    assert map_attribution("© City of Helsinki, CC BY 4.0") == "© City of Helsinki, CC BY 4.0"
    document = about_document()
    assert document["map_attribution_default"] == OSM_ATTRIBUTION
    assert document["version"] == metadata.version("geoloc")
