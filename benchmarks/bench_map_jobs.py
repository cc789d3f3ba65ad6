"""Benchmark: maps as jobs under load (issue 22): bombs refused and a city parsed while reads and queries go on.

    .venv/bin/python benchmarks/bench_map_jobs.py [--tiles-per-side 15] [--world DIR] [--references 5]
                                                  [--readers 4] [--workdir DIR] [--json map_jobs.json]

1. Makes the 100 k-building map as ``bench_city_map.py`` does (Helsinki tiled 15 x 15, 104,400 buildings; its
   ``write_tiled_osm``) and a small simulated Helsinki world (its ``_make_world``: 20 references, 5 queries,
   seed 1) unless ``--world`` names one; kept in ``--workdir`` for the next run.
2. Starts ``geoloc serve --workers 2`` (embedded, fresh data folder, the built models linked in:
   ``local_service.LocalService``), uploads Helsinki (waited for), ``--references`` of the world's references
   (labelled, waited for) and one query (answered), the targets of the reads.
3. Then at once: ``POST /v1/maps`` of the tiled map (``wait_s`` 0: 202, then ``GET /v1/maps/{id}`` every 0.5 s
   until ``done``: upload-to-usable), two gzip bombs in parallel (3 GiB of spaces after an OSM XML head, a few
   MB compressed, made in memory: nothing inflated is ever written), ``--readers`` clients reading in a loop
   with no pause (``GET /v1/maps/{helsinki}``, its references, the query, ``GET /v1/maps``) and one client
   posting the world's query photos to Helsinki one after the other (``wait_s`` 120), until the map is done.
4. Reports each bomb's status and seconds to its 413, the read latency p50/p95/p99/max over the reads that
   started while the map parsed, the queries answered then (count, latency), the map's upload-to-usable time
   and every error; prints a table, writes JSON and exits 1 unless every must-hold of
   ``map_jobs_checks.verdict`` is met (each bomb 413 within 5 s, read p99 <= 100 ms, no read error, queries
   answered and none failed during the parse, the map done).
"""

from __future__ import annotations

import argparse
import itertools
import json
import tempfile
import threading
import time
import zlib
from pathlib import Path
from typing import Any

import httpx
from bench_city_map import _make_world, ingest, upload_map, write_tiled_osm
from local_service import LocalService, run_figures
from map_jobs_checks import summarize, verdict

from client import calls
from contracts.settings import shared_path
from geoloc.sim.world import load_world

BOMB_INFLATED_BYTES = 3 * 1024**3
MAP_POLL_S = 0.5


