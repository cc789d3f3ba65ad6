"""The client (:mod:`client`) against a real ``geoloc serve`` on loopback (SQLite, API keys).

Most tests run a service without workers and with a small rate limit: nothing is labelled or answered,
which is what the waits' time-outs need, and a key soon runs out of requests. The last one runs the real
method (one worker, a small simulated world): references labelled, a query answered, read as the client
types them.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from client import (
    AsyncClient,
    AuthError,
    Client,
    InvalidRequestError,
    NotFoundError,
    RateLimitedError,
    RetryPolicy,
    ServerError,
    WaitTimeoutError,
)
from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world, load_world
from tests.service_fixtures import READ_KEY, WRITE_KEY, RunningProcess, jpeg_bytes, running_service

pytestmark = pytest.mark.slow  # a real server (tests/e2e/ is the slow suite); the method test takes a minute

INSIDE = (60.1716, 24.9443)
"""A position inside the Helsinki map (lat, lon degrees)."""
LUND = (55.7047, 13.1910)
RATE_PER_MIN = 60
"""The service's per-key rate: a full bucket of 60, then one request a second (``Retry-After: 1``)."""


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningProcess]:
    data_dir = tmp_path_factory.mktemp("client") / "data"
    with running_service(data_dir, workers=0, GEOLOC_RATE_LIMIT_PER_MIN=str(RATE_PER_MIN)) as running:
        yield running


@pytest.fixture(scope="module")
def client(service: RunningProcess) -> Iterator[Client]:
    assert service.base_url is not None
    with Client(service.base_url, api_key=WRITE_KEY) as client:
        yield client


def test_maps_references_queries_jobs_and_system(client: Client) -> None:
    assert client.health().status == "ok"
    assert client.about().name == "geoloc" and any(row.kind == "model" for row in client.about().licenses)
    with pytest.raises(ServerError) as not_ready:  # no workers: not ready
        client.ready()
    assert (not_ready.value.status, not_ready.value.code) == (503, "not_ready")

    osm = shared_path("data", "osm", "helsinki.osm.pbf")
    helsinki = client.upload_map(osm, "helsinki", attribution="© test data")
    assert helsinki.building_count > 300 and helsinki.attribution == "© test data" and not helsinki.duplicate
    assert client.upload_map(osm, "again").duplicate
    assert client.get_map(helsinki.id) == helsinki.model_copy(update={"duplicate": False})
    assert helsinki.id in [m.id for m in client.list_maps()]
    buildings = client.buildings(helsinki.id)
    assert len(buildings.features) == helsinki.building_count and buildings.member("attribution") == "© test data"

    photo = ("ref.jpg", jpeg_bytes(gps=INSIDE, seed=1))
    accepted = client.upload_reference(helsinki.id, photo, heading_deg=84.0, focal_length_35mm=28.0, sequence="a")
    assert accepted.status == "queued" and not accepted.duplicate and accepted.job_id is not None
    assert client.upload_reference(helsinki.id, photo).duplicate
    reference = client.get_reference(accepted.id)
    assert (reference.prior_heading_deg, reference.focal_length_35mm, reference.sequence_id) == (84.0, 28.0, "a")
    assert reference.position.source == "exif"
    moved = client.upload_reference(helsinki.id, ("b.jpg", jpeg_bytes(seed=2)), lat=INSIDE[0], lon=INSIDE[1])
    assert client.get_reference(moved.id).position.source == "request"
    page = client.list_references(helsinki.id, limit=1)
    assert (page.total, len(page.references), page.next_after_id) == (2, 1, accepted.id)
    assert page.counts["queued"] == 2
    job = client.get_job(accepted.job_id)
    assert (job.kind, job.status, job.payload["reference_id"]) == ("label_reference", "queued", accepted.id)
    with pytest.raises(WaitTimeoutError) as waited:
        client.wait_for_reference(accepted.id, timeout_s=0.5)
    assert waited.value.last.status == "queued"

    query = client.upload_query(helsinki.id, ("q.jpg", jpeg_bytes(seed=3)), lat=INSIDE[0], lon=INSIDE[1], wait_s=0)
    assert query.status == "queued" and query.result is None and query.params["prior"]["lat"] == INSIDE[0]
    assert client.get_query(query.id).status == "queued"
    collection = client.get_query_geojson(query.id)
    assert collection.features == [] and collection.member("status") == "queued"
    started = time.monotonic()
    with pytest.raises(WaitTimeoutError):
        client.wait_for_query(query.id, timeout_s=1.0)
    assert 0.9 <= time.monotonic() - started < 5.0

    client.delete_reference(moved.id)
    with pytest.raises(NotFoundError):
        client.get_reference(moved.id)
    client.delete_query(query.id)
    client.delete_map(helsinki.id)
    with pytest.raises(NotFoundError) as gone:
        client.get_map(helsinki.id)
    assert (gone.value.status, gone.value.code) == (404, "not_found")


