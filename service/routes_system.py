"""Health, readiness, the licences (``/v1/about``) and jobs."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse

from contracts.api import About, ErrorResponse, Health, JobOut, Readiness
from contracts.licenses import about_document
from contracts.settings import Settings
from db import LATEST_VERSION, Database, schema_version
from db import jobs as job_store
from db.outages import outage_reason
from db.rows import JobRow
from service.auth import Caller, request_caller, require_read
from service.bounds import JobId
from service.deps import app_settings, get_db, open_db
from service.errors import error_body
from service.responses import error_responses, timestamp
from service.tenancy import require_job
from workers.broker import broker_problem
from workers.context import model_problems, runs_method_jobs

router = APIRouter()
MODEL_CHECK_TTL_S = 10.0
"""``/readyz`` re-checks the built models (which hashes the weights) at most this often."""
_model_check: dict[str, tuple[float, list[str]]] = {}
_model_check_lock = threading.Lock()


def model_problems_cached(settings: Settings) -> list[str]:
    """:func:`workers.context.model_problems` for the app's data folder, cached for :data:`MODEL_CHECK_TTL_S`."""
    key = str(settings.data_dir)
    with _model_check_lock:
        checked_at, problems = _model_check.get(key, (-MODEL_CHECK_TTL_S, []))
        if time.monotonic() - checked_at >= MODEL_CHECK_TTL_S:
            problems = model_problems()
            _model_check[key] = (time.monotonic(), problems)
    return problems


def _writable(database: Path) -> bool:
    """Whether the embedded database's file and folder (its WAL and journal live there) can be written."""
    return os.access(database, os.W_OK) and os.access(database.parent, os.W_OK | os.X_OK)


@router.get("/healthz", response_model=Health, tags=["system"])
def healthz() -> Health:
    """The process is alive."""
    return Health(status="ok")


@router.get("/v1/about", response_model=About, tags=["system"], dependencies=[Depends(require_read)])
def about() -> About:
    """The service's version and the licence table: model weights, their data sets, the map data, dependencies.

    Scope ``read``, like every ``/v1`` read (whoever may see the data may see its licences). The same table as
    ``geoloc about`` and docs/licenses.md (:data:`contracts.licenses.LICENSES`).
    """
    return About.model_validate(about_document())


@router.get("/readyz", response_model=Readiness, responses={503: {"model": ErrorResponse}}, tags=["system"])
def readyz(request: Request) -> Readiness | JSONResponse:
    """Report whether the service can take work; 503 with every reason in ``problems`` when not.

    Ready when the database answers at the current schema version, the broker answers (distributed
    profile), the models the workers need are built and current, and a worker that takes queries and references
    has a recent heartbeat (a worker that only parses maps, as ``serve --workers 0`` runs one, is not counted).
    """
    settings = app_settings(request)
    problems: list[str] = []
    version, workers, database_ok = -1, 0, False
    try:
        db = open_db(settings, lock_timeout_s=2.0)
        try:
            db.execute("SELECT 1").fetchone()
            version = schema_version(db)
            live = job_store.live_workers(db, settings.ready_worker_s)
            workers = sum(runs_method_jobs(job_store.claimed_kinds(worker)) for worker in live)
            database_ok = True
        finally:
            db.close()
    except Exception as exc:  # any failure means "not ready"; the reason without paths
        problems.append(f"database unreachable: {outage_reason(exc)}")
    if database_ok and not settings.database_url and not _writable(settings.database_path):
        database_ok = False
        problems.append("database is read-only: its file or folder cannot be written")
    broker: Literal["ok", "unreachable"] | None = None
    if settings.broker_url is not None:
        broker_error = broker_problem(settings.broker_url)
        broker = "ok" if broker_error is None else "unreachable"
        if broker_error is not None:
            problems.append(broker_error)
    if version != LATEST_VERSION and version >= 0:
        problems.append(f"database schema version {version}, expected {LATEST_VERSION}")
    problems += model_problems_cached(settings)
    if workers == 0:
        problems.append(f"no worker that takes queries has a heartbeat in the last {settings.ready_worker_s:.0f} s")
    readiness = Readiness(
        status="not_ready" if problems else "ready",
        profile="distributed" if settings.distributed else "embedded",
        database="ok" if database_ok else "unreachable",
        broker=broker,
        schema_version=version,
        expected_schema_version=LATEST_VERSION,
        live_workers=workers,
        problems=problems,
    )
    if problems:
        return JSONResponse(error_body("not_ready", "; ".join(problems), readiness.model_dump()), status_code=503)
    return readiness


def job_out(job: JobRow) -> JobOut:
    """A job row as its API model."""
    return JobOut(
        id=job["id"],
        kind=job["kind"],
        status=job["status"],
        attempts=job["attempts"],
        max_attempts=job["max_attempts"],
        payload=job["payload"],
        result=job["result"],
        error=job["error"],
        created_at=timestamp(job["created_at"]),
        updated_at=timestamp(job["updated_at"]),
        started_at=timestamp(job["started_at"]),
        finished_at=timestamp(job["finished_at"]),
    )


@router.get(
    "/v1/jobs/{job_id}",
    response_model=JobOut,
    responses=error_responses(404),
    tags=["jobs"],
    dependencies=[Depends(require_read)],
)
def get_job(job_id: JobId, db: Database = Depends(get_db), caller: Caller = Depends(request_caller)) -> JobOut:
    """A background job: status, attempts, result or last error (404 for a job of another tenant's map)."""
    return job_out(require_job(db, job_id, caller.tenant))
