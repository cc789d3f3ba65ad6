"""Benchmark: the service end to end through its API, this checkout next to a baseline commit, in one run.

    .venv/bin/python benchmarks/bench_service.py [--baseline REF] [--world DIR] [--workers 2] [--rounds 3]
                                                 [--workdir DIR] [--json service.json]

Each service is ``geoloc serve --workers N`` on its own fresh data folder (the built models linked in), on
loopback; ``--baseline`` adds the same service run from another commit of this repository (exported with
``git archive`` into the work folder, ``benchmarks.baseline.export_commit``, run with the same Python
environment), and each ``--variant`` one more service of this checkout with other settings (e.g.
``GEOLOC_SEG_THREADS=2``), so that old and new are measured side by side under the same load. On each:

1. The Helsinki map is uploaded; the references of the world (``geoloc sim world --map helsinki.osm.pbf
   --references 60 --queries 30 --seed 1``, made here unless ``--world`` names one) are posted at once and
   labelled by the pool, one service after the other. Throughput: references per second of wall time per
   worker, and per CPU-second of the worker processes (``/proc``: what a core does when it is not shared).
2. Queries, one at a time with the workers warm (one warm-up query per service first): every query photo
   of the world, ``--rounds`` times, each posted to every service back to back (the order alternating by
   round). Latency: the client's wall time of ``POST /v1/maps/{id}/queries`` (waiting for the answer), with
   its median (p50) and p95, the workers' stage timings (``result.timings_ms``, medians) and the worker CPU
   time per query. Queries per CPU-second of the workers is the per-core throughput.
3. Concurrent queries: every query photo posted without waiting, the pool answering them together; queries
   per second of wall time per worker.
4. Memory: the workers' peak resident memory (``VmHWM``) while labelling and, reset in between
   (``/proc/PID/clear_refs``), while answering queries.
5. Answers: each query's ranked locations on every other service next to this checkout's (rank 1 position
   and heading, the number of locations), which must agree: the speed-ups do not change what the method
   computes. Each other service's latency is also paired query by query with this checkout's: a geometric
   mean ratio with a 95 % bootstrap interval (:func:`answer_pairs.paired_latency`), which resolves
   differences of a few per cent that the medians' noise hides. With ``--compare-eval EVAL.json``
   (``geoloc eval world``'s JSON of ``--world``), this checkout's answers of the first round are also
   compared with the evaluation's ``ours/gps`` (:mod:`eval_agreement`).
6. The floor (issue 23): the segmentation network's own CPU per query photo, measured in this process after
   the queries (:func:`segmentation_cpu`: the workers' session and threads, the median per photo); each
   service's worker CPU per query over it, and each stage's median over the service's segmentation stage.

The machine is shared: its load average is printed with each phase. Prints a table and writes JSON. Targets
(issue 14): query p50 <= 400 ms and p95 <= 800 ms, >= 1.5 references and >= 2 queries per second per core.
Must-hold checks (issue 23, ``benchmarks.baseline.service_checks``), PASS/FAIL lines and ``must_hold`` in the
JSON: worker CPU per query <= 2x the network's; against ``--baseline`` (the issue's: 7a88952) p50 <= 0.6x,
references per CPU-second >= 1.5x, and every query's ranked locations exactly those of ``--method-baseline``
(a third service: the commit the method has not changed since, when it changed after ``--baseline``; else the
baseline's). References per CPU-second count every job the references cause, their walks' placement too.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from answer_pairs import compare_answers, distance_m, paired_latency
from baseline import export_commit, service_checks
from eval_agreement import query_agreement
from local_service import REPO_ROOT, LocalService, status_mb

from client import ApiError, Call, Sent, calls
from contracts.settings import shared_path
from geoloc.photos.photo import load_photo
from geoloc.sim.world import WorldOptions, generate_world, load_world
from geoloc.vision.segmentation import load_session, segment
from workers.context import worker_context

TARGET_P50_MS = 400.0
TARGET_P95_MS = 800.0
TARGET_REFERENCES_PER_CORE_S = 1.5
TARGET_QUERIES_PER_CORE_S = 2.0


def load_average() -> float:
    return round(os.getloadavg()[0], 1)


class Service(LocalService):
    """A named service of one source folder, with its workers' CPU time and peak memory."""

    def __init__(self, name: str, source: Path, data_dir: Path, workers: int, env: dict[str, str]) -> None:
        # The baseline commit's idle workers polled every 2 s by default; both poll as this checkout does.
        env = {"GEOLOC_WORKER_POLL_MAX_S": "0.05", **env}
        super().__init__(data_dir, workers=workers, env=env, source=source, log_path=data_dir.parent / f"{name}.log")
        self.name = name
        self.workers = workers
        self.map_id = 0

    def worker_peak_mb(self) -> float:
        return max(status_mb(pid, "VmHWM") for pid in self.pids(b"workers"))

    def reset_peaks(self) -> None:
        for pid in self.pids(b"workers"):
            Path(f"/proc/{pid}/clear_refs").write_text("5")