def gzip_bomb_bytes(inflated_bytes: int) -> bytes:
    """A multi-member gzip (RFC 1952) of an OSM XML head then ``inflated_bytes`` of spaces, compressed in memory.

    One 64 MiB member of spaces is compressed once, streamed 1 MiB at a time (64 KB out), and repeated: a few MB
    in all, nothing inflated held or written.
    """
    head = zlib.compressobj(9, zlib.DEFLATED, 31)
    out = [head.compress(b"<?xml version='1.0'?>\n<osm version='0.6'>\n") + head.flush()]
    member, chunk = zlib.compressobj(9, zlib.DEFLATED, 31), b" " * 2**20
    body = b"".join(member.compress(chunk) for _ in range(64)) + member.flush()
    return b"".join(out) + body * -(-inflated_bytes // (64 * 2**20))


class Recorder:
    """What the clients saw, with seconds since ``t0``; appended from several threads (a list append is atomic)."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.parsed = threading.Event()
        self.reads: list[dict[str, Any]] = []
        self.queries: list[dict[str, Any]] = []
        self.bombs: list[dict[str, Any]] = []
        self.map: dict[str, Any] = {}

    def now(self) -> float:
        return time.perf_counter() - self.t0


def _status(call: Any) -> tuple[int, httpx.Response | None]:
    try:
        response = call()
        return response.status_code, response
    except httpx.HTTPError:
        return 0, None


def reader(url: str, paths: list[tuple[str, str]], offset: int, rec: Recorder) -> None:
    """Read the ``paths`` round robin, no pause, until the map is parsed."""
    with httpx.Client(base_url=url, timeout=30.0) as client:
        for what, path in itertools.islice(itertools.cycle(paths), offset, None):
            if rec.parsed.is_set():
                return
            start = rec.now()
            status, _ = _status(lambda p=path: client.get(p))
            rec.reads.append({"what": what, "t_s": start, "ms": 1e3 * (rec.now() - start), "status": status})


def asker(url: str, map_id: int, photos: list[Path], rec: Recorder) -> None:
    """Post the query photos to the map one after another (``wait_s`` 120) until the map is parsed."""
    with httpx.Client(base_url=url, timeout=180.0) as client:
        for photo in itertools.cycle(photos):
            if rec.parsed.is_set():
                return
            start = rec.now()
            files = {"image": (photo.name, photo.read_bytes())}
            status, response = _status(
                lambda f=files: client.post(f"/v1/maps/{map_id}/queries", files=f, data={"wait_s": "120"})
            )
            job = response.json().get("status", "") if response is not None and status in (200, 202) else ""
            rec.queries.append({"t_s": start, "ms": 1e3 * (rec.now() - start), "status": status, "job_status": job})


def bomb(url: str, index: int, payload: bytes, rec: Recorder) -> None:
    """Upload one bomb; record its status, error code and the seconds from the upload's start to the answer."""
    with httpx.Client(base_url=url, timeout=120.0) as client:
        start = time.perf_counter()
        files = {"file": (f"city{index}.osm.gz", payload)}
        status, response = _status(lambda: client.post("/v1/maps", files=files, data={"name": f"bomb {index}"}))
        seconds = time.perf_counter() - start
    code = response.json().get("error", {}).get("code", "") if response is not None and status >= 400 else ""
    rec.bombs.append({"index": index, "status": status, "code": code, "seconds": round(seconds, 2)})


def city(url: str, path: Path, rec: Recorder, timeout_s: float) -> None:
    """Upload the city map without waiting, then poll it until done (or failed, or ``timeout_s``)."""
    with httpx.Client(base_url=url, timeout=300.0) as client:
        with path.open("rb") as file:
            status, response = _status(
                lambda: client.post("/v1/maps", files={"file": (path.name, file)}, data={"name": "city"})
            )
        rec.map.update(post_status=status, post_s=round(rec.now(), 2))
        if status != 202 or response is None:
            rec.map["error"] = response.text[:500] if response is not None else "no answer"
            rec.parsed.set()
            return
        map_id, row = response.json()["id"], response.json()
        while rec.now() < timeout_s and row.get("status") not in ("done", "failed"):
            time.sleep(MAP_POLL_S)
            status, got = _status(lambda: client.get(f"/v1/maps/{map_id}"))
            row = got.json() if got is not None and status == 200 else row
        done = row.get("status") == "done"
        rec.map.update(map_id=map_id, status=row.get("status"), buildings=row.get("building_count"),
                       usable_s=round(rec.now(), 2) if done else None, error=row.get("error"))  # fmt: skip
    rec.parsed.set()


def run_load(service: LocalService, targets: dict[str, int], city_path: Path, photos: list[Path],
             readers: int, timeout_s: float) -> Recorder:  # fmt: skip
    """Step 3 of the module docstring: everything at once, until the city map is usable."""
    paths = [
        ("map", f"/v1/maps/{targets['map']}"),
        ("references", f"/v1/maps/{targets['map']}/references?format=json&limit=50"),
        ("query", f"/v1/queries/{targets['query']}?format=json"),
        ("maps", "/v1/maps"),
    ]
    payload = gzip_bomb_bytes(BOMB_INFLATED_BYTES)
    rec = Recorder()
    threads = [threading.Thread(target=city, args=(service.url, city_path, rec, timeout_s))]
    threads += [threading.Thread(target=bomb, args=(service.url, i, payload, rec)) for i in (1, 2)]
    threads += [threading.Thread(target=reader, args=(service.url, paths, i, rec)) for i in range(readers)]
    threads += [threading.Thread(target=asker, args=(service.url, targets["map"], photos, rec))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    rec.map["bomb_bytes"] = len(payload)
    return rec


def print_table(summary: dict[str, Any], city_map: dict[str, Any], checks: list[tuple[str, bool]]) -> None:
    for b in sorted(summary["bombs"], key=lambda b: b["index"]):
        print(f"bomb {b['index']}: {b['status']} {b['code']} after {b['seconds']:.2f} s")
    print(f"city map: POST {city_map.get('post_status')} after {city_map.get('post_s')} s; usable (done) "
          f"{summary['map_usable_s']} s after the upload's start; {city_map.get('buildings')} buildings")  # fmt: skip
    reads, queries = summary["reads"], summary["queries"]
    print(f"{'during the parse':24s}{'count':>8s}{'p50':>9s}{'p95':>9s}{'p99':>9s}{'max':>9s}{'errors':>8s}")
    rows = [("reads (ms)", reads["count"], reads["ms"], reads["errors"])]
    rows += [(f"  {k}", None, v, None) for k, v in reads["by_kind"].items()]
    rows += [("queries answered (ms)", queries["answered"], queries["ms"], queries["errors"])]
    for label, count, ms, errors in rows:
        cells = "".join(f"{'-' if ms[k] is None else f'{ms[k]:.0f}':>9s}" for k in ("p50", "p95", "p99", "max"))
        print(f"{label:24s}{'' if count is None else count:>8}{cells}{'' if errors is None else errors:>8}")
    for name, met in checks:
        print(f"{'met' if met else 'NOT MET':8s} {name}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tiles-per-side", type=int, default=15)
    parser.add_argument("--world", type=Path, help="a simulated Helsinki world (default: made here)")
    parser.add_argument("--references", type=int, default=5, help="references of the world ingested first")
    parser.add_argument("--readers", type=int, default=4, help="concurrent reading clients")
    parser.add_argument("--timeout-s", type=float, default=600.0, help="give up on the city map after this")
    parser.add_argument("--workdir", type=Path, help="folder for the tiled map, world and service (default: temp)")
    parser.add_argument("--json", type=Path, default=Path("map_jobs.json"))
    args = parser.parse_args()

    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench-map-jobs-"))
    workdir.mkdir(parents=True, exist_ok=True)
    helsinki = shared_path("data", "osm", "helsinki.osm.pbf")
    figures: dict[str, Any] = {
        **run_figures(),
    }
    print(f"machine: {figures['machine']}; work folder {workdir}")
    world = load_world(args.world or _make_world(workdir / "world", helsinki))
    tiled = workdir / f"helsinki_tiled_{args.tiles_per_side}x{args.tiles_per_side}.osm.pbf"
    if not tiled.exists():
        write_tiled_osm(helsinki, tiled, args.tiles_per_side)
    figures["city_file_mb"] = round(tiled.stat().st_size / 2**20, 1)

    service = LocalService(workdir / "service" / "data", workers=2, log_path=workdir / "service" / "service.log")
    try:
        map_id = upload_map(service, helsinki, "helsinki")["map_id"]
        ingest(service, {"helsinki": map_id}, [im.path for im in world.references[: args.references]])
        photos = [im.path for im in world.queries]
        # the worker's first load of the map, before the clock starts; the query read below
        query_id = service.client.call(calls.upload_query(map_id, photos[0], {"wait_s": 300})).value.id
        rec = run_load(service, {"map": map_id, "query": query_id}, tiled, photos, args.readers, args.timeout_s)
    finally:
        service.stop()

    summary = summarize(rec.reads, rec.queries, rec.bombs, rec.map.get("usable_s"))
    checks = verdict(summary)
    figures |= {"city_map": rec.map, "summary": summary, "verdict": {name: met for name, met in checks}}
    print_table(summary, rec.map, checks)
    args.json.write_text(json.dumps(figures, indent=2))
    print(f"figures written to {args.json}")
    raise SystemExit(0 if all(met for _, met in checks) else 1)


if __name__ == "__main__":
    main()
