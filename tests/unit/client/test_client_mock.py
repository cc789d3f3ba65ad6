"""The client's retries, errors, waiting and models, against mock transports and ``openapi.json``.

The client against a real service (and the real method) is ``tests/e2e/test_client.py``.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import httpx
import pytest
from pydantic import BaseModel

import contracts.api
from client import (
    ApiError,
    AsyncClient,
    Client,
    NotFoundError,
    RateLimitedError,
    RetryPolicy,
    ServerError,
    ServiceUnreachableError,
    WaitTimeoutError,
    models,
)
from contracts.settings import Settings

ROOT = Path(__file__).resolve().parents[3]
QUEUED_QUERY = {"id": 5, "map_id": 1, "status": "queued", "params": {}, "attribution": "© OSM"}


def _rate_limited(retry_after: str = "2") -> httpx.Response:
    body = {"error": {"code": "rate_limited", "message": "slow down", "details": {"limit_per_min": 5}}}
    return httpx.Response(429, json=body, headers={"Retry-After": retry_after})


def test_a_429_is_retried_after_its_retry_after_and_gives_up_at_the_limit() -> None:
    answers = [_rate_limited("2"), _rate_limited("3"), httpx.Response(200, json={"status": "ok"})]
    slept: list[float] = []
    with Client("http://mock", transport=httpx.MockTransport(lambda _: answers.pop(0)), sleep=slept.append) as client:
        assert client.health().status == "ok"
        assert slept == [2.0, 3.0]  # Retry-After, not the backoff

    def always(_request: httpx.Request) -> httpx.Response:
        return _rate_limited("1")

    transport = httpx.MockTransport(always)
    with (
        Client("http://mock", retry=RetryPolicy(retries=2), transport=transport, sleep=slept.append) as client,
        pytest.raises(RateLimitedError) as caught,
    ):
        client.list_maps()
    error = caught.value
    assert (error.status, error.code, error.message, error.attempts) == (429, "rate_limited", "slow down", 3)
    assert error.retry_after_s == 1.0 and error.details == {"limit_per_min": 5}


def test_errors_carry_status_code_and_message_and_other_bodies_too() -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        if request.url.path == "/v1/maps/7":
            return httpx.Response(404, json={"error": {"code": "not_found", "message": "map 7 not found"}})
        return httpx.Response(502, text="<html>Bad gateway</html>")

    with Client("http://mock", retry=RetryPolicy(retries=0), transport=httpx.MockTransport(handler)) as client:
        with pytest.raises(NotFoundError) as missing:
            client.get_map(7)
        with pytest.raises(ServerError) as proxy:
            client.about()
    assert (missing.value.status, missing.value.code, missing.value.message) == (404, "not_found", "map 7 not found")
    assert isinstance(missing.value, ApiError) and str(missing.value) == "404 not_found: map 7 not found"
    assert (proxy.value.status, proxy.value.code, proxy.value.message) == (502, None, "<html>Bad gateway</html>")


def test_connection_errors_are_retried_then_raised() -> None:
    calls = 0

    def down(request: httpx.Request) -> httpx.Response:
        nonlocal calls
        calls += 1
        raise httpx.ConnectError("connection refused", request=request)

    slept: list[float] = []
    policy = RetryPolicy(retries=2, backoff_s=1.0)
    with (
        Client("http://mock", retry=policy, transport=httpx.MockTransport(down), sleep=slept.append) as client,
        pytest.raises(ServiceUnreachableError, match="ConnectError"),
    ):
        client.health()
    assert calls == 3 and len(slept) == 2 and 0.75 <= slept[0] <= 1.25 and 1.5 <= slept[1] <= 2.5


def test_waiting_backs_off_and_times_out_with_the_last_state() -> None:
    seen: list[str] = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request.url.params["wait_s"])
        return httpx.Response(200, json=QUEUED_QUERY)

    with (
        Client("http://mock", transport=httpx.MockTransport(handler)) as client,
        pytest.raises(WaitTimeoutError) as caught,
    ):
        client.wait_for_query(5, timeout_s=1.2)
    assert isinstance(caught.value.last, models.Query) and caught.value.last.status == "queued"
    waits = [float(w) for w in seen]
    assert waits[:3] == [0.25, 0.5, 1.0] and len(waits) <= 6  # long polls that grow like a backoff (mock: no wait)


def test_the_async_client_sends_the_same_requests() -> None:
    requests: list[httpx.Request] = []

    def handler(request: httpx.Request) -> httpx.Response:
        requests.append(request)
        return httpx.Response(202, json=QUEUED_QUERY)

    async def run() -> models.Query:
        async with AsyncClient("http://mock", api_key="k", transport=httpx.MockTransport(handler)) as client:
            return await client.upload_query(1, ("q.jpg", b"jpeg"), lat=60.17, lon=24.94, use_exif_gps=False, wait_s=0)

    query = asyncio.run(run())
    assert query.status == "queued" and requests[0].headers["X-API-Key"] == "k"
    body = requests[0].content
    assert b'name="use_exif_gps"\r\n\r\nfalse' in body and b'name="lat"\r\n\r\n60.17' in body
    assert b'name="wait_s"\r\n\r\n0' in body and b'filename="q.jpg"' in body


def test_waiting_for_a_map_s_walks_to_be_placed() -> None:
    """Read the map's state (one reference a page) until nothing is labelled or placed; sync and async alike."""
    states = [(1, 1), (0, 1), (0, 1), (0, 0)]  # (references processing, walks_placing) per read
    seen: list[dict[str, str]] = []

    def handler(request: httpx.Request) -> httpx.Response:
        assert request.url.path == "/v1/maps/3/references"
        seen.append(dict(request.url.params))
        processing, placing = states[min(len(seen), len(states)) - 1]
        return httpx.Response(200, json={
            "map_id": 3, "references": [], "total": 4, "counts": {"queued": 0, "processing": processing, "done": 3},
            "walks_placing": placing, "next_after_id": None, "attribution": "© OSM",
        })  # fmt: skip

    with Client("http://mock", transport=httpx.MockTransport(handler), sleep=lambda _: None) as client:
        page = client.wait_for_map_placed(3)
    assert (
        page.placed
        and page.status == "placed"
        and len(seen) == 4
        and seen[0] == {"after_id": "0", "limit": "1", "format": "json"}
    )

    async def sleep(_: float) -> None:
        return None

    async def run() -> models.ReferenceList:
        async with AsyncClient("http://mock", transport=httpx.MockTransport(handler), sleep=sleep) as client:
            return await client.wait_for_map_placed(3)

    seen.clear()
    assert asyncio.run(run()).placed and len(seen) == 4

    states[:] = [(0, 1)]
    with (
        Client("http://mock", transport=httpx.MockTransport(handler)) as client,
        pytest.raises(WaitTimeoutError, match="last status: placing") as caught,
    ):
        client.wait_for_map_placed(3, timeout_s=0.6)
    assert isinstance(caught.value.last, models.ReferenceList) and caught.value.last.walks_placing == 1


