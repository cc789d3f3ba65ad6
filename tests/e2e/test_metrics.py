"""Metrics and structured logs end to end (issue 50, items 1 and 2), on both profiles.

A real service (JSON logs, a metrics key) labels references and answers queries while a real Prometheus server
(Debian's ``prometheus``) on loopback scrapes its ``/metrics`` every 2 s; what the service exported is read
back through Prometheus's own HTTP API: request counts by route, a latency histogram, jobs queued and running
by kind, stage durations, live workers. ``promtool check metrics`` passes on the exposition. Every request's log
line is JSON with its request id; a query's job lines in the worker carry the id of the request that queued it,
which is stored on the job; an incoming ``X-Request-ID`` is honoured and echoed.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world, load_world
from testbed.servers import PrometheusServer
from tests.conftest import Profile
from tests.service_fixtures import read_rows, running_service, wait_for

pytestmark = pytest.mark.slow

METRICS_KEY = "scrape-secret"
QUERIES_ROUTE = "/v1/maps/{map_id}/queries"
REFERENCES_ROUTE = "/v1/maps/{map_id}/references"


@pytest.fixture(scope="module")
def world_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("metrics-world")
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        out,
        WorldOptions(n_references=5, n_queries=4, seed=5, radius_m=90.0, query_gps_noise_m=10.0),
    )
    return out


def _value(prometheus: PrometheusServer, promql: str) -> float:
    """The single value of an instant query (NaN when it returns nothing)."""
    result = prometheus.query(promql)
    return float(result[0]["value"][1]) if result else math.nan  # type: ignore[index]


def _by_label(prometheus: PrometheusServer, promql: str, label: str) -> dict[str, float]:
    return {str(r["metric"][label]): float(r["value"][1]) for r in prometheus.query(promql)}  # type: ignore[index]


def _log_lines(path: Path) -> list[dict[str, Any]]:
    """The service's JSON log lines (its start-up banner on stderr, written with echo, is not a log record)."""
    lines = []
    for text in path.read_text(errors="replace").splitlines():
        if text.startswith("{"):
            lines.append(json.loads(text))  # a line that starts as JSON must parse as JSON
        else:  # the banners (geoloc serve's, Celery's) are not log records: no request is logged outside JSON
            assert "/v1/" not in text and "HTTP" not in text, text
    return lines


def test_prometheus_scrapes_the_service_and_logs_carry_request_ids(
    tmp_path: Path, built_models: Path, world_dir: Path, profile: Profile
) -> None:
    world = load_world(world_dir)
    env = {**profile.new_env(), "GEOLOC_LOG_FORMAT": "json", "GEOLOC_METRICS_KEY": METRICS_KEY}
    with running_service(tmp_path / "data", workers=1, models=built_models, log_level="info", **env) as service:
        target = service.base_url.removeprefix("http://") if service.base_url else ""
        # Every 2 s (a scrape may take up to that): the tests run niced beside other work, so the API can be slow.
        prometheus = PrometheusServer([target], interval_s=2.0, bearer=METRICS_KEY).start()
        try:
            with service.client(timeout=300.0) as client:
                query_ids = _run_load(client, world, prometheus)
                time.sleep(5.0)  # two more scrapes after the last answer
                _check_prometheus(prometheus)
                exposition = client.get("/metrics", headers={"Authorization": f"Bearer {METRICS_KEY}"})
                assert exposition.status_code == 200, exposition.text
                assert client.get("/metrics").status_code == 401  # the metrics key is required
        finally:
            prometheus.stop()
        jobs = {row["id"]: row for row in read_rows(service.database, "SELECT id, kind, request_id FROM jobs")}
    _check_promtool(exposition.text, tmp_path)
    _check_logs(_log_lines(service.log_path), query_ids, jobs)


def _run_load(client: httpx.Client, world: Any, prometheus: PrometheusServer) -> dict[str, int]:
    """A map, references (queued at once for one worker) and queries queued behind them; waits for every answer.

    Returns each query's request id (sent in ``X-Request-ID``) and its job id.
    """
    wait_for(lambda: _value(prometheus, "up") == 1, timeout=120, what=lambda: f"a scrape: {prometheus.targets()}")
    path = shared_path("data", "osm", "helsinki.osm.pbf")
    with path.open("rb") as f:
        response = client.post("/v1/maps", files={"file": (path.name, f)}, data={"wait_s": "120", "name": "metrics"})
    assert response.status_code in (200, 201), response.text
    map_id = response.json()["id"]
    references = []
    for image in world.references:
        response = client.post(
            f"/v1/maps/{map_id}/references", files={"image": (image.path.name, image.path.read_bytes())}
        )
        assert response.status_code == 202, response.text
        references.append(response.json()["id"])
    query_ids: dict[str, int] = {}
    for n, image in enumerate(world.queries):
        request_id = f"metrics-test-query-{n}"
        response = client.post(
            f"/v1/maps/{map_id}/queries",
            files={"image": (image.path.name, image.path.read_bytes())},
            data={"wait_s": "0"},
            headers={"X-Request-ID": request_id},
        )
        assert response.status_code == 202, response.text
        assert response.headers["X-Request-ID"] == request_id  # honoured and echoed
        query_ids[request_id] = response.json()["job_id"]
    made = client.get("/healthz")
    assert len(made.headers["X-Request-ID"]) == 32  # made when none came
    refused = client.post(f"/v1/maps/{map_id}/queries", data={"wait_s": "0"})  # no photo
    assert refused.status_code == 422 and refused.json()["error"]["code"] == "invalid_request"

    def finished() -> bool:
        rows = [client.get(f"/v1/references/{rid}").json() for rid in references]
        rows += [client.get(f"/v1/jobs/{job_id}").json() for job_id in query_ids.values()]
        return all(row["status"] in ("done", "failed") for row in rows)

    wait_for(finished, timeout=900, interval=1.0, what="references and queries to finish")
    return query_ids