def test_error_answers_raise_api_errors_with_the_api_s_code(client: Client, service: RunningProcess) -> None:
    helsinki = client.upload_map(shared_path("data", "osm", "helsinki.osm.pbf"), "helsinki")
    with pytest.raises(InvalidRequestError) as outside:
        client.upload_reference(helsinki.id, ("lund.jpg", jpeg_bytes(gps=LUND, seed=4)))
    assert (outside.value.status, outside.value.code) == (422, "outside_map")
    assert outside.value.details is not None and outside.value.details["distance_m"] > 100_000
    with pytest.raises(InvalidRequestError) as invalid:
        client.upload_query(helsinki.id, ("q.jpg", jpeg_bytes(seed=5)), lat=100.0, lon=24.9)
    assert (invalid.value.status, invalid.value.code) == (422, "invalid_request")
    assert "lat must be between -90 and 90" in invalid.value.message
    with pytest.raises(NotFoundError):
        client.get_query(987654)
    assert service.base_url is not None
    with Client(service.base_url) as anonymous, pytest.raises(AuthError) as refused:
        anonymous.list_maps()
    assert (refused.value.status, refused.value.code) == (401, "unauthorized")
    with Client(service.base_url, api_key=READ_KEY) as reader, pytest.raises(AuthError) as scope:
        reader.delete_map(helsinki.id)
    assert (scope.value.status, scope.value.code) == (403, "forbidden")


def test_a_429_is_waited_out_after_its_retry_after(service: RunningProcess) -> None:
    """The read key's bucket emptied with a client that does not retry, then one that does gets through."""
    assert service.base_url is not None
    impatient = Client(service.base_url, api_key=READ_KEY, retry=RetryPolicy(retries=0))
    with impatient, pytest.raises(RateLimitedError) as limited:
        for _ in range(3 * RATE_PER_MIN):
            impatient.list_maps()
    assert (limited.value.status, limited.value.code, limited.value.retry_after_s) == (429, "rate_limited", 1.0)
    slept: list[float] = []

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        time.sleep(seconds)

    with Client(service.base_url, api_key=READ_KEY, sleep=sleep) as patient:
        for _ in range(3):
            patient.list_maps()  # each a 429 first (no token left), then the retry after a second
    assert slept and all(s == 1.0 for s in slept)


def test_the_async_client(service: RunningProcess) -> None:
    assert service.base_url is not None
    base_url = service.base_url

    async def run() -> tuple[int, str, str | None]:
        async with AsyncClient(base_url, api_key=WRITE_KEY) as client:
            helsinki = await client.upload_map(shared_path("data", "osm", "helsinki.osm.pbf"), "helsinki")
            photo = ("q.jpg", jpeg_bytes(seed=6))
            query = await client.upload_query(helsinki.id, photo, lat=INSIDE[0], lon=INSIDE[1], wait_s=0)
            fetched, maps = await asyncio.gather(client.get_query(query.id), client.list_maps())
            try:
                await client.get_reference(987654)
            except NotFoundError as exc:
                code = exc.code
            return len(maps), fetched.status, code

    count, status, code = asyncio.run(run())
    assert count >= 1 and status == "queued" and code == "not_found"


def test_the_real_method_through_the_client(tmp_path: Path, built_models: Path) -> None:
    """References labelled and a query answered by the method, waited for and read through the client."""
    osm = shared_path("data", "osm", "helsinki.osm.pbf")
    options = WorldOptions(n_references=6, n_queries=1, seed=3, radius_m=60.0, query_gps_noise_m=10.0)
    generate_world(osm, tmp_path / "world", options)
    world = load_world(tmp_path / "world")
    with running_service(tmp_path / "data", workers=1, models=built_models) as running:
        assert running.base_url is not None
        with Client(running.base_url, api_key=WRITE_KEY) as client:
            helsinki = client.upload_map(osm, "helsinki")
            accepted = [client.upload_reference(helsinki.id, image.path) for image in world.references]
            labelled = [client.wait_for_reference(a.id, timeout_s=300) for a in accepted]
            assert all(r.status == "done" for r in labelled), [r.error for r in labelled]
            assert all(r.estimated is not None and r.estimated.heading_deg is not None for r in labelled)
            assert client.get_job(accepted[0].job_id or 0).status == "done"
            query = client.upload_query(helsinki.id, world.queries[0].path, wait_s=0)
            answered = client.wait_for_query(query.id, timeout_s=300)
            assert answered.status == "done" and answered.result is not None, answered.error
            best = answered.result.locations[0]
            bbox = helsinki.bbox
            assert bbox.min_lat <= best.lat <= bbox.max_lat and bbox.min_lon <= best.lon <= bbox.max_lon
            collection = client.get_query_geojson(query.id)
            points = [f for f in collection.features if (f.geometry or {}).get("type") == "Point"]
            assert len(points) == len(answered.result.locations) and collection.member("attribution")