@pytest.mark.parametrize(
    ("model", "schema"),
    [
        (models.Map, "MapOut"),
        (models.ReferenceAccepted, "ReferenceAccepted"),
        (models.Reference, "ReferenceOut"),
        (models.ReferenceList, "ReferenceList"),
        (models.Position, "Position"),
        (models.Query, "QueryOut"),
        (models.Job, "JobOut"),
        (models.Health, "Health"),
        (models.Readiness, "Readiness"),
        (models.About, "About"),
        (models.License, "LicenseOut"),
    ],
)
def test_the_models_are_the_api_s_own(model: type[BaseModel], schema: str) -> None:
    """Each client model is the API's class of its OpenAPI schema, with its fields (the required ones required)."""
    assert model is getattr(contracts.api, schema)
    component: dict[str, Any] = json.loads((ROOT / "openapi.json").read_text())["components"]["schemas"][schema]
    assert set(model.model_fields) == set(component["properties"])
    required = {name for name, info in model.model_fields.items() if info.is_required()}
    assert required == set(component.get("required", []))


def test_the_client_drops_an_idle_connection_before_the_service_closes_it() -> None:
    service_keep_alive_s = Settings.model_fields["http_keep_alive_s"].default
    with Client("http://127.0.0.1:1") as client:
        expiry_s = client._limits.keepalive_expiry
    # a reused connection the service is closing for idleness takes the request with it, unanswered
    assert expiry_s is not None and expiry_s <= service_keep_alive_s - 2.0
