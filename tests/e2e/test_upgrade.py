"""Upgrades: this checkout's service on a data folder that each released version (``releases.toml``) filled.

For every release: ``git archive`` of its tag (or, in a clone without tags, of the commit recorded beside it;
neither reachable fails with what to fetch), that release's service started from the archive (same venv, the
archive first on the import path and as the working folder) on a fresh data folder, filled through its API
(a map, references labelled by the method, a query answered), stopped; then this checkout's service on the same
folder, which migrates the schema forward, must serve every map, reference and answer as the old one did and
answer a new query. On both profiles: SQLite in the data folder, or one PostgreSQL database (and Redis broker)
that the old release's service fills and this checkout's migrates.
"""

from __future__ import annotations

import io
import subprocess
import tarfile
import tomllib
from pathlib import Path
from typing import Any

import pytest

from db import LATEST_VERSION, connect, schema_version
from tests.conftest import Profile
from tests.deployment_state import ask, fill, served_state
from tests.service_fixtures import REPO_ROOT, running_service

pytestmark = pytest.mark.slow  # two real services (an old release, this checkout) one after the other

RELEASES: list[dict[str, Any]] = tomllib.loads((REPO_ROOT / "releases.toml").read_text())["release"]


def _git(*args: str) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, timeout=60, check=False)


def release_tree(release: dict[str, Any]) -> str:
    """The tag if this clone has it, else the recorded commit; fails saying what to fetch when neither is here."""
    for ref in (f"refs/tags/{release['tag']}", release["commit"]):
        if _git("rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}").returncode == 0:
            return str(ref)
    pytest.fail(
        f"release {release['version']}: neither tag {release['tag']} nor commit {release['commit']} is in this "
        "clone; fetch them (git fetch --tags origin, or git fetch --unshallow for a shallow clone)"
    )


def _stored_version(database: Path | str) -> int:
    db = connect(database)
    try:
        return schema_version(db)
    finally:
        db.close()


@pytest.mark.parametrize("release", RELEASES, ids=[r["version"] for r in RELEASES])
def test_this_checkout_serves_what_a_release_stored(
    tmp_path: Path, built_models: Path, release: dict[str, Any], profile: Profile
) -> None:
    archive = _git("archive", "--format=tar", release_tree(release))
    assert archive.returncode == 0, archive.stderr.decode()
    old_code = tmp_path / f"geoloc-{release['version']}"
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(old_code, filter="data")
    data_dir = tmp_path / "data"
    deployment = {}  # the same database (and broker) for the old release and this checkout: empty, not migrated
    if profile.postgres is not None and profile.redis is not None:
        deployment = {
            "GEOLOC_DATABASE_URL": profile.postgres.new_empty_database(),
            "GEOLOC_BROKER_URL": profile.redis.new_url(),
        }
    database = deployment.get("GEOLOC_DATABASE_URL") or data_dir / "geoloc.sqlite3"
    old_env = {"PYTHONPATH": str(old_code), "GEOLOC_WORKER_PLUGINS": "", **deployment}  # no test plugins of ours
    with running_service(data_dir, models=built_models, cwd=old_code, **old_env) as old, old.client() as client:
        filled = fill(client)
        before = served_state(client, filled)
    assert _stored_version(database) == release["schema_version"], "the old release's schema"

    with running_service(data_dir, models=built_models, **deployment) as new, new.client() as client:
        after = served_state(client, filled)
        assert _stored_version(database) == LATEST_VERSION, "migrated forward"
        for kind in ("maps", "listed_references", "references", "queries"):
            assert len(after[kind]) == len(before[kind]), kind
            for old_row, new_row in zip(before[kind], after[kind], strict=True):
                kept = {key: new_row.get(key) for key in old_row}  # a newer release may add fields, not change them
                assert kept == old_row, (kind, old_row["id"])
        assert all(row["status"] == "done" for row in after["references"])
        assert ask(client, filled.map_id, seed=11)["result"]["locations"], "a new query answers"
