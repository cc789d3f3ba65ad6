"""``openapi.md`` is generated from the app and must be current (this is the CI check)."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.openapi_doc import DEFAULT_OUTPUT, main, render_markdown


def test_openapi_md_is_current(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["--check"])
    assert code == 0, f"openapi.md is out of date; run `python -m service.openapi_doc`.\n{capsys.readouterr().err}"


def test_rendering_is_deterministic_and_covers_the_api() -> None:
    text = render_markdown()
    assert text == render_markdown()
    for expected in (
        "### POST /v1/maps/{map_id}/references",
        "### GET /v1/jobs/{job_id}",
        "Auth: `X-API-Key` with scope `write`.",
        "`outside_map`",
        '"error": {',
        "| `image` | file | yes |",
    ):
        assert expected in text, expected


def test_check_reports_a_stale_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stale = tmp_path / "openapi.md"
    stale.write_text(DEFAULT_OUTPUT.read_text().replace("GET /healthz", "GET /old-healthz"))
    assert main(["--check", "--output", str(stale)]) == 1
    err = capsys.readouterr().err
    assert "out of date" in err and "python -m service.openapi_doc" in err and "-### GET /old-healthz" in err
    assert main(["--output", str(stale)]) == 0 and main(["--check", "--output", str(stale)]) == 0
