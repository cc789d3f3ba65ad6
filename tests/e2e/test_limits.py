"""Load limits against a real server.

Waiting clients hold no thread, a full queue answers 429 with ``Retry-After`` and stores nothing,
per-key rate limits, ids beyond 64 bits, ``Allow`` on 405.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.conftest import Profile
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    READ_KEY,
    WRITE_KEY,
    RunningProcess,
    jpeg_bytes,
    read_rows,
    running_service,
    stored_files,
    table_counts,
    upload_hall_map,
    wait_for,
)

pytestmark = pytest.mark.slow

WAITING_QUERIES = 60
"""More than the API's thread pool (40): a thread per waiting query would starve every read."""
QUEUE_LIMIT = WAITING_QUERIES + 4
WAIT_S = 12.0


QUERY_JOBS = "SELECT COUNT(*) AS n FROM jobs WHERE kind = 'localize_query'"
"""The query jobs (the map's own load_map job is done before any query)."""


def _error(response: httpx.Response) -> dict[str, Any]:
    return dict(response.json()["error"])


@pytest.fixture(scope="module")
def queue_service(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[RunningProcess]:
    """No workers (jobs stay queued), a queue limit just above the waiting queries, a rate limit out of the way."""
    data_dir = tmp_path_factory.mktemp("limits") / "data"
    limits = {"GEOLOC_MAX_QUEUED_JOBS": str(QUEUE_LIMIT), "GEOLOC_RATE_LIMIT_PER_MIN": "100000"}
    with running_service(data_dir, workers=0, **limits, **profile.new_env()) as running:
        yield running


def test_waiting_queries_hold_no_thread_and_a_full_queue_answers_429(queue_service: RunningProcess) -> None:
    with queue_service.client(WRITE_KEY) as client:
        map_id = upload_hall_map(client)

    def ask(seed: int) -> httpx.Response:
        with queue_service.client(READ_KEY, timeout=WAIT_S + 30) as own:
            return own.post(
                f"/v1/maps/{map_id}/queries",
                files={"image": ("q.jpg", jpeg_bytes(seed=seed))},
                data={"use_exif_gps": "false", "wait_s": str(WAIT_S)},
            )

    with ThreadPoolExecutor(WAITING_QUERIES) as pool, queue_service.client(READ_KEY) as reader:
        waiting = [pool.submit(ask, seed) for seed in range(WAITING_QUERIES)]
        wait_for(
            lambda: read_rows(queue_service.database, QUERY_JOBS)[0]["n"] == WAITING_QUERIES,  # not the map's
            timeout=60,
            what="every query to be stored and waiting",
        )
        started = time.monotonic()
        read_s = []
        while time.monotonic() - started < WAIT_S / 2:
            t0 = time.perf_counter()
            assert reader.get(f"/v1/maps/{map_id}").status_code == 200
            read_s.append(time.perf_counter() - t0)
            time.sleep(0.05)
        assert max(read_s) < 1.0, f"a read took {max(read_s):.2f} s while {WAITING_QUERIES} queries waited"

        # Four more jobs fill the queue; the next new work is refused with Retry-After and nothing stored.
        with queue_service.client(WRITE_KEY) as writer:
            for seed in range(4):
                photo = {"image": ("r.jpg", jpeg_bytes(seed=100 + seed))}
                accepted = writer.post(f"/v1/maps/{map_id}/references", files=photo, data=INSIDE_ONE_BUILDING)
                assert accepted.status_code == 202, accepted.text
            before_counts, before_files = table_counts(queue_service.database), stored_files(queue_service.data_dir)
            refused = [
                writer.post(
                    f"/v1/maps/{map_id}/references",
                    files={"image": ("r.jpg", jpeg_bytes(seed=200))},
                    data=INSIDE_ONE_BUILDING,
                ),
                writer.post(f"/v1/maps/{map_id}/queries", files={"image": ("q.jpg", jpeg_bytes(seed=201))}),
            ]
            for response in refused:
                assert response.status_code == 429, response.text
                assert _error(response)["code"] == "queue_full" and "nothing was stored" in _error(response)["message"]
                assert 1 <= int(response.headers["Retry-After"]) <= 120
            assert reader.get(f"/v1/maps/{map_id}").status_code == 200, "reads are never refused for load"
            assert table_counts(queue_service.database) == before_counts
            assert stored_files(queue_service.data_dir) == before_files

        answers = [future.result() for future in waiting]
    assert [r.status_code for r in answers] == [202] * WAITING_QUERIES, "each waited wait_s, then got its query id"
    assert {r.json()["status"] for r in answers} == {"queued"}
    with queue_service.client(READ_KEY) as reader:  # the same wait on a GET: a long poll
        query_id = answers[0].json()["id"]
        t0 = time.perf_counter()
        polled = reader.get(f"/v1/queries/{query_id}", params={"wait_s": 1.5})
        assert polled.status_code == 200 and polled.json()["status"] == "queued"
        assert time.perf_counter() - t0 >= 1.4
        assert reader.get(f"/v1/queries/{query_id}", params={"wait_s": 301}).status_code == 422

    # Room again (a queued job is cancelled with its reference): new work is accepted.
    with queue_service.client(WRITE_KEY) as writer:
        reference_id = read_rows(queue_service.database, "SELECT id FROM reference_images LIMIT 1")[0]["id"]
        assert writer.delete(f"/v1/references/{reference_id}").status_code == 204
        again = writer.post(
            f"/v1/maps/{map_id}/references", files={"image": ("r.jpg", jpeg_bytes(seed=200))}, data=INSIDE_ONE_BUILDING
        )
        assert again.status_code == 202, again.text


def test_ids_beyond_64_bits_and_405_allow(queue_service: RunningProcess) -> None:
    with queue_service.client(WRITE_KEY) as client:
        for url in ("/v1/maps/18856353251648462848", "/v1/jobs/9223372036854775808", "/v1/references/0"):
            response = client.get(url)
            assert response.status_code == 422 and _error(response)["code"] == "invalid_request", response.text
        response = client.delete("/v1/queries/-60092825076608711986547523584")
        assert response.status_code == 422 and "map_id" not in response.text
        assert client.get("/v1/maps/9223372036854775807").status_code == 404, "the largest id is valid"
        for url, allow in [("/v1/maps/1", "DELETE, GET"), ("/v1/maps", "GET, POST"), ("/v1/queries/1", "DELETE, GET")]:
            response = client.request("PUT", url)
            assert response.status_code == 405 and response.headers["Allow"] == allow, response.headers


def test_openapi_documents_the_running_configuration(queue_service: RunningProcess, tmp_path: Path) -> None:
    with queue_service.client(None) as anonymous:
        keyed = anonymous.get("/openapi.json").json()
    operation = keyed["paths"]["/v1/maps/{map_id}"]["get"]
    assert operation["security"] == [{"APIKeyHeader": ["read"]}]
    assert {"401", "403", "429"} <= set(operation["responses"])
    assert keyed["paths"]["/v1/maps/{map_id}/queries"]["post"]["responses"]["429"]["headers"]["Retry-After"]
    with running_service(tmp_path / "open", workers=0, api_keys=None) as service, service.client(None) as client:
        assert client.get("/v1/maps").status_code == 200, "no keys configured: none needed"
        spec = client.get("/openapi.json").json()
    assert "securitySchemes" not in spec["components"]
    for item in spec["paths"].values():
        for method, op in item.items():
            assert "security" not in op, method
            assert not {"401", "403"} & set(op["responses"]), (method, op["responses"])
    uploads = spec["paths"]["/v1/maps/{map_id}/references"]["post"]["responses"]
    assert "queue_full" in uploads["429"]["description"] and "rate_limited" not in uploads["429"]["description"]


def test_a_key_past_its_rate_limit_gets_429_others_go_on(tmp_path: Path, profile: Profile) -> None:
    with running_service(tmp_path / "data", workers=0, GEOLOC_RATE_LIMIT_PER_MIN="5", **profile.new_env()) as service:
        with service.client(WRITE_KEY) as writer, service.client(READ_KEY) as reader:
            assert [writer.get("/v1/maps").status_code for _ in range(5)] == [200] * 5
            limited = writer.get("/v1/maps")
            assert limited.status_code == 429 and _error(limited)["code"] == "rate_limited", limited.text
            assert 10 <= int(limited.headers["Retry-After"]) <= 12, "one request back every 12 s at 5 a minute"
            assert _error(limited)["details"]["limit_per_min"] == 5
            assert reader.get("/v1/maps").status_code == 200, "the limit is per key"
            assert writer.get("/healthz").status_code == 200, "health checks are not limited"
        with service.client(None) as anonymous:
            assert anonymous.get("/v1/maps").status_code == 401, "no key is 401, not a rate-limit answer"


def test_two_api_processes_share_a_keys_rate_limit(tmp_path: Path, postgres_server: Any, redis_server: Any) -> None:
    """Distributed profile: the buckets live in Redis, so a key's limit holds across API processes."""
    env = Profile("distributed", postgres_server, redis_server).new_env()
    data_dir = tmp_path / "data"
    with (
        running_service(data_dir, workers=0, GEOLOC_RATE_LIMIT_PER_MIN="6", **env) as first,
        running_service(data_dir, workers=0, GEOLOC_RATE_LIMIT_PER_MIN="6", **env) as second,
        first.client(WRITE_KEY) as one,
        second.client(WRITE_KEY) as other,
    ):
        assert [c.get("/v1/maps").status_code for c in (one, other, one, other, one, other)] == [200] * 6
        assert one.get("/v1/maps").status_code == 429 and other.get("/v1/maps").status_code == 429
        with first.client(READ_KEY) as reader:
            assert reader.get("/v1/maps").status_code == 200, "the limit is per key"
