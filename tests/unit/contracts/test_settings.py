"""The one settings object: defaults, parsing, clear errors, the docs' table, and the entry points."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from contracts import settings as config
from contracts.keys import ApiKey
from contracts.settings import REPO_ROOT, Settings, SettingsError, get_settings, reset_settings, settings_table


def test_docs_settings_table_is_generated_from_the_settings_class() -> None:
    operations = (REPO_ROOT / "docs" / "operations.md").read_text()
    match = re.search(r"<!-- settings table: [^\n]*-->\n(.*?)\n<!-- end of settings table -->", operations, re.S)
    assert match, "docs/operations.md has no generated settings table"
    stale = "docs/operations.md's settings table is stale: paste `python -m contracts.settings`"
    assert match.group(1) == settings_table(), stale


def test_every_field_is_documented_with_a_description() -> None:
    for name, info in Settings.model_fields.items():
        assert info.description, f"Settings.{name} has no description (it becomes the row in docs/operations.md)"


def test_defaults_ignore_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GEOLOC_MAX_MAP_BYTES", "5")
    defaults = Settings.from_values()
    assert defaults.max_map_bytes == 256 * 1024 * 1024
    assert defaults.api_keys == {} and not defaults.auth_enabled
    assert defaults.shared == (REPO_ROOT.parent / "shared").resolve()
    assert defaults.database_path == defaults.data_dir / "geoloc.sqlite3"


def test_environment_is_parsed_once_and_reset_reads_it_again(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("GEOLOC_API_KEYS", " k1:read+write , k2:read,k3 ")
    monkeypatch.setenv("GEOLOC_WORKER_PLUGINS", "a.py, mod.handlers ,")
    monkeypatch.setenv("GEOLOC_JOB_LEASE_S", "1.5")
    monkeypatch.setenv("GEOLOC_MIN_IMAGE_SIDE", "")  # empty counts as unset
    reset_settings()
    settings = get_settings()
    assert settings.data_dir == (tmp_path / "data").resolve()
    assert settings.api_keys == {
        "k1": ApiKey(frozenset({"read", "write"})),
        "k2": ApiKey(frozenset({"read"})),
        "k3": ApiKey(frozenset({"read", "write"})),
    }
    assert settings.worker_plugins == ("a.py", "mod.handlers")
    assert settings.job_lease_s == 1.5 and settings.min_image_side == 64
    assert config.data_dir() == settings.data_dir and settings.data_dir.is_dir()

    monkeypatch.setenv("GEOLOC_JOB_LEASE_S", "7")
    assert get_settings().job_lease_s == 1.5, "cached until reset"
    reset_settings()
    assert get_settings().job_lease_s == 7.0


@pytest.mark.parametrize(
    ("variable", "value", "reason"),
    [
        ("GEOLOC_JOB_LEASE_S", "soon", "valid number"),
        ("GEOLOC_JOB_LEASE_S", "0.1", "greater than or equal to 0.5"),
        ("GEOLOC_MAX_IMAGE_BYTES", "-1", "greater than or equal to 0"),
        ("GEOLOC_JOB_MAX_ATTEMPTS", "0", "greater than or equal to 1"),
        ("GEOLOC_API_KEYS", "k1:admin", "bad entry 'k1:admin'"),
        ("GEOLOC_API_KEYS", "k1:read@team a", "tenant 'team a' must be 1 to 64 letters"),
    ],
)
def test_invalid_values_name_the_variable_and_the_rule(
    monkeypatch: pytest.MonkeyPatch, variable: str, value: str, reason: str
) -> None:
    monkeypatch.setenv(variable, value)
    reset_settings()
    with pytest.raises(SettingsError) as error:
        get_settings()
    assert f"{variable}={value!r}" in str(error.value) and reason in str(error.value)


GEOLOC_COMMAND = str(Path(sys.executable).parent / "geoloc")


@pytest.mark.parametrize(
    "command",
    [[GEOLOC_COMMAND, "worker"], [sys.executable, "-m", "workers"], [sys.executable, "-m", "service"]],
)
def test_entry_points_exit_2_on_an_invalid_setting(command: list[str], tmp_path: Path) -> None:
    env = {**os.environ, "GEOLOC_DATA_DIR": str(tmp_path), "GEOLOC_WORKER_GRACE_S": "-3"}
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=60, cwd=REPO_ROOT, check=False)
    assert result.returncode == 2, result.stderr
    assert "GEOLOC_WORKER_GRACE_S='-3'" in result.stderr
    assert "Traceback" not in result.stderr
