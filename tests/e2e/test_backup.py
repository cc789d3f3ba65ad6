"""``geoloc backup`` of a running service and ``geoloc restore`` into a fresh deployment, on both profiles.

A real service with a real worker, filled through its API (a map, references labelled by the method, a query
answered), backed up by the CLI while it runs and still takes a query; the backup is restored into a fresh data
folder (and, distributed, a fresh PostgreSQL database), a service started there serves the same maps,
references and answers, and answers the same query photo with the same pose. Under load (issue 22, embedded):
a backup taken while clients post queries and references restores the snapshot's answers byte for byte, and
a truncated or tampered copy of it is refused by ``geoloc restore`` with the reason, the target untouched.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3
import subprocess
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import pytest

from tests.conftest import Profile
from tests.deployment_state import QUERY_GPS, REFERENCE_GPS, ask, fill, served_state, top_pose
from tests.service_fixtures import REPO_ROOT, geoloc_command, jpeg_bytes, running_service, service_env, wait_for

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


def _post_until(client: httpx.Client, map_id: int, kind: str, stop: threading.Event) -> list[int]:
    """Post ``kind`` (``queries`` or ``references``) photos without waiting, every 0.3 s until ``stop``; the ids.

    A full queue (``429``) is waited out, as a client does; any other answer but ``202`` fails the test.
    """
    ids: list[int] = []
    while not stop.is_set():
        seed = (100 if kind == "queries" else 200) + len(ids)
        gps = QUERY_GPS if kind == "queries" else REFERENCE_GPS[len(ids) % len(REFERENCE_GPS)]
        image = {"image": (f"{kind}{seed}.jpg", jpeg_bytes(gps=gps, seed=seed))}
        response = client.post(f"/v1/maps/{map_id}/{kind}", files=image, data={"wait_s": "0"})
        assert response.status_code in (202, 429), response.text
        if response.status_code == 202:
            ids.append(int(response.json()["id"]))
        stop.wait(0.3 if response.status_code == 202 else 1.0)
    return ids


def _answers(database: Path) -> dict[int, str]:
    """The stored answer (the ``result`` JSON as written, ranked poses first) of every done query, by id."""
    with sqlite3.connect(database) as db:
        rows = db.execute("SELECT id, result FROM queries WHERE status = 'done' ORDER BY id").fetchall()
    return {int(qid): str(result) for qid, result in rows}


def _digests(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder`` (what a refused restore must leave as it was)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


def test_a_backup_under_queries_and_ingest_restores_the_same_answers_and_a_bad_copy_is_refused(
    tmp_path: Path, built_models: Path
) -> None:
    backup = tmp_path / "backup"
    with running_service(tmp_path / "a", models=built_models, workers=2) as source, source.client() as client:
        filled = fill(client)
        stop = threading.Event()
        with ThreadPoolExecutor(2) as pool, httpx.Client(base_url=client.base_url, headers=client.headers) as other:
            posting = [pool.submit(_post_until, c, filled.map_id, kind, stop)
                       for c, kind in ((client, "queries"), (other, "references"))]  # fmt: skip
            wait_for(lambda: _answers(source.data_dir / "geoloc.sqlite3").keys() - set(filled.query_ids), timeout=60,
                     interval=0.2, what="a query posted by the load to be answered")  # fmt: skip
            done = _geoloc(["backup", str(backup)], source.data_dir, {})
            running = [not f.done() for f in posting]
            stop.set()
            queries, references = (f.result() for f in posting)
        assert done.returncode == 0, done.stderr
        assert all(running), "the load ran for the whole backup"

        def settled() -> bool:
            rows = [client.get(f"/v1/queries/{q}").json()["status"] for q in queries]
            return all(status in ("done", "failed") for status in rows)

        wait_for(settled, timeout=180, interval=0.5, what="the load's queries to be answered")
        source_answers = _answers(source.data_dir / "geoloc.sqlite3")
        served = {q: client.get(f"/v1/queries/{q}").json()["result"]["locations"] for q in source_answers}

    target = tmp_path / "b"
    done = _geoloc(["restore", str(backup)], target, {})
    assert done.returncode == 0, done.stderr
    restored = _answers(target / "geoloc.sqlite3")
    snapshot_load = restored.keys() & set(queries)
    assert filled.query_ids[0] in restored and snapshot_load, "the snapshot holds answers of the load"
    assert restored == {q: source_answers[q] for q in restored}, "the snapshot's answers, byte for byte"
    with sqlite3.connect(target / "geoloc.sqlite3") as db:
        assert db.execute(
            "SELECT COUNT(*) FROM reference_images WHERE id > ?", (max(filled.reference_ids),)
        ).fetchone()[0]

    for damage in ("truncated", "tampered"):
        bad = tmp_path / f"backup-{damage}"
        shutil.copytree(backup, bad)
        manifest = json.loads((bad / "manifest.json").read_text())
        if damage == "truncated":  # the database snapshot cut in half
            name = manifest["database"]
            (bad / name).write_bytes((bad / name).read_bytes()[: (bad / name).stat().st_size // 2])
        else:  # one byte of a stored photo flipped, its size kept
            name = next(e["path"] for e in manifest["files"] if e["path"].startswith("store/images/"))
            data = bytearray((bad / name).read_bytes())
            data[len(data) // 2] ^= 0xFF
            (bad / name).write_bytes(bytes(data))
        before = _digests(target)
        for args, into in ((["--force"], target), ([], tmp_path / f"fresh-{damage}")):
            refused = _geoloc(["restore", str(bad), *args], into, {})
            assert refused.returncode == 2, (damage, refused.stdout, refused.stderr)
            assert f"the backup is corrupt: {name} does not match its checksum in manifest.json" in refused.stderr
            assert "Traceback" not in refused.stderr
        assert _digests(target) == before, f"a {damage} backup, even with --force, overwrote nothing"
        assert not (tmp_path / f"fresh-{damage}" / "geoloc.sqlite3").exists()

    with running_service(target, models=built_models) as restored_service, restored_service.client() as client:
        for q in sorted(restored):
            assert client.get(f"/v1/queries/{q}").json()["result"]["locations"] == served[q], q
