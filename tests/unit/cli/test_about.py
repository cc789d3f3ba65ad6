"""``geoloc about``: the version and the licence table, the same document as ``GET /v1/about``."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from cli.main import app
from contracts.licenses import LICENSES, about_document


def test_about_prints_every_licence() -> None:
    result = CliRunner().invoke(app, ["about"])
    assert result.exit_code == 0, result.output
    assert "© OpenStreetMap contributors" in result.output
    for entry in LICENSES:
        assert f"{entry.name}: {entry.license}" in result.output


def test_about_json_is_the_api_document() -> None:
    result = CliRunner().invoke(app, ["about", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output) == about_document()
