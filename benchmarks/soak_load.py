"""The soak benchmark's mixed load (``benchmarks/bench_soak.py``): each action, and what it saw.

:class:`Load` posts queries and waits for their answers (deleting a quarter, leaving the rest to retention), uploads
reference photos and deletes them after a while, uploads small maps, reads what exists; each request is tried once
and counted, its errors kept with their times (:data:`Stats.error_events`), over one API process or each of a
deployment's in turn. A query's polls wait out a ``503``'s ``Retry-After``, as a client does through an outage.
"""

from __future__ import annotations

import asyncio
import random
import time
from collections import Counter
from dataclasses import dataclass, field
from itertools import cycle
from pathlib import Path
from typing import Any, TypeVar

from client import ApiError, AsyncClient, RetryPolicy, Sent, ServiceUnreachableError, calls
from client.calls import Call
from contracts.settings import shared_path
from geoloc.sim.world import load_world
from workers.retention import purge_interval_s

T = TypeVar("T")
NO_RETRY = RetryPolicy(retries=0)
"""Each request tried once: every answer counts."""
QUERY_WAIT_S = 30.0
REFERENCE_LIFE_S = 30.0
DELETE_QUERY_SHARE = 0.25
FINAL = ("done", "failed", "cancelled")
DRAIN_TIMEOUT_S = 900.0
RETRY_AFTER_MAX_S = 10.0
"""Longest pause before polling again after a ``503`` (its ``Retry-After``, else a second)."""


@dataclass
class Stats:
    """What the load saw: per-action counts, errors, 429s, accepted jobs and their outcomes."""

    ops: Counter[str] = field(default_factory=Counter)
    errors: Counter[str] = field(default_factory=Counter)
    error_samples: list[str] = field(default_factory=list)
    error_events: list[dict[str, Any]] = field(default_factory=list)  # per error: sent and answered (s), status, ...
    refused: Counter[str] = field(default_factory=Counter)
    accepted: dict[int, str] = field(default_factory=dict)  # job id -> kind
    outcome: dict[int, str] = field(default_factory=dict)  # job id -> final status ("gone": 404)
    failure_reasons: dict[int, str] = field(default_factory=dict)  # failed job id -> its error ("" when none)
    per_api: Counter[str] = field(default_factory=Counter)  # requests sent to each API process (its URL)
    queries_kept: list[tuple[float, int]] = field(default_factory=list)  # (created monotonic, id), left to retention
    live_references: dict[int, int] = field(default_factory=dict)  # reference id -> job id
    held_photos: set[Path] = field(default_factory=set)


