"""Database outages against real servers and processes (issue 51, item 1).

PostgreSQL stopped for 20 s mid-ingest while uploads, queries and reads go on: every request answers within
10 s, with success or ``503`` ``database_unavailable`` and ``Retry-After`` (never a 500), ``/readyz`` says not
ready, and once PostgreSQL is back every reference ends ``done`` exactly once with the outcome of a reference
labelled before the outage. On the embedded profile, SQLite's write lock held past the lock timeout: uploads are
``503`` within the bound, reads go on, and everything is stored once the lock is released.

Labelling is the quick stand-in of ``tests/fault_plugin.py`` (a sleep, then the real single-transaction write);
the job machinery, the API and the servers are the real ones.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from testbed.servers import PostgresServer, RedisServer
from tests import TESTS_DIR
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    jpeg_bytes,
    read_rows,
    running_service,
    upload_hall_map,
    wait_for,
)

pytestmark = pytest.mark.slow

PLUGIN = TESTS_DIR / "fault_plugin.py"
OUTAGE_S = 20.0
BOUND_S = 10.0
"""Every request during the outage must be answered within this long."""
OUTCOME_FIELDS = ("status", "estimated_heading_deg", "error", "placement", "map_id")


@dataclass
class Answer:
    """One request made while the database went away and came back."""

    what: str
    status: int
    elapsed_s: float
    code: str | None
    retry_after: str | None
    body: dict[str, Any]


def _upload(client: httpx.Client, map_id: int, seed: int) -> httpx.Response:
    files = {"image": (f"{seed}.jpg", jpeg_bytes(seed=seed))}
    return client.post(f"/v1/maps/{map_id}/references", files=files, data=INSIDE_ONE_BUILDING)


def _timed(client: httpx.Client, what: str, method: str, url: str, **kwargs: Any) -> Answer:
    started = time.monotonic()
    try:
        response = client.request(method, url, **kwargs)
    except httpx.TimeoutException:
        return Answer(what, 0, time.monotonic() - started, "client timeout", None, {})
    elapsed = time.monotonic() - started
    body = response.json() if response.headers.get("content-type", "").startswith("application/json") else {}
    error = body.get("error") if isinstance(body, dict) else None
    code = error.get("code") if isinstance(error, dict) else None
    return Answer(what, response.status_code, elapsed, code, response.headers.get("retry-after"), body)


class Traffic:
    """Reads, reference uploads and queries in a loop on two threads until :meth:`stop`."""

    def __init__(self, client: httpx.Client, map_id: int, reference_id: int) -> None:
        self.client, self.map_id, self.reference_id = client, map_id, reference_id
        self.answers: list[Answer] = []
        self.uploaded: dict[int, Answer] = {}
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._threads = [threading.Thread(target=self._reads), threading.Thread(target=self._writes)]

    def __enter__(self) -> Traffic:
        for thread in self._threads:
            thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=60)

    def _keep(self, answer: Answer) -> None:
        with self._lock:
            self.answers.append(answer)

    def _reads(self) -> None:
        reads = (
            ("map", f"/v1/maps/{self.map_id}"),
            ("references", f"/v1/maps/{self.map_id}/references"),
            ("reference", f"/v1/references/{self.reference_id}"),
            ("maps", "/v1/maps"),
        )
        while not self._stop.is_set():
            for what, url in reads:
                self._keep(_timed(self.client, what, "GET", url))
            self._stop.wait(0.2)

    def _writes(self) -> None:
        seed = 100
        while not self._stop.is_set():
            files = {"image": (f"{seed}.jpg", jpeg_bytes(seed=seed))}
            answer = _timed(
                self.client,
                "upload",
                "POST",
                f"/v1/maps/{self.map_id}/references",
                files=files,
                data=INSIDE_ONE_BUILDING,
            )
            self._keep(answer)
            self.uploaded[seed] = answer
            query = {"image": ("q.jpg", jpeg_bytes(seed=seed + 5000))}
            self._keep(
                _timed(
                    self.client, "query", "POST", f"/v1/maps/{self.map_id}/queries", files=query, data={"wait_s": "0"}
                )
            )
            seed += 1
            self._stop.wait(0.5)


def _check_answers(answers: list[Answer]) -> None:
    """Every answer a success or a 503 ``database_unavailable`` with ``Retry-After``, all within the bound."""
    assert answers, "no request was made"
    slow = [a for a in answers if a.elapsed_s > BOUND_S or a.status == 0]
    assert not slow, f"requests past {BOUND_S:.0f} s: {[(a.what, a.status, round(a.elapsed_s, 1)) for a in slow]}"
    wrong = [a for a in answers if a.status not in (200, 201, 202, 503)]
    assert not wrong, [(a.what, a.status, a.code, a.body) for a in wrong]
    unavailable = [a for a in answers if a.status == 503 and a.what != "readyz"]
    assert all(a.code == "database_unavailable" and a.retry_after for a in unavailable), unavailable[:3]
    assert all("/" not in str(a.body["error"]["message"]) for a in unavailable)


def _outcome(reference: dict[str, Any]) -> dict[str, Any]:
    return {field: reference.get(field) for field in OUTCOME_FIELDS}


@pytest.fixture
def private_postgres() -> Iterator[PostgresServer]:
    """A PostgreSQL cluster of this test alone: stopping it touches no other test's deployment."""
    server = PostgresServer().start()
    try:
        yield server
    finally:
        server.stop()


