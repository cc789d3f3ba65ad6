"""Ingest throughput on both profiles: references labelled per second with 1 and 2 worker processes.

    .venv/bin/python benchmarks/bench_ingest.py --json ingest.json [--world /tmp/w1] [--references 12]

For each profile (``embedded``: SQLite and the built-in pool; ``distributed``: PostgreSQL and Celery
workers on Redis) and each worker count, the benchmark starts a fresh deployment with ``geoloc serve
--workers N`` on loopback (the distributed one on a private PostgreSQL cluster and ``redis-server`` it
starts itself, as the tests do, with ``testbed/servers.py``), uploads the Helsinki map, labels ``N`` warm-up
references (each worker process loads its models and the map once), then uploads ``--references``
references at once and times them from the first upload to the last reference ``done`` through the API.
The photos are the references of a simulated world (``--world``, else one generated here from the
Helsinki map, seed 5); every run labels the same photos with the real method (``label_reference``).

It prints one table, the profiles side by side, and writes the figures to ``--json``: references per second,
per worker process, the median labelling time of a job (``timings.total`` of the references), and the ratio
distributed / embedded per worker count. Target of issue 13: that ratio is at least 0.8 (exit code 1 below).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from baseline import add_baseline_option, baseline_figures
from local_service import LocalService

from client import Client
from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world, load_world
from testbed.servers import PostgresServer, RedisServer

TARGET_RATIO = 0.8
"""Distributed throughput per worker must be at least this share of the embedded one."""


def upload_all(client: Client, map_id: int, photos: list[Path]) -> list[int]:
    """Upload photos as references; returns their ids."""
    return [client.upload_reference(map_id, photo).id for photo in photos]


def wait_done(client: Client, map_id: int, count: int, timeout_s: float = 1800.0) -> None:
    """Wait until ``count`` references of the map are done (fail on a failed one)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        counts = client.list_references(map_id, limit=1).counts
        if counts["failed"]:
            raise SystemExit(f"a reference failed: {counts}")
        if counts["done"] >= count:
            return
        time.sleep(0.2)
    raise SystemExit(f"timed out waiting for {count} references")


def run_one(profile: str, workers: int, photos: list[Path], warmup: int, servers: dict[str, Any]) -> dict[str, Any]:
    """One deployment: warm up, then time the measured batch."""
    env: dict[str, str] = {}
    if profile == "distributed":
        env = {
            "GEOLOC_DATABASE_URL": servers["postgres"].new_database(),
            "GEOLOC_BROKER_URL": servers["redis"].new_url(),
        }
    with tempfile.TemporaryDirectory(prefix=f"bench-ingest-{profile}-{workers}-") as tmp:
        # A queue deep enough for every upload at once.
        service = LocalService(Path(tmp) / "data", workers=workers, env={"GEOLOC_MAX_QUEUED_JOBS": "10000", **env})
        try:
            with Client(service.url, timeout_s=120) as client:
                map_id = client.upload_map(shared_path("data", "osm", "helsinki.osm.pbf"), "helsinki").id
                upload_all(client, map_id, photos[:warmup])
                wait_done(client, map_id, warmup)
                measured = photos[warmup:]
                start = time.perf_counter()
                ids = upload_all(client, map_id, measured)
                wait_done(client, map_id, warmup + len(measured))
                elapsed_s = time.perf_counter() - start
                totals_ms = [(client.get_reference(i).timings or {})["total"] for i in ids]
        finally:
            service.stop()
    rate = len(measured) / elapsed_s
    return {
        "profile": profile,
        "workers": workers,
        "references": len(measured),
        "elapsed_s": round(elapsed_s, 2),
        "references_per_s": round(rate, 3),
        "per_worker_per_s": round(rate / workers, 3),
        "median_label_ms": round(float(np.median(totals_ms)), 1),
    }


def world_photos(world: Path | None, count: int, tmp: Path) -> list[Path]:
    """Reference photos of ``world``, or of a world generated now (Helsinki, seed 5)."""
    if world is None:
        world = tmp / "world"
        options = WorldOptions(n_references=count, n_queries=1, seed=5, radius_m=150.0)
        generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), world, options)
    return [image.path for image in load_world(world).references][:count]


def main() -> int:
    """Run the four deployments, print the table, write JSON; exit 1 when the target is missed."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--world", type=Path, default=None, help="a `geoloc sim world` folder (default: generate)")
    parser.add_argument("--references", type=int, default=12, help="references timed per run")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts to run")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    add_baseline_option(parser)
    args = parser.parse_args()
    warmup = max(args.workers)
    with tempfile.TemporaryDirectory(prefix="bench-ingest-") as tmp:
        photos = world_photos(args.world, args.references + warmup, Path(tmp))
        if len(photos) < args.references + warmup:
            raise SystemExit(f"the world has {len(photos)} references; need {args.references + warmup}")
        servers = {"postgres": PostgresServer().start(), "redis": RedisServer().start()}
        try:
            runs = [
                run_one(profile, workers, photos, warmup, servers)
                for workers in args.workers
                for profile in ("embedded", "distributed")
            ]
        finally:
            servers["postgres"].stop()
            servers["redis"].close()
    by_key = {(r["profile"], r["workers"]): r for r in runs}
    ratios = {
        str(w): round(by_key["distributed", w]["per_worker_per_s"] / by_key["embedded", w]["per_worker_per_s"], 3)
        for w in args.workers
    }
    print(f"Ingest throughput, {args.references} references per run ({platform.machine()}, {os.cpu_count()} cores)")
    print("| workers | embedded refs/s (per worker) | distributed refs/s (per worker) | distributed / embedded |")
    print("| --- | --- | --- | --- |")
    for w in args.workers:
        cells = [
            f"{r['references_per_s']:.3f} ({r['per_worker_per_s']:.3f}; median job {r['median_label_ms']:.0f} ms)"
            for r in (by_key["embedded", w], by_key["distributed", w])
        ]
        print(f"| {w} | {cells[0]} | {cells[1]} | {ratios[str(w)]:.2f} |")
    result = {
        "machine": {"arch": platform.machine(), "cores": os.cpu_count(), "load_avg": os.getloadavg()},
        "runs": runs,
        "ratio_distributed_to_embedded": ratios,
        "target_ratio": TARGET_RATIO,
    }
    baseline_figures(args.baseline, __file__, result)
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2))
    return 0 if all(ratio >= TARGET_RATIO for ratio in ratios.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
