"""``geoloc backup`` of a running service and ``geoloc restore`` into a fresh deployment, on both profiles.

A real service with a real worker, filled through its API (a map, references labelled by the method, a query
answered), backed up by the CLI while it runs and still takes a query; the backup is restored into a fresh data
folder (and, distributed, a fresh PostgreSQL database), a service started there serves the same maps,
references and answers, and answers the same query photo with the same pose.
"""

from __future__ import annotations

import json
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.conftest import Profile
from tests.deployment_state import ask, fill, served_state, top_pose
from tests.service_fixtures import REPO_ROOT, geoloc_command, running_service, service_env

pytestmark = pytest.mark.slow  # two real servers and workers, one after the other


def _geoloc(args: list[str], data_dir: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Run ``geoloc ARGS`` with the settings of the deployment in ``data_dir``."""
    return subprocess.run(
        [*geoloc_command(), *args],
        cwd=REPO_ROOT,
        env=service_env(data_dir, **env),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_a_running_service_backed_up_and_restored_serves_the_same_state(
    tmp_path: Path, built_models: Path, profile: Profile
) -> None:
    source_env, target_env = profile.new_env(), profile.new_env()
    backup = tmp_path / "backup"
    with running_service(tmp_path / "a", models=built_models, **source_env) as source, source.client() as client:
        filled = fill(client)
        before = served_state(client, filled)
        assert all(row["status"] == "done" for row in before["references"]), before["references"]
        with ThreadPoolExecutor(1) as pool:  # a query written while the backup runs
            during = pool.submit(ask, client, filled.map_id, 99)
            done = _geoloc(["backup", str(backup)], source.data_dir, source_env)
            assert during.result()["status"] == "done", "the service kept answering"
        assert done.returncode == 0, done.stderr
    manifest = json.loads((backup / "manifest.json").read_text())
    paths = [entry["path"] for entry in manifest["files"]]
    assert sum(p.startswith("store/images/") for p in paths) == 3 and any(p.startswith("store/maps/") for p in paths)
    assert any(p.startswith("store/queries/") for p in paths) and not any("cache/" in p for p in paths)

    done = _geoloc(["restore", str(backup)], tmp_path / "b", target_env)
    assert done.returncode == 0, done.stderr
    again = _geoloc(["restore", str(backup)], tmp_path / "b", target_env)
    assert again.returncode == 2 and "already holds data" in again.stderr and "--force" in again.stderr
    with running_service(tmp_path / "b", models=built_models, **target_env) as target, target.client() as client:
        after = served_state(client, filled)
        assert after == before
        reposted = ask(client, filled.map_id)
        assert reposted["id"] not in filled.query_ids, "a new query, not the restored one"
        assert top_pose(reposted) == top_pose(before["queries"][0])