class Load:
    """The mixed load on one service; ``map_id``: the Helsinki map the references and queries go to.

    Given several clients (a deployment's API processes), each request goes to the next in turn.
    """

    def __init__(self, https: list[AsyncClient], map_id: int, world: Path, retention_s: float, seed: int) -> None:
        loaded = load_world(world)
        self.clients, self.map_id, self.retention_s = cycle(https), map_id, retention_s
        self.references = [im.path for im in loaded.references]
        self.queries = [im.path for im in loaded.queries]
        self.rng = random.Random(seed)
        self.stats = Stats()
        self.t0 = time.monotonic()
        """The start of the load (:data:`Stats.error_events` times are seconds from it)."""

    @property
    def http(self) -> AsyncClient:
        """The client of the next request: each API process in turn."""
        client = next(self.clients)
        self.stats.per_api[str(client.base_url)] += 1
        return client

    def error(self, key: str, text: str, sent: float, status: int, retry_after_s: float | None) -> None:
        """Count an error (``key``: request, status, code) and keep it with its times (monotonic ``sent``)."""
        self.stats.errors[key] += 1
        if len(self.stats.error_samples) < 50:
            self.stats.error_samples.append(f"{key}: {text}"[:300])
        self.stats.error_events.append({"t_s": round(sent - self.t0, 2), "end_s": round(time.monotonic() - self.t0, 2),
                                        "status": status, "key": key, "retry_after_s": retry_after_s,
                                        "text": text[:200]})  # fmt: skip

    async def request(self, call: Call[T], endpoint: str, *, retry_503: bool = False) -> Sent[T] | None:
        """One try of ``call``; None (and counted) when it did not answer 2xx.

        retry_503: a ``503`` (counted) is tried again after its ``Retry-After`` (at most :data:`RETRY_AFTER_MAX_S`),
        for up to :data:`DRAIN_TIMEOUT_S`, as a client waiting for an answer does through an outage.
        """
        self.stats.ops[f"{call.method} {endpoint}"] += 1
        deadline = time.monotonic() + DRAIN_TIMEOUT_S
        while True:
            sent = time.monotonic()
            try:
                return await self.http.call(call, retry=NO_RETRY)
            except ServiceUnreachableError as exc:
                self.error(f"{call.method} {endpoint} unreachable", str(exc), sent, 0, None)
                return None
            except ApiError as exc:
                key = f"{call.method} {endpoint} {exc.status} {exc.code}"
                if exc.status == 429:
                    self.stats.refused[key] += 1
                    return None
                self.error(key, exc.message, sent, exc.status, exc.retry_after_s)
                if not (retry_503 and exc.status == 503 and time.monotonic() < deadline):
                    return None
                await asyncio.sleep(min(exc.retry_after_s or 1.0, RETRY_AFTER_MAX_S))

    async def job_outcome(self, job_id: int, timeout_s: float = DRAIN_TIMEOUT_S) -> str | None:
        """Poll a job until it ends: its final status, ``gone`` on 404, None on timeout.

        A failed job's error goes to :data:`Stats.failure_reasons`; an error answer other than 404 is counted
        (as ``GET /v1/jobs/{id} (poll)``), and polling goes on.
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            sent = time.monotonic()
            try:
                job = (await self.http.call(calls.get_job(job_id), retry=NO_RETRY)).value
            except ApiError as exc:
                if exc.status == 404:
                    return "gone"
                self.error(f"GET /v1/jobs/{{id}} (poll) {exc.status} {exc.code}", exc.message, sent, exc.status,
                           exc.retry_after_s)  # fmt: skip
                await asyncio.sleep(1.0)
                continue
            except ServiceUnreachableError as exc:
                self.error("GET /v1/jobs/{id} (poll) unreachable", str(exc), sent, 0, None)
                await asyncio.sleep(1.0)
                continue
            if job.status in FINAL:
                if job.status == "failed":
                    self.stats.failure_reasons[job_id] = job.error or ""
                return str(job.status)
            await asyncio.sleep(1.0)
        return None

    async def query(self, photo: Path | None = None, wait_s: float = QUERY_WAIT_S) -> None:
        """Post a query, wait for its answer, then delete it or leave it to retention."""
        created = time.monotonic()  # before the upload, which waits up to wait_s: the row is as old as this
        sent = await self.request(
            calls.upload_query(self.map_id, photo or self.rng.choice(self.queries), {"wait_s": wait_s}),
            "/v1/maps/{id}/queries",
        )
        if sent is None:
            return
        query = sent.value
        if query.job_id is not None:
            self.stats.accepted[query.job_id] = "query"
        while query.status not in ("done", "failed"):
            polled = await self.request(
                calls.get_query(query.id, QUERY_WAIT_S), "/v1/queries/{id}?wait_s", retry_503=True
            )
            if polled is None:
                return
            query = polled.value
        if query.job_id is not None:
            self.stats.outcome[query.job_id] = query.status
            if query.status == "failed":
                self.stats.failure_reasons[query.job_id] = query.error or ""
        if self.rng.random() < DELETE_QUERY_SHARE:
            await self.request(calls.delete("queries", query.id), "/v1/queries/{id}")
        else:
            self.stats.queries_kept.append((created, query.id))

    async def reference(self) -> None:
        """Upload a reference photo not held now, wait for its job, keep it a while, delete it."""
        free = [p for p in self.references if p not in self.stats.held_photos]
        if not free:
            return
        photo = self.rng.choice(free)
        self.stats.held_photos.add(photo)
        try:
            sent = await self.request(calls.upload_reference(self.map_id, photo, {}), "/v1/maps/{id}/references")
            if sent is None or sent.value.job_id is None:
                return
            reference = sent.value
            self.stats.accepted[reference.job_id] = "reference"
            outcome = await self.job_outcome(reference.job_id)
            if outcome is not None:
                self.stats.outcome[reference.job_id] = outcome
            self.stats.live_references[reference.id] = reference.job_id
            await asyncio.sleep(REFERENCE_LIFE_S)
            del self.stats.live_references[reference.id]
            await self.request(calls.delete("references", reference.id), "/v1/references/{id}")
        finally:
            self.stats.held_photos.discard(photo)

    async def small_map(self) -> None:
        """Upload the small map, read it, list maps, delete it."""
        path = shared_path("data", "osm", "germany_patch.osm")
        sent = await self.request(calls.upload_map(path, "soak-small", {}), "/v1/maps")
        if sent is None:
            return
        await self.request(calls.get_map(sent.value.id), "/v1/maps/{id}")
        await self.request(calls.list_maps(), "/v1/maps")
        await self.request(calls.delete("maps", sent.value.id), "/v1/maps/{id}")

    async def read(self) -> None:
        """One read of something that exists now (queries younger than half the retention)."""
        choices: list[tuple[Call[Any], str]] = [
            (calls.get_map(self.map_id), "/v1/maps/{id}"),
            (calls.list_maps(), "/v1/maps"),
            (calls.list_references(self.map_id, 0, 20), "/v1/maps/{id}/references"),
        ]
        if self.stats.live_references:
            reference_id, job_id = self.rng.choice(list(self.stats.live_references.items()))
            choices.append((calls.get_reference(reference_id), "/v1/references/{id}"))
            choices.append((calls.get_job(job_id), "/v1/jobs/{id}"))
        recent = [qid for created, qid in self.stats.queries_kept[-20:]
                  if time.monotonic() - created < self.retention_s / 2]  # fmt: skip
        if recent:
            choices.append((calls.get_query(self.rng.choice(recent)), "/v1/queries/{id}"))
        call, endpoint = self.rng.choice(choices)
        await self.request(call, endpoint)

    async def saturation_qps(self, count: int) -> float:
        """Post ``count`` queries at once (no wait); queries answered per second until the last is done."""
        started = time.monotonic()
        await asyncio.gather(*(self.query(self.queries[i % len(self.queries)], wait_s=0.0) for i in range(count)))
        return count / (time.monotonic() - started)

    async def retention_check(self) -> dict[str, int]:
        """How many kept queries older than the retention (and a purge period) are gone (up to 200 looked at)."""
        margin = self.retention_s + 2 * purge_interval_s(self.retention_s) + 5.0
        old = [qid for created, qid in self.stats.queries_kept if time.monotonic() - created > margin]
        pruned = 0
        for query_id in old[-200:]:
            try:
                await self.http.call(calls.get_query(query_id), retry=NO_RETRY)
            except ApiError as exc:
                pruned += exc.status == 404
        return {"older_than_retention": len(old[-200:]), "pruned": pruned}