def segmentation_cpu(photos: list[Path], repeats: int) -> dict[str, Any]:
    """The segmentation network's own CPU per query photo, as the workers run it, in this process.

    The workers' session (:func:`geoloc.vision.segmentation.load_session` with ``workers.context``'s context: the
    same models, onnxruntime threads and device); ``time.process_time`` (every thread of this process) around
    :func:`~geoloc.vision.segmentation.segment` of each photo as the workers load it, ``repeats`` times after
    one warm-up: the median per photo, and the median of those (ms). This process's settings: a ``--variant``'s
    (e.g. other onnxruntime threads) are not applied here, so every service is set against the default network.
    """
    session = load_session(worker_context())
    per_photo: dict[str, float] = {}
    for photo in photos:
        image = load_photo(photo).image_rgb
        segment(image, session=session)  # warm-up: the first run of a session allocates its buffers
        times_ms = []
        for _ in range(repeats):
            t0 = time.process_time()
            segment(image, session=session)
            times_ms.append(1e3 * (time.process_time() - t0))
        per_photo[photo.name] = round(statistics.median(times_ms), 1)
    return {"cpu_ms_median": round(statistics.median(per_photo.values()), 1), "cpu_ms_per_photo": per_photo}


def as_json(call: Call[Any]) -> Call[dict[str, Any]]:
    """``call`` with its answer read as plain JSON: a baseline commit's answers may predate the client's models."""
    return replace(call, read=lambda response: dict(response.json()))


def send(service: Service, call: Call[Any], what: str) -> Sent[dict[str, Any]]:
    """``call`` sent through the client (retries included), its JSON answer; an error answer ends the run."""
    try:
        return service.client.call(as_json(call))
    except ApiError as exc:
        raise SystemExit(f"{service.name}: {what}: {exc}") from exc


def upload_map(service: Service, timeout_s: float = 600.0, osm: Path | None = None) -> None:
    """Upload a map (default Helsinki) and wait until it is parsed (a commit before maps as jobs answers it parsed)."""
    osm = osm or shared_path("data", "osm", "helsinki.osm.pbf")
    uploaded = send(service, calls.upload_map(osm, osm.name.split(".")[0], {"wait_s": 60.0}), "map upload failed").value
    service.map_id = int(uploaded["id"])
    deadline = time.monotonic() + timeout_s
    while uploaded.get("status", "done") not in ("done", "failed"):
        if time.monotonic() > deadline:
            raise SystemExit(f"{service.name}: map {service.map_id} not parsed within {timeout_s:.0f} s")
        time.sleep(0.5)
        uploaded = send(service, calls.get_map(service.map_id), "map").value
    if uploaded.get("status") == "failed":
        raise SystemExit(f"{service.name}: map {service.map_id} failed: {json.dumps(uploaded)[:300]}")


def label_references(service: Service, photos: list[Path]) -> dict[str, Any]:
    """Post every reference at once, wait until the pool has labelled them and placed their walks: throughput.

    The CPU counted is every job the references cause: their labels and their walks' joint placement.
    """
    service.reset_peaks()
    cpu0, load0, t0 = service.worker_cpu_s(), load_average(), time.perf_counter()
    ids = []
    for photo in photos:
        upload = calls.upload_reference(service.map_id, photo, {})
        ids.append(send(service, upload, f"reference {photo.name} refused").value["id"])
    while True:
        listing = send(service, calls.list_references(service.map_id, 0, 1), "references").value
        counts = listing["counts"]
        if counts.get("queued", 0) + counts.get("processing", 0) + listing.get("walks_placing", 0) == 0:
            break
        time.sleep(0.2)
    wall_s = service.wait_until_idle() - t0  # a walk's placement job (a commit without walks_placing hides it)
    cpu_s = service.worker_cpu_s() - cpu0
    rows = [send(service, calls.get_reference(rid), "reference").value for rid in ids]
    totals = [r["timings"]["total"] for r in rows if r.get("timings")]
    return {
        "references": len(ids),
        "labelled": sum(r["status"] == "done" for r in rows),
        "wall_s": round(wall_s, 1),
        "worker_cpu_s": round(cpu_s, 1),
        "per_s_per_worker": round(len(ids) / wall_s / service.workers, 2),
        "per_cpu_s": round(len(ids) / cpu_s, 2),
        "job_ms_median": round(statistics.median(totals), 1) if totals else None,
        "worker_peak_rss_mb": round(service.worker_peak_mb(), 1),
        "load_average": [load0, load_average()],
    }


