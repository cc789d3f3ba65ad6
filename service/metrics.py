"""``GET /metrics``: the machine's metrics in Prometheus's text format, and gauges read from the database.

The exposition adds up what every API and worker process of this machine wrote into the metrics folder
(:mod:`workers.metrics`: jobs and stages; :mod:`service.observe`: requests, latencies, rejections) and reads, at
each scrape, what the database knows for the whole deployment:

- ``geoloc_jobs{kind, state}``: jobs in the table by kind and state (``queued``: not tried yet, ``retrying``: queued
  again after a failed attempt, ``running``, ``done``, ``failed``, ``cancelled``; every shipped kind, zeros too);
- ``geoloc_workers{state}``: worker processes not stopped, ``live`` (a heartbeat within ``GEOLOC_READY_WORKER_S``)
  or ``stale``; ``geoloc_worker_heartbeat_age_seconds``: the oldest live heartbeat's age;
- ``geoloc_maps{status}``, ``geoloc_references{status}``, ``geoloc_index_documents`` (references in the SBoW index).

Off (``GEOLOC_METRICS=false``): ``404``. With ``GEOLOC_METRICS_KEY``: ``401`` without ``Authorization: Bearer
KEY``. It is not part of the API's OpenAPI document (an operator's endpoint, like the scrape it serves).
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Iterator
from typing import Any

from fastapi import APIRouter, Request, Response

from contracts.jobs import LABEL_REFERENCE, LOAD_MAP, LOCALIZE_QUERY, LOCATE_TRACK, PLACE_SEQUENCE
from contracts.settings import Settings
from db import connect
from db.stats import catalogue_counts, job_counts, worker_heartbeats
from service.deps import app_settings
from service.errors import ApiError
from workers.metrics import enabled_folder

router = APIRouter()

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
JOB_KINDS = (LOAD_MAP, LABEL_REFERENCE, PLACE_SEQUENCE, LOCALIZE_QUERY, LOCATE_TRACK)
JOB_STATES = ("queued", "retrying", "running", "done", "failed", "cancelled")


class DatabaseCollector:
    """Gauges read from the database at each scrape (module docstring); a prometheus-client custom collector."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings

    def collect(self) -> Iterator[Any]:
        """The gauges, from one connection."""
        from prometheus_client.core import GaugeMetricFamily

        db = connect(self.settings.database)
        try:
            jobs, beats, catalogue = job_counts(db), worker_heartbeats(db), catalogue_counts(db)
        finally:
            db.close()
        family = GaugeMetricFamily("geoloc_jobs", "Jobs in the job table by kind and state", labels=["kind", "state"])
        kinds = sorted({*JOB_KINDS, *(kind for kind, _ in jobs)})
        for kind in kinds:
            for state in JOB_STATES:
                family.add_metric([kind, state], jobs.get((kind, state), 0))
        yield family
        now = time.time()
        ages = [now - beat for beat in beats]
        live = [age for age in ages if age <= self.settings.ready_worker_s]
        family = GaugeMetricFamily("geoloc_workers", "Worker processes not stopped, by liveness", labels=["state"])
        family.add_metric(["live"], len(live))
        family.add_metric(["stale"], len(ages) - len(live))
        yield family
        yield GaugeMetricFamily(
            "geoloc_worker_heartbeat_age_seconds", "Age of the oldest live worker's heartbeat (s)", max(live, default=0)
        )
        for metric, name, what in (
            ("geoloc_maps", "maps", "Maps by status"),
            ("geoloc_references", "references", "Reference photos by status"),
        ):
            family = GaugeMetricFamily(metric, what, labels=["status"])
            for status, count in sorted(catalogue[name].items()):
                family.add_metric([status], count)
            yield family
        yield GaugeMetricFamily(
            "geoloc_index_documents", "References in the SBoW retrieval index", catalogue["index"]["documents"]
        )


def exposition(settings: Settings) -> bytes:
    """The metrics of this machine's processes and the database's gauges, in Prometheus's text format."""
    from prometheus_client import CollectorRegistry, generate_latest, multiprocess

    registry = CollectorRegistry()
    folder = enabled_folder()
    if folder is not None:
        multiprocess.MultiProcessCollector(registry, path=str(folder))  # type: ignore[no-untyped-call]
    registry.register(DatabaseCollector(settings))
    return generate_latest(registry)


def _authorised(request: Request, key: str) -> bool:
    """Whether the request carries ``Authorization: Bearer KEY``."""
    scheme, _, credentials = request.headers.get("authorization", "").partition(" ")
    return scheme.lower() == "bearer" and secrets.compare_digest(credentials.strip().encode(), key.encode())


@router.get("/metrics", include_in_schema=False)
def metrics(request: Request) -> Response:
    """The Prometheus exposition (module docstring): 404 when off, 401 without the metrics key when one is set."""
    settings = app_settings(request)
    if not settings.metrics:
        raise ApiError(404, "not_found", "metrics are off on this service (GEOLOC_METRICS=false)")
    if settings.metrics_key and not _authorised(request, settings.metrics_key):
        raise ApiError(
            401,
            "unauthorized",
            "/metrics needs the metrics key: Authorization: Bearer KEY (GEOLOC_METRICS_KEY)",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return Response(exposition(settings), media_type=CONTENT_TYPE)
