"""``geoloc doctor``: the report as lines or JSON, the exit codes, ``--repair`` on the settings' deployment."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from tests.conftest import Profile


def _old_file(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"left by a crash")
    stamp = time.time() - 3600
    os.utime(path, (stamp, stamp))


def test_doctor_reports_repairs_and_exits_by_what_is_left(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    data_dir = tmp_path / "data"
    Profile("embedded").new_deployment(data_dir)
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(data_dir))
    _old_file(data_dir / "images" / "1" / "orphan.jpg")
    runner = CliRunner()

    found = runner.invoke(app, ["doctor"])
    assert found.exit_code == 1, found.output
    assert "embedded profile: integrity ok; 1 stored files" in found.output
    assert "orphaned_file: images/1/orphan.jpg: no row names this stored file" in found.output
    assert "1 problems, 0 repaired (geoloc doctor --repair repairs what is safe)" in found.output
    assert (data_dir / "images" / "1" / "orphan.jpg").exists()

    repaired = runner.invoke(app, ["doctor", "--repair", "--json"])
    assert repaired.exit_code == 0, repaired.output
    report = json.loads(repaired.output)
    assert report["clean"] and report["repaired"] == 1 and report["counts"]["orphaned_file"] == 1
    assert report["findings"] == [
        {"check": "orphaned_file", "subject": "images/1/orphan.jpg", "problem": "no row names this stored file",
         "repair": "deleted"}
    ]  # fmt: skip
    assert not (data_dir / "images" / "1" / "orphan.jpg").exists()

    clean = runner.invoke(app, ["doctor"])
    assert clean.exit_code == 0 and clean.output.strip().endswith("clean: nothing to repair"), clean.output


def test_doctor_leaves_young_files_to_the_grace_period(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    data_dir = tmp_path / "data"
    Profile("embedded").new_deployment(data_dir)
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(data_dir))
    (data_dir / "tmp").mkdir()
    (data_dir / "tmp" / "upload-1.part").write_bytes(b"being received")
    assert CliRunner().invoke(app, ["doctor", "--repair"]).exit_code == 0
    assert (data_dir / "tmp" / "upload-1.part").exists()
    result = CliRunner().invoke(app, ["doctor", "--repair", "--grace-s", "0"])
    assert result.exit_code == 0 and "temp_file: tmp/upload-1.part" in result.output, result.output
    assert not (data_dir / "tmp" / "upload-1.part").exists()


def test_doctor_without_a_database_says_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path / "empty"))
    result = CliRunner().invoke(app, ["doctor"])
    assert result.exit_code == 2
    assert "error: no database at" in result.output and "Traceback" not in result.output
