"""Load benchmark: 64 concurrent clients for 2 minutes against a real service (prints figures; not a test).

    geoloc sim world --map ../shared/data/osm/helsinki.osm.pbf --out /tmp/w --references 60 --queries 30 --seed 1
    .venv/bin/python benchmarks/bench_load.py --world /tmp/w --json load.json

Starts ``geoloc serve --workers 2`` (the README's first command) on a free loopback port with a fresh data
folder (the built models linked from ``GEOLOC_DATA_DIR/cache/models``), uploads the Helsinki map, then runs
``--clients`` asyncio clients (``client.AsyncClient``, each request tried once: every answer counts)
for ``--duration-s``. Each client repeats: think 0.5-1.5 s, then one action, drawn as

- a read (70 %): ``GET /v1/maps/{id}``, ``/v1/maps``, ``/v1/references/{id}``, ``/v1/jobs/{id}`` or
  ``/v1/queries/{id}`` of something it made;
- a reference upload (15 %): a photo of the world's references (each is new once, then a duplicate);
- a query (15 %): a photo of the world's queries with ``wait_s`` 30; an answer not ready by then is awaited
  in the background (``GET /v1/queries/{id}?wait_s=30``, repeated) while the client goes on.

A ``429`` (queue full) is honoured: the client waits ``Retry-After`` before its next upload or query. After
the timed phase the benchmark waits for every accepted job to end and checks that each is ``done``. It
prints p50/p99/max latency of reads (overall, per endpoint, and while the workers were saturated: both
busy and jobs waiting) and of query answers (upload to answer), and writes everything to ``--json``.
Targets (exit code 1 if one is missed): no error but documented 429s, every accepted job done, reads under
100 ms at p99 and never over 1 s. ``--url`` runs against a service already running instead.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import random
import sqlite3
import sys
import tempfile
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import httpx
import numpy as np
from local_service import LocalService

from client import ApiError, AsyncClient, Query, RetryPolicy, Sent, ServiceUnreachableError, calls, pool_limits
from client.calls import Call
from contracts.settings import shared_path

READ_SHARE, UPLOAD_SHARE = 0.70, 0.15
"""The rest (15 %) are queries."""
T = TypeVar("T")
NO_RETRY = RetryPolicy(retries=0)
"""Each request tried once: a 429 or an error is what the figures count."""
THINK_S = (0.5, 1.5)
QUERY_WAIT_S = 30.0
READ_P99_TARGET_S = 0.100
READ_MAX_TARGET_S = 1.0
DRAIN_TIMEOUT_S = 1800.0


@dataclass
class Stats:
    """Everything the clients observed."""

    reads: list[tuple[float, str, float]] = field(default_factory=list)  # (start, endpoint, seconds)
    answers_s: list[float] = field(default_factory=list)
    statuses: Counter[str] = field(default_factory=Counter)
    errors: list[str] = field(default_factory=list)
    accepted_jobs: set[int] = field(default_factory=set)
    saturated: list[tuple[float, float]] = field(default_factory=list)  # (start, end) of saturated spans


def percentiles(values: list[float]) -> dict[str, float | int]:
    """Count, p50, p99 and max in milliseconds."""
    if not values:
        return {"count": 0}
    array = np.asarray(values) * 1e3
    return {
        "count": len(values),
        "p50_ms": round(float(np.percentile(array, 50)), 1),
        "p99_ms": round(float(np.percentile(array, 99)), 1),
        "max_ms": round(float(array.max()), 1),
    }


def _unread(_response: httpx.Response) -> None:
    """A read's answer is only timed and counted, never parsed (as before the client)."""


