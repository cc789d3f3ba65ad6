"""The system's answers: jobs, health, readiness and ``/v1/about`` (the licences)."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import ConfigDict, Field

from contracts.api.base import ApiModel
from contracts.jobs import JobStatus


class JobOut(ApiModel):
    """A background job."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": 7,
                    "kind": "label_reference",
                    "status": "running",
                    "attempts": 1,
                    "max_attempts": 3,
                    "payload": {"reference_id": 3, "map_id": 1},
                    "result": None,
                    "error": None,
                    "created_at": "2025-01-01T12:00:00Z",
                    "updated_at": "2025-01-01T12:00:01Z",
                    "started_at": "2025-01-01T12:00:01Z",
                    "finished_at": None,
                }
            ]
        }
    )

    id: int
    kind: str
    status: JobStatus
    attempts: int
    max_attempts: int
    payload: dict[str, Any]
    result: dict[str, Any] | None = None
    error: str | None = Field(default=None, description="Last error with a traceback summary")
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None


class Health(ApiModel):
    """Liveness: the process answers."""

    status: str = Field(examples=["ok"])


class Readiness(ApiModel):
    """What ``/readyz`` checked: the database, the broker (distributed profile), the models, live workers."""

    status: Literal["ready", "not_ready"]
    profile: Literal["embedded", "distributed"] = Field(
        description="`embedded` (SQLite, built-in workers) or `distributed` (PostgreSQL, Celery on Redis)"
    )
    database: Literal["ok", "unreachable"]
    broker: Literal["ok", "unreachable"] | None = Field(
        default=None, description="The Celery broker (Redis); null in the embedded profile, which has none"
    )
    schema_version: int
    expected_schema_version: int
    live_workers: int = Field(
        description="Worker processes that take queries and references (not those that only parse maps) with a "
        "heartbeat within `GEOLOC_READY_WORKER_S`"
    )
    problems: list[str] = Field(default_factory=list)


class LicenseOut(ApiModel):
    """One thing the service is built from and its licence (:data:`contracts.licenses.LICENSES`)."""

    name: str = Field(examples=["ALIKED keypoint weights (aliked-n16)"])
    license: str = Field(examples=["BSD-3-Clause"])
    source: str = Field(examples=["github.com/Shiaoming/ALIKED@683d7c6 (LICENSE, © 2022 Zhao Xiaoming)"])
    kind: Literal["model", "dataset", "map data", "dependency"]


class About(ApiModel):
    """The service's version and the licences of its models, data and main dependencies."""

    name: str = Field(examples=["geoloc"])
    version: str = Field(examples=["0.1.0"])
    map_attribution_default: str = Field(
        description="The attribution of a map whose upload states none", examples=["© OpenStreetMap contributors"]
    )
    licenses: list[LicenseOut]
