"""Queries and tracks: a query (:class:`QueryOut`), a track (:class:`TrackOut`) and a track's JSON request."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import ConfigDict, Field

from contracts.answers import QueryResult, TrackFrameResult, TrackSearch
from contracts.api.base import ApiModel, Attribution
from contracts.jobs import WorkStatus
from contracts.queries import QueryPreset


class QueryOut(ApiModel):
    """A query: its status and, when done, its answer."""

    id: int = Field(examples=[5])
    map_id: int = Field(examples=[1])
    status: WorkStatus
    error: str | None = None
    job_id: int | None = Field(default=None, examples=[93])
    params: dict[str, Any] = Field(examples=[{"top_n": 10, "k": 4, "prior": {"lat": 60.1695, "lon": 24.9412}}])
    result: QueryResult | None = None
    attribution: Attribution
    created_at: datetime | None = None
    updated_at: datetime | None = None


class TrackOut(ApiModel):
    """A track: its status, its frames in order (each with its pose once located) and how it was searched."""

    id: int = Field(examples=[3])
    map_id: int = Field(examples=[1])
    status: WorkStatus
    error: str | None = None
    job_id: int | None = Field(default=None, examples=[120])
    params: dict[str, Any] = Field(examples=[{"order": "sent", "top_n": 10, "k": 4, "preset": "balanced"}])
    frames: list[TrackFrameResult]
    search: TrackSearch | None = None
    timings_ms: dict[str, float] | None = None
    attribution: Attribution
    created_at: datetime | None = None
    updated_at: datetime | None = None


class FramePrior(ApiModel):
    """One frame's priors, as a query's form fields (WGS84 degrees, metres, degrees from north)."""

    model_config = ConfigDict(extra="forbid")

    lat: float | None = None
    lon: float | None = None
    radius_m: float | None = None
    heading_deg: float | None = None
    place: str | None = Field(default=None, max_length=200)


class TrackFromQueries(ApiModel):
    """``POST /v1/maps/{id}/tracks`` with a JSON body: a track of earlier queries of the same map, in order."""

    model_config = ConfigDict(extra="forbid")

    query_ids: list[int] = Field(min_length=1, description="The queries whose photos are the frames, in order")
    by_capture_time: bool = Field(default=False, description="Order the frames by their photos' capture time")
    top_n: int = Field(default=10, ge=1, le=50, description="How many distinct locations each frame's answer holds")
    k: int = Field(default=4, ge=1, le=20, description="How many references to retrieve for identities")
    preset: QueryPreset | None = Field(default=None, description="fast, balanced or accurate")
    wait_s: float = Field(default=60.0, ge=0, le=300, description="How long to wait for the answer before 202")