class Client:
    """One simulated user."""

    def __init__(self, http: AsyncClient, map_id: int, world: Path, stats: Stats, rng: random.Random) -> None:
        self.http, self.map_id, self.stats, self.rng = http, map_id, stats, rng
        self.references = sorted((world / "references").glob("*.jpg"))
        self.queries = sorted((world / "queries").glob("*.jpg"))
        self.mine: dict[str, list[int]] = defaultdict(list)
        self.busy_until = 0.0
        self.pollers: list[asyncio.Task[None]] = []

    async def run(self, stop_at: float) -> None:
        while time.monotonic() < stop_at:
            await asyncio.sleep(self.rng.uniform(*THINK_S))
            draw = self.rng.random()
            if draw < READ_SHARE or time.monotonic() < self.busy_until:
                await self.read()
            elif draw < READ_SHARE + UPLOAD_SHARE:
                await self.upload_reference()
            else:
                await self.ask()
        await asyncio.gather(*self.pollers)

    async def _request(self, call: Call[T], endpoint: str) -> Sent[T] | None:
        """One try of ``call`` (no retry: each answer is counted), None when it was not a 2xx."""
        try:
            sent = await self.http.call(call, retry=NO_RETRY)
        except ServiceUnreachableError as exc:
            self.stats.errors.append(f"{call.method} {endpoint}: {exc}")
            return None
        except ApiError as exc:
            self.stats.statuses[f"{call.method} {endpoint} {exc.status}"] += 1
            if exc.status == 429:
                self.busy_until = time.monotonic() + (exc.retry_after_s if exc.retry_after_s is not None else 5.0)
            else:
                self.stats.errors.append(f"{call.method} {endpoint}: {exc.status} {exc.code}: {exc.message}"[:240])
            return None
        self.stats.statuses[f"{call.method} {endpoint} {sent.status}"] += 1
        return sent

    async def read(self) -> None:
        choices: list[tuple[Call[Any], str]] = [(calls.get_map(self.map_id), "/v1/maps/{id}")]
        choices.append((calls.list_maps(), "/v1/maps"))
        for kind, template, make in (("reference", "/v1/references/{id}", calls.get_reference),
                                     ("job", "/v1/jobs/{id}", calls.get_job),
                                     ("query", "/v1/queries/{id}", calls.get_query)):  # fmt: skip
            if self.mine[kind]:
                choices.append((make(self.rng.choice(self.mine[kind])), template))
        call, endpoint = self.rng.choice(choices)
        await self._timed_read(call, endpoint)

    async def _timed_read(self, call: Call[Any], endpoint: str) -> None:
        started = time.monotonic()
        sent = await self._request(replace(call, read=_unread), endpoint)  # the answer timed, not parsed
        if sent is not None and sent.status == 200:
            self.stats.reads.append((started, endpoint, time.monotonic() - started))

    async def upload_reference(self) -> None:
        path = self.rng.choice(self.references)
        sent = await self._request(calls.upload_reference(self.map_id, path, {}), "/v1/maps/{id}/references")
        if sent is not None and sent.status in (200, 202):
            self.mine["reference"].append(sent.value.id)
            if sent.status == 202 and sent.value.job_id is not None:
                self.stats.accepted_jobs.add(sent.value.job_id)
                self.mine["job"].append(sent.value.job_id)

    async def ask(self) -> None:
        """Post a query and wait up to ``wait_s`` for its answer.

        An answer not ready by then is polled in the background while the client goes on (as an app
        would), until it comes.
        """
        path = self.rng.choice(self.queries)
        started = time.monotonic()
        upload = calls.upload_query(self.map_id, path, {"wait_s": QUERY_WAIT_S})
        sent = await self._request(upload, "/v1/maps/{id}/queries")
        if sent is None or sent.status not in (200, 202):
            return
        query = sent.value
        if query.job_id is not None:
            self.stats.accepted_jobs.add(query.job_id)
            self.mine["job"].append(query.job_id)
        self.mine["query"].append(query.id)
        if query.status in ("done", "failed"):
            self._answered(query, started)
        else:
            self.pollers.append(asyncio.create_task(self._poll(query.id, started)))

    async def _poll(self, query_id: int, started: float) -> None:
        """Long-poll the query (``wait_s``) until it is answered: a wait, not a read, in the figures."""
        while True:
            polled = await self._request(calls.get_query(query_id, QUERY_WAIT_S), "/v1/queries/{id}?wait_s")
            if polled is None or polled.status != 200:
                return
            if polled.value.status in ("done", "failed"):
                self._answered(polled.value, started)
                return

    def _answered(self, query: Query, started: float) -> None:
        if query.status == "done":
            self.stats.answers_s.append(time.monotonic() - started)


async def watch_saturation(db_path: Path | None, workers: int, stats: Stats, stop: asyncio.Event) -> None:
    """Record when every worker was busy and jobs were waiting (read-only look at the service's database)."""
    if db_path is None:
        return
    conn = sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=5)
    span_start: float | None = None
    try:
        while not stop.is_set():
            now = time.monotonic()
            running, queued = conn.execute(
                "SELECT SUM(status = 'running'), SUM(status = 'queued') FROM jobs"
            ).fetchone()
            saturated = (running or 0) >= workers and (queued or 0) > 0
            if saturated and span_start is None:
                span_start = now
            elif not saturated and span_start is not None:
                stats.saturated.append((span_start, now))
                span_start = None
            await asyncio.sleep(0.5)
        if span_start is not None:
            stats.saturated.append((span_start, time.monotonic()))
    finally:
        conn.close()


async def drain(http: AsyncClient, job_ids: set[int]) -> tuple[dict[str, int], list[str]]:
    """Wait until every accepted job has ended: the count per final status, and the errors of failed jobs."""
    deadline = time.monotonic() + DRAIN_TIMEOUT_S
    final: dict[int, str] = {}
    errors: list[str] = []
    while time.monotonic() < deadline:
        for job_id in sorted(job_ids - set(final)):
            body: dict[str, Any] = {}
            status: str
            try:
                job = (await http.call(calls.get_job(job_id), retry=NO_RETRY)).value
                body, status = job.model_dump(), job.status
            except ApiError as exc:
                status = f"http {exc.status}"
            if status in ("done", "failed", "cancelled") or status.startswith("http"):
                final[job_id] = status
                if status != "done":
                    errors.append(f"job {job_id} ({body.get('kind')}) {status}: {str(body.get('error'))[:600]}")
        if len(final) == len(job_ids):
            break
        await asyncio.sleep(2.0)
    counts = Counter(final.values())
    counts["not finished"] = len(job_ids) - len(final)
    return dict(counts), errors


