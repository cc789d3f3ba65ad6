"""Soak benchmark: an hour of mixed load at half the saturation rate; memory, fds, sizes and errors over time.

    .venv/bin/python benchmarks/bench_soak.py --profile embedded --out soak.json      # an hour (--duration-s 3600)
    .venv/bin/python benchmarks/bench_soak.py --profile distributed --out soak-distributed.json   # with restarts

Starts ``geoloc serve --workers N`` with the query retention short (``GEOLOC_QUERY_RETENTION_S`` a
fifteenth of the run, at least 60 s: well above a query's wait for its answer, or a query could be pruned
before the load sees it answered), so that the workers' retention prunes queries during the run, and
uploads the Helsinki map. ``--profile distributed`` deploys apart instead, on a private PostgreSQL cluster and
``redis-server`` (``testbed.servers``, as ``bench_ingest.py`` does): one ``geoloc worker --concurrency N`` (a Celery
worker: its main process and N pool processes) and two API processes, ``geoloc serve --workers 0`` each on its own
port over the same data folder, database and broker; the load sends each request to the next API in turn.
Unless ``--rate`` is given it first measures saturation: ``6 x workers`` queries
posted at once, queries answered per second while every worker is busy; it then runs at half that rate.
Each tick (``1 / rate`` seconds apart, jittered) it

- posts a query photo of ``--world`` and waits for its answer (``wait_s``, then long polls, each polled again after
  a ``503``'s ``Retry-After``); a quarter of the answered queries are deleted (``DELETE /v1/queries/{id}``), the
  rest are left for retention;
- makes three reads: ``GET`` the map, the map list, a page of references, a live reference, a recent query, or
  a live reference's job;
- every fourth tick, uploads a reference photo not held now, waits for its labelling job, and deletes the
  reference half a minute later (so the same photo is new again next time);
- every 30 s, uploads a small map (``germany_patch.osm``), reads it, lists maps and deletes it.

Every ``--sample-s`` it samples (:mod:`soak_checks`) the resident memory and open fds of every supervisor, every
API process, the worker pool's own process (``pool``, :meth:`LocalService.worker_roles`: the forking pool, or the
Celery worker's main process) and each worker process, the database and store sizes and the queue depth (none
while PostgreSQL is down). After the run it waits for every accepted job to end (at most 15 minutes for all) and
checks that queries older than the retention are gone (pruned). Errors are counted by request, status and code, and
each is kept with its times (sent, answered: seconds into the load); ``429`` answers apart.

Distributed, the run restarts each server once: PostgreSQL is stopped (``pg_ctl stop -m fast``: its sessions end)
at ``--restart-postgres-at-s`` (default a third of the run) and started again ``--outage-s`` (default 20) later;
Redis is killed at ``--restart-redis-at-s`` (default two thirds) and started again, empty, as long after. The
report's ``outages`` hold each window: ``start_s`` (the stop asked), ``down_s`` (stopped), ``end_s`` (listening
again), seconds into the load.

The verdict (issue 22): no errors but 429s, every accepted job done, resident memory within 10 % of its level at the
mark (10 minutes into an hour, a sixth of a shorter run), no growth in open fds; the exit code is 1 when a check
fails. Distributed (issue 51), the errors and jobs are judged instead by: each server restarted once; every error a
``503`` whose request (sent to answered) overlaps an outage window or the 15 s after its end
(:data:`soak_checks.OUTAGE_GRACE_S`: an API finds its pooled connections dead as it next uses them), nothing else
(no ``500``, no request unanswered); every ``503`` with ``Retry-After``; 0 lost jobs: every accepted job ended
``done``, or ``failed`` with a reason; and two API processes sampled. The memory and fd checks are the same, for
every process. The machine may be shared: the load average is in each sample.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import platform
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from local_service import LocalService, LocalWorkers, Supervised, prepare_data_dir
from soak_checks import OUTAGE_GRACE_S, process_checks, sample, under_load, unexcused_errors, verdict
from soak_load import DRAIN_TIMEOUT_S, Load

from client import AsyncClient, pool_limits
from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world
from workers.retention import purge_interval_s

READS_PER_TICK = 3
REFERENCE_EVERY = 4
"""Ticks per reference upload."""
MAP_EVERY_S = 30.0
MARK_S, HOUR_S = 600.0, 3600.0
API_PROCESSES = 2
"""API processes of the distributed profile (``geoloc serve --workers 0`` each); the load alternates between them."""
OUTAGE_S = 20.0


@dataclass
class Deployment:
    """The processes under test, on one data folder (and database).

    ``apis``: ``geoloc serve`` processes (the embedded profile's one runs the workers too); ``workers``: the
    distributed profile's ``geoloc worker`` beside them.
    """

    apis: list[LocalService]
    data_dir: Path
    database_url: str | None = None
    workers: LocalWorkers | None = None

    def roles(self) -> dict[str, list[int]]:
        """The pids to sample by role: every ``supervisor``, ``api`` process, worker ``pool`` and ``worker``."""
        supervised: list[Supervised] = [*self.apis, *([self.workers] if self.workers else [])]
        roles = {"supervisor": [s.process.pid for s in supervised],
                 "api": [pid for api in self.apis for pid in api.pids(b"service")]}  # fmt: skip
        for each in supervised:
            for role, pids in each.worker_roles().items():
                roles.setdefault(role, []).extend(pids)
        return roles

    def stop(self) -> None:
        """Stop the API processes, then the workers."""
        for each in [*self.apis, *([self.workers] if self.workers else [])]:
            each.stop()


async def sampler(deployment: Deployment, every_s: float, t0: float, out: list[dict[str, Any]],
                  stop: asyncio.Event) -> None:  # fmt: skip
    """Sample every ``every_s`` until ``stop``, printing a line per sample."""
    while True:
        row = await asyncio.to_thread(
            sample, time.monotonic() - t0, deployment.roles(), deployment.data_dir, deployment.database_url
        )
        row["load_average"] = round(os.getloadavg()[0], 2)
        out.append(row)
        rss = " ".join(
            f"{name.split()[0]}={p['rss_mb']:.0f}MB(uss {p.get('uss_mb', float('nan')):.0f})/{p['fds']}fd"
            for name, p in row["processes"].items()
        )
        queued, db_mb = ("-", "-") if row["queued"] is None else (row["queued"], f"{row['db_bytes'] / 1e6:.1f}")
        print(f"t={row['t_s']:6.0f}s queued={queued:>3} db={db_mb}MB "
              f"store={row['store_bytes'] / 1e6:.1f}MB load={row['load_average']} {rss}", flush=True)  # fmt: skip
        try:
            await asyncio.wait_for(stop.wait(), every_s)
            return
        except TimeoutError:
            pass


async def outage(server: str, at_s: float, down_s: float, halt: Callable[[], None], resume: Callable[[], None],
                 t0: float, out: list[dict[str, Any]]) -> None:  # fmt: skip
    """At ``at_s`` into the run stop ``server`` (``halt``), keep it down ``down_s``, start it (``resume``).

    Appends the window to ``out``: ``start_s`` (the stop asked), ``down_s`` (stopped), ``end_s`` (listening again),
    seconds from ``t0``.
    """
    await asyncio.sleep(max(0.0, t0 + at_s - time.monotonic()))
    start = time.monotonic()
    print(f"t={start - t0:6.0f}s stopping {server} for {down_s:.0f} s", flush=True)
    await asyncio.to_thread(halt)
    down = time.monotonic()
    await asyncio.sleep(down_s)
    await asyncio.to_thread(resume)
    end = time.monotonic()
    out.append({"server": server, "start_s": round(start - t0, 2), "down_s": round(down - t0, 2),
                "end_s": round(end - t0, 2)})  # fmt: skip
    print(f"t={end - t0:6.0f}s {server} back (down {end - down:.1f} s)", flush=True)


async def run(args: argparse.Namespace, deployment: Deployment, servers: list[Any]) -> dict[str, Any]:
    """The load, the samples and (``servers``: PostgreSQL and Redis, distributed) their restarts; the report."""
    limits = pool_limits(max_connections=None)
    async with contextlib.AsyncExitStack() as stack:
        https = [await stack.enter_async_context(AsyncClient(api.url, timeout_s=120.0, limits=limits))
                 for api in deployment.apis]  # fmt: skip
        map_id = (await https[0].upload_map(shared_path("data", "osm", "helsinki.osm.pbf"), "helsinki")).id
        load = Load(https, map_id, args.world, args.retention_s, args.seed)
        saturation = None
        if args.rate is None:
            saturation = await load.saturation_qps(6 * args.workers)
            print(f"saturation: {saturation:.2f} queries/s with {args.workers} workers busy", flush=True)
        rate = args.rate if saturation is None else saturation / 2
        samples: list[dict[str, Any]] = []
        windows: list[dict[str, Any]] = []
        stop = asyncio.Event()
        t0 = load.t0 = time.monotonic()
        watcher = asyncio.create_task(sampler(deployment, args.sample_s, t0, samples, stop))
        tasks: set[asyncio.Task[None]] = set()
        restarts = []
        if servers:
            postgres, redis = servers
            restarts = [
                asyncio.create_task(outage("postgres", args.restart_postgres_at_s, args.outage_s, postgres.halt,
                                           postgres.resume, t0, windows)),
                asyncio.create_task(outage("redis", args.restart_redis_at_s, args.outage_s, redis.stop, redis.start,
                                           t0, windows)),
            ]  # fmt: skip

        def spawn(action: Any) -> None:
            task = asyncio.create_task(action)
            tasks.add(task)
            task.add_done_callback(tasks.discard)

        print(f"load at {rate:.2f} queries/s for {args.duration_s:.0f} s", flush=True)
        tick, next_map = 0, t0
        while (now := time.monotonic()) < t0 + args.duration_s:
            spawn(load.query())
            for _ in range(READS_PER_TICK):
                spawn(load.read())
            if tick % REFERENCE_EVERY == 0:
                spawn(load.reference())
            if now >= next_map:
                spawn(load.small_map())
                next_map = now + MAP_EVERY_S
            tick += 1
            await asyncio.sleep(load.rng.uniform(0.5, 1.5) / rate)
        print(f"load done after {time.monotonic() - t0:.0f} s; waiting for {len(tasks)} actions", flush=True)
        t_drain = time.monotonic()
        await asyncio.gather(*restarts)  # a restart set past the load's end (given by hand) ends before the drain
        await asyncio.gather(*tasks)
        stats = load.stats
        deadline = time.monotonic() + DRAIN_TIMEOUT_S  # one bound for the whole drain: a stuck job is not waited twice
        for job_id in sorted(set(stats.accepted) - set(stats.outcome)):
            if (outcome := await load.job_outcome(job_id, max(0.0, deadline - time.monotonic()))) is not None:
                stats.outcome[job_id] = outcome
        drain_s = time.monotonic() - t_drain
        await asyncio.sleep(max(0.0, args.retention_s + 2 * purge_interval_s(args.retention_s) + 6 - drain_s))
        retention = await load.retention_check()
        stop.set()
        await watcher
    outcomes = Counter(stats.outcome.values())
    failed = [job_id for job_id, outcome in stats.outcome.items() if outcome == "failed"]
    report = {
        "profile": args.profile,
        "duration_s": args.duration_s,
        "workers": args.workers,
        "api_processes": len(deployment.apis),
        "saturation_qps": None if saturation is None else round(saturation, 3),
        "rate_qps": round(rate, 3),
        "retention_s": args.retention_s,
        "sample_s": args.sample_s,
        "mark_s": args.mark_s or args.duration_s * MARK_S / HOUR_S,
        "drain_s": round(drain_s, 1),
        "requests": dict(sorted(stats.ops.items())),
        "requests_per_api": dict(stats.per_api),
        "errors": dict(stats.errors),
        "error_samples": stats.error_samples,
        "error_events": stats.error_events,
        "refused_429": dict(stats.refused),
        "jobs": {
            "accepted": len(stats.accepted),
            "done": outcomes["done"],
            "failed": outcomes["failed"],
            "failed_without_reason": sum(not stats.failure_reasons.get(job_id) for job_id in failed),
            "cancelled": outcomes["cancelled"],
            "gone": outcomes["gone"],
            "unfinished": len(set(stats.accepted) - set(stats.outcome)),
        },  # fmt: skip
        "failure_reasons": dict(Counter(stats.failure_reasons.get(job_id, "") for job_id in failed).most_common(20)),
        "retention": retention,
        "samples": samples,
    }
    if servers:
        report |= {"outages": sorted(windows, key=lambda w: w["start_s"]), "outage_grace_s": OUTAGE_GRACE_S}
    return report


def summary(report: dict[str, Any]) -> dict[str, Any]:
    """The figures a reader wants first: sizes and queue at the start and the end, and the per-process checks.

    Beside them the errors by status and, in the distributed profile, the outages and the errors none excuses.
    """
    first, last = report["samples"][0], report["samples"][-1]
    with_db = [s for s in report["samples"] if s["queued"] is not None]  # not those taken while PostgreSQL was down
    figures = {
        "db_mb": [round(with_db[0]["db_bytes"] / 1e6, 2), round(with_db[-1]["db_bytes"] / 1e6, 2)],
        "store_mb": [round(first["store_bytes"] / 1e6, 2), round(last["store_bytes"] / 1e6, 2)],
        "queued_max": max(s["queued"] for s in with_db),
        "load_average_mean": round(sum(s["load_average"] for s in report["samples"]) / len(report["samples"]), 2),
        "errors_by_status": dict(sorted(Counter(str(e["status"]) for e in report.get("error_events", [])).items())),
    }
    if "outages" in report:
        unexcused = unexcused_errors(report["error_events"], report["outages"], report["outage_grace_s"])
        figures |= {"outages": report["outages"], "unexcused_errors": len(unexcused),
                    "unexcused_samples": unexcused[:5]}  # fmt: skip
    return figures | {"processes": process_checks(under_load(report), report["mark_s"])}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration-s", type=float, default=HOUR_S)
    parser.add_argument("--profile", choices=("embedded", "distributed"), default="embedded")
    parser.add_argument("--world", type=Path, default=None, help="a `geoloc sim world` folder (made if absent)")
    parser.add_argument("--rate", type=float, default=None, help="queries/s (default: half the measured saturation)")
    parser.add_argument("--sample-s", type=float, default=None, help="seconds between samples (default duration/120)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--retention-s",
        type=float,
        default=None,
        help="GEOLOC_QUERY_RETENTION_S of the service (default: a fifteenth of the run, at least 60 s)",
    )
    parser.add_argument("--out", type=Path, default=None, help="write the JSON report here")
    parser.add_argument(
        "--mark-s",
        type=float,
        default=None,
        help="the memory and fd checks' mark (default: 600 s of an hour, a sixth of a shorter run)",
    )
    parser.add_argument(
        "--restart-postgres-at-s",
        type=float,
        default=None,
        help="distributed: when PostgreSQL is stopped, seconds into the load (default: a third of the run)",
    )
    parser.add_argument(
        "--restart-redis-at-s",
        type=float,
        default=None,
        help="distributed: when Redis is stopped, seconds into the load (default: two thirds of the run)",
    )
    parser.add_argument(
        "--outage-s", type=float, default=OUTAGE_S, help="distributed: how long each server stays down (default 20)"
    )
    parser.add_argument("--judge", type=Path, default=None, help="judge a saved report (--out) again; no run")
    args = parser.parse_args()
    if args.judge is not None:
        saved = json.loads(args.judge.read_text())
        return judge(saved | ({"mark_s": args.mark_s} if args.mark_s else {}), args.out)
    args.sample_s = args.sample_s or max(1.0, args.duration_s / 120.0)
    args.retention_s = args.retention_s or max(60.0, round(args.duration_s / 15.0))
    restarts = (args.restart_postgres_at_s, args.restart_redis_at_s)
    if args.profile == "embedded" and restarts != (None, None):
        parser.error("--restart-postgres-at-s and --restart-redis-at-s are for --profile distributed")
    if args.restart_postgres_at_s is None:
        args.restart_postgres_at_s = args.duration_s / 3
    if args.restart_redis_at_s is None:
        args.restart_redis_at_s = 2 * args.duration_s / 3
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    print(f"machine: {machine}")
    with tempfile.TemporaryDirectory(prefix="geoloc-soak-") as tmp:
        if args.world is None:
            args.world = Path(tmp) / "world"
        if not (args.world / "manifest.json").exists():
            generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), args.world,
                           WorldOptions(n_references=20, n_queries=20, seed=1))  # fmt: skip
        env = {"GEOLOC_QUERY_RETENTION_S": str(args.retention_s)}
        servers: list[Any] = []
        data_dir = Path(tmp) / "data"
        if args.profile == "distributed":
            from testbed.servers import PostgresServer, RedisServer  # only this profile needs the servers

            servers = [PostgresServer().start(), RedisServer().start()]
            database_url = servers[0].new_database()
            env |= {"GEOLOC_DATABASE_URL": database_url, "GEOLOC_BROKER_URL": servers[1].new_url()}
        try:
            deployment = start(args, data_dir, env, distributed=bool(servers))
            try:
                report = asyncio.run(run(args, deployment, servers))
            finally:
                deployment.stop()
        finally:
            if servers:
                servers[0].stop()
                servers[1].close()
    report |= {"machine": machine, "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])}
    return judge(report, args.out)


def start(args: argparse.Namespace, data_dir: Path, env: dict[str, str], *, distributed: bool) -> Deployment:
    """``geoloc serve --workers N``, or (``distributed``) the workers and the API processes apart.

    Distributed: ``geoloc worker --concurrency N`` and :data:`API_PROCESSES` times ``geoloc serve --workers 0`` on
    the same folder, database and broker, each API ready (its ``/readyz`` waits for the worker's heartbeat).
    """
    if not distributed:
        return Deployment([LocalService(data_dir, workers=args.workers, env=env)], data_dir)
    prepare_data_dir(data_dir)
    deployment = Deployment([], data_dir, env["GEOLOC_DATABASE_URL"])
    try:
        deployment.workers = LocalWorkers(data_dir, concurrency=args.workers, env=env)
        for n in range(1, API_PROCESSES + 1):
            log_path = data_dir.parent / f"serve-{n}.log"
            deployment.apis.append(
                LocalService(data_dir, workers=0, env=env, fresh=False, log_path=log_path, name=f"API {n}")
            )
    except BaseException:
        deployment.stop()
        raise
    return deployment


def judge(report: dict[str, Any], out: Path | None) -> int:
    """Add the summary and the checks to ``report``, print them, write it to ``out``; the exit code."""
    report["summary"] = summary(report)
    checks = verdict(report)
    report["checks"] = {name: met for name, met in checks}
    print(json.dumps({k: report[k] for k in ("rate_qps", "errors", "refused_429", "jobs", "retention")}))
    if report.get("requests_per_api") and len(report["requests_per_api"]) > 1:
        print(json.dumps({"requests_per_api": report["requests_per_api"]}))
    print(json.dumps({k: v for k, v in report["summary"].items() if k != "processes"}))
    for name, figures in report["summary"]["processes"].items():
        print(f"  {name}: {figures}")
    for line in report["error_samples"][:5]:
        print(f"error: {line}")
    for name, met in checks:
        print(f"{'ok  ' if met else 'MISS'} {name}")
    if out:
        out.write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {out}")
    return 0 if all(met for _, met in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