def post_query(service: Service, photo: Path, wait_s: float = 300.0) -> Sent[dict[str, Any]]:
    return send(service, calls.upload_query(service.map_id, photo, {"wait_s": wait_s}), f"query {photo.name}")


def query_once(service: Service, photo: Path) -> dict[str, Any]:
    cpu0 = service.worker_cpu_s()
    t0 = time.perf_counter()
    sent = post_query(service, photo)
    wall_ms = 1e3 * (time.perf_counter() - t0)
    body = sent.value
    if sent.status != 200 or body.get("status") != "done":
        raise SystemExit(f"{service.name}: query {photo.name}: {sent.status} {json.dumps(body)[:300]}")
    result = body["result"]
    locations = [(loc["lat"], loc["lon"], loc["heading_deg"]) for loc in result["locations"]]
    return {
        "photo": photo.name,
        "wall_ms": wall_ms,
        "worker_cpu_ms": 1e3 * (service.worker_cpu_s() - cpu0),
        "timings_ms": result["timings_ms"],
        "locations": locations,
    }


def concurrent_queries(service: Service, photos: list[Path]) -> dict[str, Any]:
    """Every photo posted without waiting; the pool answers them together."""
    cpu0, load0, t0 = service.worker_cpu_s(), load_average(), time.perf_counter()
    ids = [post_query(service, photo, wait_s=0.0).value["id"] for photo in photos]
    pending = set(ids)
    while pending:
        for query_id in list(pending):
            if send(service, calls.get_query(query_id), "query").value["status"] in ("done", "failed"):
                pending.discard(query_id)
        time.sleep(0.1)
    wall_s = time.perf_counter() - t0
    cpu_s = service.worker_cpu_s() - cpu0
    return {
        "queries": len(ids),
        "wall_s": round(wall_s, 1),
        "per_s_per_worker": round(len(ids) / wall_s / service.workers, 2),
        "per_cpu_s": round(len(ids) / cpu_s, 2),
        "load_average": [load0, load_average()],
    }


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    walls = [r["wall_ms"] for r in runs]
    stages = sorted({stage for r in runs for stage in r["timings_ms"]}, key=list(runs[0]["timings_ms"]).index)
    return {
        "queries": len(walls),
        "wall_ms_p50": round(float(np.percentile(walls, 50)), 1),
        "wall_ms_p95": round(float(np.percentile(walls, 95)), 1),
        "worker_cpu_ms_median": round(statistics.median(r["worker_cpu_ms"] for r in runs), 1),
        "per_cpu_s": round(len(runs) / (sum(r["worker_cpu_ms"] for r in runs) / 1e3), 2),
        "stages_ms_median": {s: round(statistics.median(r["timings_ms"].get(s, 0.0) for r in runs), 1) for s in stages},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", help="a commit (or branch) of this repository to measure beside this checkout")
    parser.add_argument(
        "--method-baseline",
        help="the commit whose answers this checkout must equal (the method unchanged since it; default --baseline)",
    )
    parser.add_argument("--world", type=Path, help="a simulated Helsinki world (default: made here)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        help="KEY=VALUE[,KEY=VALUE]: one more service of this checkout with these settings (repeatable)",
    )
    parser.add_argument("--workdir", type=Path, help="folder for the services and the world (default: temp)")
    parser.add_argument("--json", type=Path, default=Path("service.json"))
    parser.add_argument("--compare-eval", type=Path, help="`geoloc eval world`'s JSON of --world: the same answers?")
    args = parser.parse_args()

    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench-service-"))
    workdir.mkdir(parents=True, exist_ok=True)
    figures: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {load_average()} at start",
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
    }
    print(f"machine: {figures['machine']}; work folder {workdir}")
    world_dir = args.world
    if world_dir is None:
        world_dir = workdir / "world"
        if not (world_dir / "manifest.json").exists():
            generate_world(
                shared_path("data", "osm", "helsinki.osm.pbf"),
                world_dir,
                WorldOptions(n_references=60, n_queries=30, seed=1),
            )
    world = load_world(world_dir)
    references = [im.path for im in world.references]
    queries = [im.path for im in world.queries]
    figures["world"] = {"path": str(world_dir), "references": len(references), "queries": len(queries)}

    sources: dict[str, tuple[Path, dict[str, str]]] = {}
    if args.baseline:
        commit = export_commit(args.baseline, workdir / "baseline-src")
        sources[f"baseline {commit}"] = (workdir / "baseline-src", {})
    if args.method_baseline:
        commit = export_commit(args.method_baseline, workdir / "method-baseline-src")
        sources[f"method {commit}"] = (workdir / "method-baseline-src", {})
    for variant in args.variant:
        sources[f"current {variant}"] = (REPO_ROOT, dict(kv.split("=", 1) for kv in variant.split(",")))
    sources["current"] = (REPO_ROOT, {})
    services: dict[str, Service] = {}
    try:
        for index, (name, (source, env)) in enumerate(sources.items()):
            services[name] = Service(name, source, workdir / f"service-{index}" / "data", args.workers, env)
            upload_map(services[name])
        names = list(services)

        figures["labelling"] = {}
        for name, service in services.items():
            row = label_references(service, references)
            figures["labelling"][name] = row
            print(f"{name}: {row['labelled']}/{row['references']} references labelled in {row['wall_s']} s "
                  f"({row['per_s_per_worker']} per second per worker, {row['per_cpu_s']} per CPU-second; "
                  f"worker peak {row['worker_peak_rss_mb']:.0f} MB; load {row['load_average']})")  # fmt: skip

        for service in services.values():
            query_once(service, queries[0])  # warm-up: the worker's first load of the map and its indexes
            service.reset_peaks()
        runs: dict[str, list[dict[str, Any]]] = {name: [] for name in names}
        load0 = load_average()
        for round_index in range(args.rounds):
            for photo in queries:
                for name in names if round_index % 2 == 0 else reversed(names):
                    runs[name].append(query_once(services[name], photo))
        figures["queries"] = {name: summarize(runs[name]) for name in names}
        for name in names:
            figures["queries"][name]["worker_peak_rss_mb"] = round(services[name].worker_peak_mb(), 1)
        figures["queries_load_average"] = [load0, load_average()]
        figures["segmentation"] = segmentation_cpu(queries, args.rounds)
        segmentation_ms = figures["segmentation"]["cpu_ms_median"]
        for row in figures["queries"].values():
            row["cpu_per_segmentation"] = round(row["worker_cpu_ms_median"] / segmentation_ms, 2)
            seg_stage = row["stages_ms_median"].get("segmentation")
            row["stages_per_segmentation"] = {
                stage: round(ms / seg_stage, 2) if seg_stage else None for stage, ms in row["stages_ms_median"].items()
            }
        figures["concurrent_queries"] = {name: concurrent_queries(services[name], queries) for name in names}

        figures["answers"] = {name: compare_answers(runs[name], runs["current"]) for name in names if name != "current"}
        if args.compare_eval is not None:  # this checkout's first round against the evaluation's ours/gps
            truth = {im.path.name: (im.record["pose"]["lat"], im.record["pose"]["lon"]) for im in world.queries}
            errors = {
                Path(r["photo"]).stem: distance_m(r["locations"][0][:2], truth[r["photo"]]) if r["locations"] else None
                for r in runs["current"][: len(queries)]
            }
            agreement = query_agreement(errors, json.loads(args.compare_eval.read_text()))
            figures["agreement_with_evaluation"] = agreement
            print(f"queries answered as `geoloc eval world` answered them: {agreement['same']} of "
                  f"{agreement['photos']}; differing (query, API m, evaluation m): {agreement['differ']}")  # fmt: skip
        for name, row in figures["answers"].items():
            row["speedup_p50"] = round(
                figures["queries"][name]["wall_ms_p50"] / figures["queries"]["current"]["wall_ms_p50"], 2
            )
            row["paired_latency"] = paired_latency(runs[name], runs["current"])
    finally:
        for service in services.values():
            service.stop()

    print(f"\nqueries one at a time ({args.rounds} rounds x {len(queries)} photos, interleaved; "
          f"load average {figures['queries_load_average']}):")  # fmt: skip
    width = max(len(n) for n in names) + 14  # room for a stage's ratio to the segmentation
    print(f"{'':28s}" + "".join(f"{n:>{width}s}" for n in names))
    rows = [("wall p50 (ms)", "wall_ms_p50"), ("wall p95 (ms)", "wall_ms_p95"),
            ("worker CPU per query (ms)", "worker_cpu_ms_median"), ("queries per CPU-second", "per_cpu_s"),
            ("worker peak memory (MB)", "worker_peak_rss_mb")]  # fmt: skip
    for label, key in rows:
        print(f"{label:28s}" + "".join(f"{figures['queries'][n][key]:>{width},}" for n in names))
    stages = list(figures["queries"][names[-1]]["stages_ms_median"])
    print(f"{'segmentation CPU (ms)':28s}{figures['segmentation']['cpu_ms_median']:>{width},}  (this process, "
          "the workers' session, median per photo)")  # fmt: skip
    print(f"{'worker CPU / segmentation':28s}" + "".join(f"{figures['queries'][n]['cpu_per_segmentation']:>{width}}"
                                                         for n in names))  # fmt: skip
    for stage in stages:
        values = [figures["queries"][n]["stages_ms_median"].get(stage, float("nan")) for n in names]
        ratios = [figures["queries"][n]["stages_per_segmentation"].get(stage) for n in names]
        cells = [f"{v:,} ({r}x)" if r is not None else str(v) for v, r in zip(values, ratios, strict=True)]
        print(f"{'  ' + stage + ' (ms, x seg.)':28s}" + "".join(f"{cell:>{width}}" for cell in cells))
    for name in names:
        c = figures["concurrent_queries"][name]
        print(f"{name}: {c['queries']} concurrent queries in {c['wall_s']} s: {c['per_s_per_worker']} per second per "
              f"worker, {c['per_cpu_s']} per CPU-second (load {c['load_average']})")  # fmt: skip
    for name, answers in figures["answers"].items():
        print(f"answers of {name} and current: rank 1 the same for {answers['same_rank1_pose']} queries (largest "
              f"gap {answers['rank1_gap_m_max']} m, {answers['rank1_heading_gap_deg_max']} deg); median latency "
              f"{answers['speedup_p50']}x current's; a location differs: {answers['different_photos']}")  # fmt: skip
        paired = answers["paired_latency"]
        print(f"  paired latency of {name} over current ({paired['pairs']} pairs, geometric mean): "
              f"{paired['ratio']}x [{paired['ratio_95'][0]}, {paired['ratio_95'][1]}] (95 %)")  # fmt: skip
    current = "current"
    q, lab = figures["queries"][current], figures["labelling"][current]
    figures["targets"] = {
        "query_p50_ms": {"value": q["wall_ms_p50"], "target": TARGET_P50_MS, "met": q["wall_ms_p50"] <= TARGET_P50_MS},
        "query_p95_ms": {"value": q["wall_ms_p95"], "target": TARGET_P95_MS, "met": q["wall_ms_p95"] <= TARGET_P95_MS},
        "references_per_core_s": {
            "value": lab["per_cpu_s"],
            "per_worker_wall": lab["per_s_per_worker"],
            "target": TARGET_REFERENCES_PER_CORE_S,
            "met": lab["per_cpu_s"] >= TARGET_REFERENCES_PER_CORE_S,
        },
        "queries_per_core_s": {
            "value": q["per_cpu_s"],
            "per_worker_wall": figures["concurrent_queries"][current]["per_s_per_worker"],
            "target": TARGET_QUERIES_PER_CORE_S,
            "met": q["per_cpu_s"] >= TARGET_QUERIES_PER_CORE_S,
        },
    }
    for name, target in figures["targets"].items():
        print(f"target {name}: {target['value']} vs {target['target']}: {'met' if target['met'] else 'NOT MET'}")
    base = next((n for n in names if n.startswith("baseline ")), None)
    same_method = next((n for n in names if n.startswith("method ")), base)
    checks = service_checks(
        q["cpu_per_segmentation"],
        (q["wall_ms_p50"], figures["queries"][base]["wall_ms_p50"]) if base else None,
        (lab["per_cpu_s"], figures["labelling"][base]["per_cpu_s"]) if base else None,
        figures["answers"][same_method]["different"] if same_method else None,
    )
    figures["must_hold"] = {
        "against": base,
        "answers_against": same_method,
        **{check.name: check.as_json() for check in checks},
    }
    print(f"must-hold (issue 23{', against ' + base if base else ', no baseline'}; answers against {same_method}):")
    for check in checks:
        print("  " + check.line())
    args.json.write_text(json.dumps({**figures, "runs": runs}, indent=2))
    print(f"figures written to {args.json}")


if __name__ == "__main__":
    main()