async def run(args: argparse.Namespace, url: str, db_path: Path | None) -> dict[str, Any]:
    stats = Stats()
    # No pool limit: answers awaited in the background hold a connection each (up to wait_s), and a read
    # queued behind them in the client's pool would measure the pool, not the service.
    limits = pool_limits(max_connections=None)
    async with AsyncClient(url, timeout_s=120.0, limits=limits) as http:
        map_id = (await http.upload_map(shared_path("data", "osm", "helsinki.osm.pbf"), "helsinki")).id
        rngs = [random.Random(args.seed * 1000 + i) for i in range(args.clients)]
        clients = [Client(http, map_id, args.world, stats, rng) for rng in rngs]
        stop = asyncio.Event()
        watcher = asyncio.create_task(watch_saturation(db_path, args.workers, stats, stop))
        started = time.monotonic()
        print(f"{args.clients} clients for {args.duration_s:.0f} s against {url} (map {map_id})", flush=True)
        await asyncio.gather(*(client.run(started + args.duration_s) for client in clients))
        elapsed = time.monotonic() - started
        accepted = len(stats.accepted_jobs)
        print(f"clients done (answers polled) after {elapsed:.0f} s; checking the {accepted} accepted jobs", flush=True)
        t_drain = time.monotonic()
        jobs, job_errors = await drain(http, stats.accepted_jobs)
        stop.set()
        await watcher
        drain_s = time.monotonic() - t_drain

    in_saturation = [s for t, _, s in stats.reads if any(a <= t <= b for a, b in stats.saturated)]
    by_endpoint: dict[str, list[float]] = defaultdict(list)
    for _, endpoint, seconds in stats.reads:
        by_endpoint[endpoint].append(seconds)
    reads_all = [s for _, _, s in stats.reads]
    refused = sum(n for key, n in stats.statuses.items() if key.endswith(" 429"))
    return {
        "clients": args.clients,
        "duration_s": args.duration_s,
        "clients_done_s": round(elapsed, 1),
        "workers": args.workers,
        "requests": sum(stats.statuses.values()),
        "statuses": dict(sorted(stats.statuses.items())),
        "refused_429": refused,
        "errors": len(stats.errors),
        "error_samples": stats.errors[:20],
        "accepted_jobs": len(stats.accepted_jobs),
        "jobs": jobs,
        "job_errors": job_errors,
        "drain_s": round(drain_s, 1),
        "reads": percentiles(reads_all),
        "reads_while_saturated": percentiles(in_saturation),
        "saturated_s": round(sum(b - a for a, b in stats.saturated), 1),
        "reads_by_endpoint": {endpoint: percentiles(v) for endpoint, v in sorted(by_endpoint.items())},
        "query_answers": percentiles(stats.answers_s),
    }


def verdict(result: dict[str, Any]) -> list[tuple[str, bool]]:
    """The targets, each with whether it was met."""
    reads = result["reads"]
    return [
        ("no errors other than documented 429s", result["errors"] == 0),
        ("every accepted job ended done", result["jobs"].get("done", 0) == result["accepted_jobs"]),
        ("reads p99 under 100 ms", reads.get("p99_ms", 0) < READ_P99_TARGET_S * 1e3),
        ("no read over 1 s", reads.get("max_ms", 0) <= READ_MAX_TARGET_S * 1e3),
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--world", type=Path, required=True, help="a `geoloc sim world` folder")
    parser.add_argument("--clients", type=int, default=64)
    parser.add_argument("--duration-s", type=float, default=120.0)
    parser.add_argument("--workers", type=int, default=2, help="worker processes of the service it starts")
    parser.add_argument("--url", default=None, help="a running service instead of starting one (no API keys)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = parser.parse_args()
    if not (args.world / "references").is_dir():
        parser.error(f"{args.world} is not a simulated world (see `geoloc sim world`)")

    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    print(f"machine: {machine}")
    service = None
    with tempfile.TemporaryDirectory(prefix="geoloc-load-") as tmp:
        db_path = None
        if args.url is None:
            service = LocalService(Path(tmp) / "data", workers=args.workers)
            url, db_path = service.url, service.database_path
        else:
            url = args.url
        try:
            result = asyncio.run(run(args, url, db_path))
        finally:
            if service is not None:
                service.stop()
    result["machine"] = machine
    result["command"] = " ".join(sys.argv)

    print(json.dumps({k: result[k] for k in ("requests", "refused_429", "errors", "accepted_jobs", "jobs",
                                             "drain_s", "saturated_s")}))  # fmt: skip
    for name in ("reads", "reads_while_saturated", "query_answers"):
        print(f"{name:22s} {result[name]}")
    for endpoint, figures in result["reads_by_endpoint"].items():
        print(f"  GET {endpoint:26s} {figures}")
    for sample in result["error_samples"][:5] + result["job_errors"][:5]:
        print(f"error: {sample}")
    checks = verdict(result)
    result["targets"] = {name: met for name, met in checks}
    for name, met in checks:
        print(f"{'ok  ' if met else 'MISS'} {name}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0 if all(met for _, met in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