def _check_prometheus(prometheus: PrometheusServer) -> None:
    # Request counts by route template.
    requests = _by_label(prometheus, "sum by (route) (geoloc_http_requests_total)", "route")
    assert requests.get(REFERENCES_ROUTE, 0) >= 5 and requests.get(QUERIES_ROUTE, 0) >= 4, requests
    assert requests.get("/v1/references/{reference_id}", 0) >= 1, requests
    # A latency histogram: buckets with `le`, and a quantile from them.
    buckets = prometheus.query(f'geoloc_http_request_duration_seconds_bucket{{route="{QUERIES_ROUTE}"}}')
    assert {r["metric"]["le"] for r in buckets} >= {"0.1", "1.0", "+Inf"}  # type: ignore[index]
    by_le = f'sum by (le) (geoloc_http_request_duration_seconds_bucket{{route="{QUERIES_ROUTE}"}})'
    p90 = _value(prometheus, f"histogram_quantile(0.9, {by_le})")
    assert 0 < p90 < 60, p90
    # Jobs queued and running by kind, as the job table showed them while the load ran.
    for kind in ("label_reference", "localize_query"):
        for state in ("queued", "running"):
            seen = _value(prometheus, f'max_over_time(geoloc_jobs{{kind="{kind}",state="{state}"}}[15m])')
            assert seen >= 1, (kind, state, seen)
    done = _by_label(prometheus, 'geoloc_jobs{state="done"}', "kind")
    assert done["label_reference"] >= 5 and done["localize_query"] >= 4, done
    # Stage durations of the workers' jobs, and the jobs' own.
    stages = _by_label(
        prometheus, 'sum by (stage) (geoloc_stage_duration_seconds_count{kind="localize_query"})', "stage"
    )
    assert {"segmentation", "features", "retrieval", "anchors", "localize"} <= set(stages), stages
    assert all(count >= 4 for count in stages.values()), stages
    labelled = _value(prometheus, 'sum(geoloc_stage_duration_seconds_count{kind="label_reference",stage="labeling"})')
    assert labelled >= 5
    jobs_done = _by_label(prometheus, 'sum by (kind) (geoloc_job_duration_seconds_count{outcome="done"})', "kind")
    assert jobs_done["localize_query"] >= 4 and jobs_done["label_reference"] >= 5, jobs_done
    # Worker liveness and the catalogue's sizes.
    assert _value(prometheus, 'geoloc_workers{state="live"}') >= 1
    assert _value(prometheus, 'geoloc_references{status="done"}') >= 5
    assert _value(prometheus, "geoloc_index_documents") >= 5
    # Rejections by status and reason.
    assert _value(prometheus, 'geoloc_rejections_total{status="422",reason="invalid_request"}') >= 1


def _check_promtool(exposition: str, tmp_path: Path) -> None:
    promtool = shutil.which("promtool")
    assert promtool is not None, "promtool not found: install Debian's `prometheus` package (.ci/run does)"
    checked = subprocess.run(
        [promtool, "check", "metrics"], input=exposition, capture_output=True, text=True, check=False
    )
    assert checked.returncode == 0, checked.stdout + checked.stderr


def _check_logs(lines: list[dict[str, Any]], query_ids: dict[str, int], jobs: dict[int, dict[str, Any]]) -> None:
    requests = [line for line in lines if line["logger"] == "geoloc.request"]
    assert len(requests) > 20  # the uploads, the polls, the health checks
    assert all(line.get("request_id") and line["status"] and "route" in line for line in requests)
    for request_id, job_id in query_ids.items():
        posted = [line for line in requests if line["request_id"] == request_id]
        assert [(line["route"], line["status"]) for line in posted] == [(QUERIES_ROUTE, 202)]
        assert jobs[job_id]["request_id"] == request_id  # stored on the job
        job_lines = [line for line in lines if line.get("job_id") == job_id]
        assert {line["logger"] for line in job_lines} == {"geoloc.worker"}
        assert [line.get("outcome") for line in job_lines][-1] == "done"
        assert all(line["request_id"] == request_id for line in job_lines), job_lines
        assert all(line["process"] != posted[0]["process"] for line in job_lines)  # a worker process, not the API
    # Reference uploads made their own ids, which their label jobs carry.
    label_jobs = [job for job in jobs.values() if job["kind"] == "label_reference"]
    assert label_jobs and all(job["request_id"] for job in label_jobs)
