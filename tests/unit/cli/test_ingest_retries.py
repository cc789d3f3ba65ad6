"""``geoloc ingest``'s retries against a mock transport: transient errors retried, given up at the limit.

The same command against a real service is in ``tests/e2e/test_ingest.py``.
"""

from __future__ import annotations

import io
from pathlib import Path

import httpx
import numpy as np
import pytest
from rich.console import Console

from cli.ingest import IngestAbortError, IngestOptions, ingest_folder
from geoloc.photos.exif import ExifFields, write_jpeg
from tests.service_fixtures import WRITE_KEY

MOCK_MAP = {
    "id": 1,
    "name": "mock",
    "source_filename": "mock.osm",
    "source_format": "osm",
    "sha256": "00",
    "bbox": {"min_lat": 60.16, "min_lon": 24.93, "max_lat": 60.18, "max_lon": 24.96},
    "origin": {"lat": 60.17, "lon": 24.94},
    "building_count": 1,
    "facade_count": 4,
    "repair_report": {},
    "attribution": "© OpenStreetMap contributors",
    "created_at": "2025-01-01T12:00:00Z",
}
"""``GET /v1/maps/1``'s answer, as the service's ``MapOut`` has it (the client reads it into a ``Map``)."""
INSIDE_HELSINKI = [(60.1716, 24.9443), (60.1700, 24.9450), (60.1690, 24.9420)]
"""Positions inside the Helsinki map (lat, lon degrees)."""


def photo(path: Path, position: tuple[float, float], seed: int) -> Path:
    """A 320 x 240 noise JPEG at ``position`` (lat, lon) with a 28 mm focal length."""
    rgb = np.random.default_rng(seed).integers(0, 255, size=(240, 320, 3), dtype=np.uint8)
    return write_jpeg(path, rgb, ExifFields(lat=position[0], lon=position[1], focal_35mm=28))


def test_transient_errors_are_retried_and_give_up_at_the_limit(tmp_path: Path) -> None:
    """No server: a mock transport answers in turn.

    503, then a connection error, then 202 for one photo; always 429 for the other.
    """
    photo(tmp_path / "ok.jpg", INSIDE_HELSINKI[0], seed=4)
    photo(tmp_path / "busy.jpg", INSIDE_HELSINKI[1], seed=5)
    calls: dict[str, int] = {}

    def handler(request: httpx.Request) -> httpx.Response:
        if request.method == "GET":
            return httpx.Response(200, json=MOCK_MAP)
        name = "busy" if b'filename="busy.jpg"' in request.content else "ok"
        calls[name] = calls.get(name, 0) + 1
        if name == "busy":
            return httpx.Response(429, json={"error": {"code": "rate_limited", "message": "slow down"}})
        if calls[name] == 1:
            return httpx.Response(503, json={"error": {"code": "unavailable", "message": "busy"}})
        if calls[name] == 2:
            raise httpx.ConnectError("connection refused", request=request)
        accepted = {"id": 9, "map_id": 1, "job_id": 10, "status": "queued", "sha256": "ab", "duplicate": False}
        return httpx.Response(202, json=accepted)

    report = ingest_folder(
        tmp_path,
        1,
        IngestOptions(url="http://mock", api_key=WRITE_KEY, retries=3, backoff_s=0.0),
        transport=httpx.MockTransport(handler),
        console=Console(file=io.StringIO()),
    )
    files = {f.path: f for f in report.files}
    assert (files["ok.jpg"].outcome, files["ok.jpg"].attempts, files["ok.jpg"].reference_id) == ("accepted", 3, 9)
    assert files["busy.jpg"].outcome == "failed" and files["busy.jpg"].attempts == 4 == calls["busy"]
    assert "429 rate_limited" in (files["busy.jpg"].reason or "")
    assert report.exit_code == 1

    def down(request: httpx.Request) -> httpx.Response:
        raise httpx.ConnectError("connection refused", request=request)

    with pytest.raises(IngestAbortError, match="cannot reach the service"):
        options = IngestOptions(url="http://mock", api_key=None, retries=1, backoff_s=0.0)
        ingest_folder(tmp_path, 1, options, transport=httpx.MockTransport(down), console=Console(file=io.StringIO()))
