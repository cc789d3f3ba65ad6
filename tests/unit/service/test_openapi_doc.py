"""``openapi.json`` and ``openapi.md`` are generated from the app and must be current (the CI check)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from contracts.api import ERROR_CODES
from service.openapi_doc import DEFAULT_JSON, DEFAULT_MARKDOWN, main, openapi_spec, render_markdown
from tests import REPO_ROOT

SERVICE = REPO_ROOT / "service"


def test_openapi_files_are_current(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["--check"])
    assert code == 0, (
        f"openapi.json/openapi.md are out of date; run `python -m service.openapi_doc`.\n{capsys.readouterr().err}"
    )


def test_markdown_is_rendered_from_the_committed_json_alone() -> None:
    spec = json.loads(DEFAULT_JSON.read_text())
    assert render_markdown(spec) == DEFAULT_MARKDOWN.read_text()


def test_reference_shows_constraints_scopes_statuses_and_error_codes() -> None:
    text = render_markdown(openapi_spec())
    for expected in (
        "### POST /v1/maps/{map_id}/references",
        "### GET /v1/jobs/{job_id}",
        "Auth: `X-API-Key` with scope `write`.",
        "| `top_n` | integer | no | 1 – 50; default `10` | How many distinct locations to return |",
        "| `lat` | number | no | -90 – 90 | Prior position latitude (WGS84) |",
        "| `name` | string | yes | 1 – 200 characters; matches `\\S` | A name for the map (not blank) |",
        'one of `"queued"`, `"running"`, `"done"`, `"failed"`, `"cancelled"`',
        "| `409` Conflict | `not_ready` |",
        "| `422` Unprocessable Content | `outside_map` |",
        "| `202` | Not answered within wait_s: poll the query | [`QueryOut`](#queryout) |",
        '"error": {',
        "| `image` | file | yes | not empty |",
    ):
        assert expected in text, expected


def test_every_error_code_raised_in_the_service_is_documented() -> None:
    documented = {code for _, code in ERROR_CODES}
    raised = set()
    for path in SERVICE.glob("*.py"):
        source = path.read_text()
        raised |= set(re.findall(r'ApiError\(\s*\d{3},\s*"(\w+)"', source))
        raised |= set(re.findall(r'error_body\(\s*"(\w+)"', source))
    assert raised, "the pattern finds the service's error codes"
    assert raised <= documented, f"add to contracts.api.errors.ERROR_CODES: {sorted(raised - documented)}"


def test_check_reports_a_stale_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stale_md, stale_json = tmp_path / "openapi.md", tmp_path / "openapi.json"
    stale_md.write_text(DEFAULT_MARKDOWN.read_text().replace("GET /healthz", "GET /old-healthz"))
    stale_json.write_text(DEFAULT_JSON.read_text())
    paths = ["--output", str(stale_md), "--json", str(stale_json)]
    assert main(["--check", *paths]) == 1
    err = capsys.readouterr().err
    assert "out of date" in err and "python -m service.openapi_doc" in err and "-### GET /old-healthz" in err
    assert "openapi.json is out of date" not in err
    stale_json.write_text("{}")
    assert main(["--check", *paths]) == 1 and "openapi.json is out of date" in capsys.readouterr().err
    assert main(paths) == 0 and main(["--check", *paths]) == 0
