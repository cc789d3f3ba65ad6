"""Request ids and the metrics endpoint's switches, on a real service (embedded, no models needed).

An ``X-Request-ID`` is honoured and echoed, a malformed one is a ``400`` ``invalid_request_id``; ``text`` logs
carry the id too; ``GEOLOC_METRICS=false`` answers ``404`` on ``/metrics``; the body-size guard's ``413`` is
counted as a rejection by its reason.
"""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from contracts.settings import Settings
from tests.service_fixtures import running_service, wait_for
from workers.metrics import metrics_folder

pytestmark = pytest.mark.slow


def test_request_ids_are_honoured_refused_when_malformed_and_logged_as_text(tmp_path: Path) -> None:
    with running_service(tmp_path / "data", workers=0, api_keys=None, log_level="info") as service:
        with service.client(api_key=None) as client:
            echoed = client.get("/healthz", headers={"X-Request-ID": "3f2c-ab:trace/1"})
            assert echoed.status_code == 200 and echoed.headers["X-Request-ID"] == "3f2c-ab:trace/1"
            for bad in (b"has space", b"x" * 129, "é".encode()):
                refused = client.get("/v1/maps", headers={"X-Request-ID": bad})
                assert refused.status_code == 400, bad
                assert refused.json()["error"]["code"] == "invalid_request_id"
                assert len(refused.headers["X-Request-ID"]) == 32  # a fresh id of our own, for the log
            too_large = client.post("/v1/maps", content=b"x" * 300_000_000, headers={"Content-Type": "text/plain"})
            assert too_large.status_code == 413
            metrics = client.get("/metrics")
            assert metrics.status_code == 200  # no key set: open, as /healthz
            assert 'geoloc_rejections_total{reason="payload_too_large",status="413"} 1.0' in metrics.text
            assert 'geoloc_http_requests_total{method="GET",route="/healthz",status="200"}' in metrics.text

        def logged() -> bool:
            return "[3f2c-ab:trace/1] GET /healthz 200" in service.log_path.read_text(errors="replace")

        wait_for(logged, timeout=10, what=service.log_tail)


def test_metrics_off_is_a_404(tmp_path: Path) -> None:
    with running_service(tmp_path / "data", workers=0, api_keys=None, GEOLOC_METRICS="false") as service:
        response = httpx.get(f"{service.base_url}/metrics")
        assert response.status_code == 404 and response.json()["error"]["code"] == "not_found"
        folder = metrics_folder(Settings.from_values(data_dir=tmp_path / "data"))
        assert not folder.exists()  # no process recorded anything
