"""Benchmark: the query presets (fast, balanced, accurate) through the API, on one world.

    .venv/bin/python benchmarks/bench_presets.py [--world /tmp/worlds/h1] [--references 20] [--queries 10]
                                                 [--workers 2] [--rounds 1] [--workdir DIR] [--json presets.json]

One ``geoloc serve --workers N`` on a fresh data folder (:class:`local_service.LocalService`), driven with the
Python client (:class:`client.Client`): the Helsinki map is uploaded, the world's first
``--references`` references posted and labelled, then each of its first ``--queries`` query photos is posted
once per preset (``preset=fast|balanced|accurate``, the order rotating by photo so that no preset always runs
first), one at a time, waiting for the answer, ``--rounds`` times; one warm-up query per preset comes first.
The queries keep their EXIF GPS as the position prior (the service's default, 50 m radius).

Per preset: the client's wall time of ``POST /v1/maps/{id}/queries`` (p50, p95), the worker's own total
(``result.timings_ms.total``, median), the rank-1 answer's position error against the renderer's truth
(median, share within 5 m) and its heading error (share within 5 deg). Prints a markdown table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any, get_args

import numpy as np
from baseline import add_baseline_option, baseline_figures
from local_service import LocalService

from contracts.queries import QUERY_PRESETS, QueryPreset
from contracts.settings import shared_path
from geoloc.sim.world import WorldImage, load_world

WITHIN_M = 5.0
WITHIN_DEG = 5.0


def _angle_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def ask(service: LocalService, map_id: int, photo: WorldImage, preset: QueryPreset) -> dict[str, Any]:
    """One query with ``preset``, waited for: wall time (ms), the worker's total (ms), the rank-1 answer."""
    t0 = time.perf_counter()
    query = service.client.upload_query(map_id, photo.path, preset=preset, wait_s=300.0)
    wall_ms = 1e3 * (time.perf_counter() - t0)
    if query.status != "done" or query.result is None:
        raise SystemExit(f"query {photo.name} ({preset}): {query.status} {query.error}")
    search = query.result.search
    if search.preset != preset or query.params.get("preset") != preset:
        raise SystemExit(f"query {photo.name}: asked {preset}, answered with {search.preset}")
    best = query.result.locations[0]
    return {
        "photo": photo.name,
        "wall_ms": wall_ms,
        "worker_ms": float(query.result.timings_ms["total"]),
        "lat": best.lat,
        "lon": best.lon,
        "heading_deg": best.heading_deg,
    }


def summary(runs: list[dict[str, Any]], truth: dict[str, tuple[float, float, float]], frame: Any) -> dict[str, Any]:
    """Latency and accuracy of one preset's answers; ``truth``: photo -> (x m, y m, heading deg)."""
    walls = np.array([r["wall_ms"] for r in runs])
    errors_m, headings = [], []
    for r in runs:
        x, y, heading = truth[r["photo"]]
        ax, ay = (float(v) for v in frame.to_local(r["lat"], r["lon"]))
        errors_m.append(float(np.hypot(ax - x, ay - y)))
        headings.append(_angle_deg(r["heading_deg"], heading))
    return {
        "queries": len(runs),
        "wall_ms_p50": round(float(np.percentile(walls, 50)), 1),
        "wall_ms_p95": round(float(np.percentile(walls, 95)), 1),
        "worker_ms_median": round(statistics.median(r["worker_ms"] for r in runs), 1),
        "error_m_median": round(statistics.median(errors_m), 1),
        "within_5m": round(float(np.mean(np.array(errors_m) <= WITHIN_M)), 3),
        "heading_within_5deg": round(float(np.mean(np.array(headings) <= WITHIN_DEG)), 3),
    }


def table(results: dict[str, dict[str, Any]]) -> str:
    """The markdown table of :func:`summary` per preset."""
    rows = [
        "| preset | query p50 / p95 (API) | worker total, median | within 5 m | heading within 5° | median error |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for preset, s in results.items():
        rows.append(
            f"| `{preset}` | {s['wall_ms_p50']:.0f} / {s['wall_ms_p95']:.0f} ms | {s['worker_ms_median']:.0f} ms | "
            f"{s['within_5m']:.0%} | {s['heading_within_5deg']:.0%} | {s['error_m_median']:.1f} m |"
        )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--world", type=Path, default=Path("/tmp/worlds/h1"))
    parser.add_argument("--references", type=int, default=None, help="the world's first N references (all)")
    parser.add_argument("--queries", type=int, default=None, help="the world's first N queries (all)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--workdir", type=Path, default=None)
    parser.add_argument("--json", type=Path, default=None)
    add_baseline_option(parser)
    args = parser.parse_args()
    assert tuple(get_args(QueryPreset)) == QUERY_PRESETS
    world = load_world(args.world)
    references, photos = world.references[: args.references], world.queries[: args.queries]
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench_presets_"))
    service = LocalService(workdir / "data", workers=args.workers)
    try:
        client = service.client
        map_id = client.upload_map(shared_path("data", "osm", "helsinki.osm.pbf"), "helsinki").id
        ids = [client.upload_reference(map_id, ref.path).id for ref in references]
        labelled = [client.wait_for_reference(rid).status for rid in ids]
        print(f"{labelled.count('done')} / {len(ids)} references labelled; load average {os.getloadavg()[0]:.1f}")
        for preset in QUERY_PRESETS:  # warm-up: the workers' caches, the compiled kernels
            ask(service, map_id, photos[0], preset)
        runs: dict[str, list[dict[str, Any]]] = {preset: [] for preset in QUERY_PRESETS}
        for round_index in range(args.rounds):
            for i, photo in enumerate(photos):
                shift = (i + round_index) % len(QUERY_PRESETS)
                for preset in QUERY_PRESETS[shift:] + QUERY_PRESETS[:shift]:
                    runs[preset].append(ask(service, map_id, photo, preset))
    finally:
        service.stop()
    frame = world.load_map().frame
    truth = {p.name: (p.pose.x_m, p.pose.y_m, float(p.record["pose"]["heading_deg"])) for p in photos}
    results = {preset: summary(runs[preset], truth, frame) for preset in QUERY_PRESETS}
    print(f"{platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    print(table(results))
    report = {"world": str(args.world), "references": len(references), "queries": len(photos), "runs": runs}
    report["presets"] = results
    baseline_figures(args.baseline, __file__, report)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
