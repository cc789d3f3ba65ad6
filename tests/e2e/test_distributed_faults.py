"""Faults in the distributed profile (PostgreSQL, Celery on Redis), with real servers and processes.

A worker SIGKILLed mid-job, Redis restarted (every message lost) mid-ingest while uploads go on, Redis killed
while a message waits for the worker's busy process (its acknowledgement fails), an API process killed and
restarted by its supervisor, and two API processes receiving the same photo at once: after each, every reference
ends ``done`` exactly once (one row, one job, done) and no job is lost.

Labelling is the quick stand-in of ``tests/fault_plugin.py`` (a sleep, then the same single-transaction
write); the job machinery is the real one. Each test has its own Redis, so restarting it touches nothing else.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import pytest

from testbed.servers import PostgresServer, RedisServer
from tests import TESTS_DIR
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    RunningProcess,
    jpeg_bytes,
    read_rows,
    running_service,
    running_workers,
    upload_hall_map,
    wait_for,
)
from workers.celery_worker import CONSUMER_STALL_S

pytestmark = pytest.mark.slow

PLUGIN = TESTS_DIR / "fault_plugin.py"


@pytest.fixture
def deployment(postgres_server: PostgresServer, tmp_path: Path) -> Iterator[tuple[dict[str, str], RedisServer]]:
    """Settings of a fresh distributed deployment (its own database and Redis) and that Redis."""
    redis = RedisServer().start()
    env = {
        "GEOLOC_DATABASE_URL": postgres_server.new_database(),
        "GEOLOC_BROKER_URL": redis.new_url(),
        "GEOLOC_WORKER_PLUGINS": str(PLUGIN),
        "GEOLOC_TEST_LABEL_LOG": str(tmp_path / "labels.log"),
        "GEOLOC_TEST_LABEL_S": "1.0",
        "GEOLOC_RATE_LIMIT_PER_MIN": "100000",
    }
    try:
        yield env, redis
    finally:
        redis.close()


def _upload(client: httpx.Client, map_id: int, seed: int) -> httpx.Response:
    photo = jpeg_bytes(seed=seed)
    return client.post(
        f"/v1/maps/{map_id}/references", files={"image": (f"{seed}.jpg", photo)}, data=INSIDE_ONE_BUILDING
    )


def _accepted(response: httpx.Response) -> int:
    assert response.status_code in (200, 202), response.text
    return int(response.json()["id"])


def _all_done(client: httpx.Client, map_id: int, count: int) -> bool:
    counts = client.get(f"/v1/maps/{map_id}/references").json()["counts"]
    return bool(counts["done"] == count)


def _assert_each_done_exactly_once(database: str, reference_ids: list[int]) -> list[dict[str, Any]]:
    """One row and one finished job per reference, all ``done``; returns the jobs."""
    references = read_rows(database, "SELECT id, status, job_id FROM reference_images ORDER BY id")
    assert [r["id"] for r in references] == sorted(set(reference_ids)), "no reference lost or stored twice"
    assert all(r["status"] == "done" for r in references), references
    jobs = read_rows(database, "SELECT * FROM jobs WHERE kind = 'label_reference' ORDER BY reference_id")
    assert [j["reference_id"] for j in jobs] == [r["id"] for r in references], "one job per reference"
    assert all(j["status"] == "done" for j in jobs), [(j["id"], j["status"], j["error"]) for j in jobs]
    assert [r["job_id"] for r in references] == [j["id"] for j in jobs]
    return jobs


def _healthy(client: httpx.Client) -> bool:
    try:
        return client.get("/healthz").status_code == 200
    except httpx.HTTPError:
        return False


def _job_states(database: str) -> list[tuple[Any, ...]]:
    """(id, status, attempts, published) of every job, for failure messages."""
    rows = read_rows(database, "SELECT id, status, attempts, published_at FROM jobs ORDER BY id")
    return [(r["id"], r["status"], r["attempts"], r["published_at"] is not None) for r in rows]


def _api_child_pid(service: RunningProcess) -> int | None:
    """The API process (``python -m service``) under a ``geoloc serve`` supervisor (None while it is restarted).

    Its other children are workers (the test services' map-only worker: maps are parsed by jobs).
    """
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) != service.process.pid:  # the field after the state is the parent's pid
                continue
            argv = (stat.parent / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:
            continue
        if "service" in argv:
            children.append(int(stat.parent.name))
    assert len(children) <= 1, children
    return children[0] if children else None


def test_worker_killed_and_redis_restarted_mid_ingest_lose_nothing(
    tmp_path: Path, built_models: Path, deployment: tuple[dict[str, str], RedisServer]
) -> None:
    env, redis = deployment
    with (
        running_service(tmp_path / "data", workers=2, models=built_models, GEOLOC_JOB_LEASE_S="2", **env) as service,
        service.client() as client,
    ):
        map_id = upload_hall_map(client)
        ids = [_accepted(_upload(client, map_id, seed)) for seed in range(8)]

        def running_job() -> dict[str, Any] | None:
            rows = read_rows(service.database, "SELECT * FROM jobs WHERE status = 'running'")
            return rows[0] if rows else None

        victim_job = wait_for(running_job, timeout=60, what=lambda: f"a job to run\n{service.log_tail()}")
        os.kill(int(victim_job["lease_owner"].split(":")[1]), signal.SIGKILL)  # a Celery pool process, mid-job

        redis.stop()  # every message in the broker is lost; uploads go on meanwhile (published later)
        ids += [_accepted(_upload(client, map_id, seed)) for seed in range(8, 12)]
        unpublished = read_rows(service.database, "SELECT id FROM jobs WHERE published_at IS NULL")
        assert len(unpublished) >= 4, "the API could not publish while the broker was down"
        time.sleep(1.0)
        redis.start()
        ids += [_accepted(_upload(client, map_id, seed)) for seed in range(12, 14)]

        wait_for(
            lambda: _all_done(client, map_id, len(ids)),
            timeout=120,
            what=lambda: f"{len(ids)} references done: {_job_states(service.database)}\n{service.log_tail(80)}",
        )
    jobs = _assert_each_done_exactly_once(service.database, ids)
    killed = next(j for j in jobs if j["id"] == victim_job["id"])
    assert killed["attempts"] == 2 and killed["lease_owner"] != victim_job["lease_owner"], "taken again after its lease"


def test_an_acknowledgement_lost_with_redis_does_not_stall_the_consumer(
    tmp_path: Path, built_models: Path, deployment: tuple[dict[str, str], RedisServer]
) -> None:
    """An acknowledgement that fails with Redis down does not leave the consumer stuck (workers/redis_transport.py).

    Redis is killed while a message waits in the worker for its one busy process; the message's early
    acknowledgement fails once the process takes it. The consumer takes new messages once Redis is back, well
    before its watchdog would restart it (``CONSUMER_STALL_S``), and the worker is the same process throughout.
    """
    env, redis = deployment
    with (
        running_service(tmp_path / "data", workers=1, models=built_models, **{**env, "GEOLOC_TEST_LABEL_S": "3.0"})
        as service,
        service.client() as client,
    ):  # fmt: skip
        map_id = upload_hall_map(client)
        celery = [p for p in _children(service) if "workers.celery_worker" in p[1]]
        ids = [_accepted(_upload(client, map_id, seed)) for seed in range(3)]
        wait_for(lambda: read_rows(service.database, "SELECT id FROM jobs WHERE status = 'running'"), 30, what="a job")
        time.sleep(0.5)  # the next message is taken meanwhile, and waits for the busy process
        redis.stop()
        time.sleep(4.0)  # the running job ends, the process takes the waiting message: its acknowledgement fails
        redis.start()
        back = time.monotonic()
        ids += [_accepted(_upload(client, map_id, seed)) for seed in range(3, 5)]
        wait_for(
            lambda: _all_done(client, map_id, len(ids)),
            timeout=CONSUMER_STALL_S,
            what=lambda: f"{len(ids)} references done: {_job_states(service.database)}\n{service.log_tail(80)}",
        )
        assert time.monotonic() - back < CONSUMER_STALL_S
        assert [p for p in _children(service) if "workers.celery_worker" in p[1]] == celery, "the worker restarted"
        log = service.log_path.read_text(errors="replace")
        assert "Couldn't ack" in log, "the fault did not happen: no acknowledgement failed"
        assert "consumer stalled" not in log
    _assert_each_done_exactly_once(service.database, ids)


def _children(service: RunningProcess) -> list[tuple[int, str]]:
    """(pid, command line) of the supervisor's direct children."""
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) != service.process.pid:
                continue
            children.append((int(stat.parent.name), (stat.parent / "cmdline").read_bytes().decode(errors="replace")))
        except (OSError, ValueError):
            continue
    return sorted(children)