def test_postgres_stopped_mid_ingest_answers_503_and_loses_nothing(
    tmp_path: Path, built_models: Path, private_postgres: PostgresServer
) -> None:
    redis = RedisServer().start()
    env = {
        "GEOLOC_DATABASE_URL": private_postgres.new_database(),
        "GEOLOC_BROKER_URL": redis.new_url(),
        "GEOLOC_WORKER_PLUGINS": str(PLUGIN),
        "GEOLOC_TEST_LABEL_LOG": str(tmp_path / "labels.log"),
        "GEOLOC_TEST_LABEL_S": "1.0",
        "GEOLOC_JOB_LEASE_S": "10",
        "GEOLOC_DATABASE_TIMEOUT_S": "2",
        "GEOLOC_DATABASE_LOCK_TIMEOUT_S": "5",
        "GEOLOC_RATE_LIMIT_PER_MIN": "100000",
        "GEOLOC_MAX_QUEUED_JOBS": "1000",
    }
    try:
        with (
            running_service(tmp_path / "data", workers=2, models=built_models, **env) as service,
            service.client(timeout=30.0) as client,
        ):
            map_id = upload_hall_map(client)
            first = int(_upload(client, map_id, 0).json()["id"])
            wait_for(lambda: client.get(f"/v1/references/{first}").json()["status"] == "done", 60, what="a first label")
            baseline = _outcome(client.get(f"/v1/references/{first}").json())
            ids = [first] + [int(_upload(client, map_id, seed).json()["id"]) for seed in range(1, 7)]
            wait_for(
                lambda: read_rows(service.database, "SELECT id FROM jobs WHERE status = 'running'"), 30, what="a job"
            )
            with Traffic(client, map_id, first) as traffic:
                time.sleep(1.0)
                private_postgres.halt()  # mid-ingest: jobs are running, more are queued
                halted = time.monotonic()
                time.sleep(3.0)
                ready = _timed(client, "readyz", "GET", "/readyz")
                time.sleep(max(OUTAGE_S - (time.monotonic() - halted), 0.0))
                private_postgres.resume()
                time.sleep(4.0)
            _check_answers([*traffic.answers, ready])
            assert ready.status == 503 and "database unreachable" in json.dumps(ready.body), ready.body
            outage = [a for a in traffic.answers if a.status == 503]
            assert len(outage) >= 5, "the outage was not seen"
            assert sum(a.status == 503 and a.what != "query" for a in traffic.answers) >= 3
            for seed, answer in traffic.uploaded.items():  # a client retries what was refused
                if answer.status == 503:
                    retried = _upload(client, map_id, seed)
                    assert retried.status_code in (200, 202), retried.text
                    ids.append(int(retried.json()["id"]))
                else:
                    ids.append(int(answer.body["id"]))
            wait_for(
                lambda: client.get(f"/v1/maps/{map_id}/references").json()["counts"].get("done") == len(set(ids)),
                timeout=120,
                what=lambda: f"{len(set(ids))} references done\n{service.log_tail(60)}",
            )
            assert client.get("/readyz").status_code == 200
            outcomes = [_outcome(client.get(f"/v1/references/{i}").json()) for i in sorted(set(ids))]
        assert all(outcome == baseline for outcome in outcomes), [o for o in outcomes if o != baseline][:3]
        references = read_rows(service.database, "SELECT id, job_id FROM reference_images ORDER BY id")
        assert [r["id"] for r in references] == sorted(set(ids)), "no reference lost or stored twice"
        jobs = read_rows(service.database, "SELECT * FROM jobs WHERE kind = 'label_reference' ORDER BY reference_id")
        assert [j["reference_id"] for j in jobs] == [r["id"] for r in references], "one job per reference"
        assert all(j["status"] == "done" for j in jobs), [(j["id"], j["status"], j["error"]) for j in jobs]
        labelled = (tmp_path / "labels.log").read_text().split("\n")
        assert {int(line.split()[0]) for line in labelled if line} == set(ids)
        queries = read_rows(service.database, "SELECT q.id, j.status FROM queries q JOIN jobs j ON j.id = q.job_id")
        assert queries and all(q["status"] in ("done", "failed", "queued", "running") for q in queries)
    finally:
        redis.close()


def test_sqlite_locked_past_the_lock_timeout_answers_503_then_stores(tmp_path: Path, built_models: Path) -> None:
    env = {
        "GEOLOC_WORKER_PLUGINS": str(PLUGIN),
        "GEOLOC_TEST_LABEL_LOG": str(tmp_path / "labels.log"),
        "GEOLOC_TEST_LABEL_S": "0.2",
        "GEOLOC_DATABASE_LOCK_TIMEOUT_S": "1",
    }
    with (
        running_service(tmp_path / "data", workers=1, models=built_models, **env) as service,
        service.client(timeout=30.0) as client,
    ):
        map_id = upload_hall_map(client)
        first = int(_upload(client, map_id, 0).json()["id"])
        holder = sqlite3.connect(str(service.database), isolation_level=None)
        holder.execute("BEGIN IMMEDIATE")  # another process holds the write lock
        try:
            refused = _timed(
                client,
                "upload",
                "POST",
                f"/v1/maps/{map_id}/references",
                files={"image": ("1.jpg", jpeg_bytes(seed=1))},
                data=INSIDE_ONE_BUILDING,
            )
            read = _timed(client, "reference", "GET", f"/v1/references/{first}")
        finally:
            holder.execute("ROLLBACK")
            holder.close()
        _check_answers([refused, read])
        assert refused.status == 503 and refused.elapsed_s < 5.0, refused
        assert read.status == 200
        assert [r["id"] for r in read_rows(service.database, "SELECT id FROM reference_images")] == [first]
        second = int(_upload(client, map_id, 1).json()["id"])
        wait_for(
            lambda: client.get(f"/v1/maps/{map_id}/references").json()["counts"].get("done") == 2,
            timeout=60,
            what=lambda: service.log_tail(40),
        )
        assert second != first