def test_two_api_processes_same_photo_at_once_and_an_api_restart(
    tmp_path: Path, built_models: Path, deployment: tuple[dict[str, str], RedisServer]
) -> None:
    env, _ = deployment
    data_dir = tmp_path / "data"  # the shared file store of this deployment
    with (
        running_service(data_dir, workers=0, **env) as first,
        running_service(data_dir, workers=0, **env) as second,
        running_workers(data_dir, concurrency=1, models=built_models, **env) as workers,
        first.client() as one,
        second.client() as other,
        ThreadPoolExecutor(2) as pool,
    ):
        map_id = upload_hall_map(one)
        ids: list[int] = []
        for seed in range(6):  # the same photo through both API processes at the same moment
            answers = list(pool.map(lambda client, s=seed: _upload(client, map_id, s), (one, other)))
            assert sorted(a.status_code for a in answers) == [200, 202], [a.text for a in answers]
            assert (
                len({_accepted(a) for a in answers}) == 1 and answers[0].json()["sha256"] == answers[1].json()["sha256"]
            )
            ids.append(_accepted(answers[0]))

        victim = _api_child_pid(first)
        assert victim is not None
        os.kill(victim, signal.SIGKILL)  # the first API process dies; its supervisor starts another
        ids += [_accepted(_upload(other, map_id, seed)) for seed in range(6, 8)]
        wait_for(
            lambda: _api_child_pid(first) not in (None, victim) and _healthy(one),
            timeout=60,
            what="the first API process to be restarted",
        )
        ids += [_accepted(_upload(one, map_id, seed)) for seed in range(8, 10)]
        ids += [_accepted(_upload(one, map_id, seed)) for seed in range(4)]  # already there: nothing new
        wait_for(
            lambda: _all_done(other, map_id, 10),
            timeout=180,
            what=lambda: f"10 references done\n{workers.log_tail(80)}",
        )
        ready = one.get("/readyz").json()
        # the worker process; not the map-only worker each API service starts (tests.service_fixtures, workers=0)
        assert ready["profile"] == "distributed" and ready["broker"] == "ok" and ready["live_workers"] == 1
    _assert_each_done_exactly_once(first.database, ids)
    runs = (tmp_path / "labels.log").read_text().split("\n")[:-1]
    assert sorted(int(line.split()[0]) for line in runs) == sorted(set(ids)), "each reference labelled once"
