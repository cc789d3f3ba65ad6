"""Tracks through the API, end to end: issue 20's time must-hold (a 10-frame track answered within 6 s).

    .venv/bin/python benchmarks/bench_track.py --world /tmp/tw/h1 --json track.json

The world is one with query tracks (``geoloc sim world ... --queries 0 --query-tracks 10 --track-length 10``).
One service of this checkout (``geoloc serve --workers W`` on loopback, a fresh data folder,
:class:`benchmarks.local_service.LocalService`) gets the world's map and every reference (waited for until
labelled and their walks placed), then each track is posted alone, its photos in frame order in one
``POST /v1/maps/{id}/tracks`` with ``wait_s``, as a client sends it (each frame's EXIF GPS and compass are
its priors, the service's default). Per track: the wall time from the request to the answer (upload, every
frame's analysis and answer, the smoother), the workers' CPU seconds over it, the job's ``timings_ms``, and
its frames' errors against the manifest (the rank-1 pose the API returns). Printed: the median and the
largest wall time beside the must-hold, and the frames' shares within 1 / 5 / 10 m. With ``--compare-eval
EVAL.json`` (``geoloc eval world``'s JSON of the same world), also how many frames the API answered as the
evaluation did (:mod:`eval_agreement`): the evaluation measures what ships only if they are the same.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from bench_service import Service, _distance_m, label_references, load_average, send, upload_map
from eval_agreement import track_agreement
from local_service import run_figures
from track_checks import MUST_HOLD_S, track_summary, world_tracks

from client import calls
from geoloc.sim.world import load_world


def post_track(service: Service, frames: list[tuple[Path, tuple[float, float]]], wait_s: float) -> dict[str, Any]:
    """One track posted and answered: its wall and worker CPU seconds, timings and its frames' errors (m)."""
    cpu0, t0 = service.worker_cpu_s(), time.perf_counter()
    call = calls.upload_track(service.map_id, [path for path, _ in frames], {"wait_s": wait_s})
    body = send(service, call, "track refused").value
    wall_s = time.perf_counter() - t0
    if body.get("status") != "done":
        raise SystemExit(f"track not answered within {wait_s:.0f} s: {json.dumps(body)[:300]}")
    errors = [
        None if frame.get("lat") is None else round(_distance_m((frame["lat"], frame["lon"]), truth), 2)
        for frame, (_, truth) in zip(body["frames"], frames, strict=True)
    ]
    return {
        "frames": len(frames),
        "wall_s": round(wall_s, 2),
        "worker_cpu_s": round(service.worker_cpu_s() - cpu0, 2),
        "timings_ms": body.get("timings_ms"),
        "errors_m": errors,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--world", type=Path, required=True, help="a world with query tracks")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--wait-s", type=float, default=120.0, help="the request's wait_s (s)")
    parser.add_argument("--workdir", type=Path, help="folder for the service (default: temp)")
    parser.add_argument("--json", type=Path, default=Path("track.json"))
    parser.add_argument(
        "--compare-eval",
        type=Path,
        help="the JSON of `geoloc eval world` on the same world: count the frames the API answered as it did",
    )
    args = parser.parse_args()

    world = load_world(args.world)
    tracks = world_tracks(world)
    if not tracks:
        raise SystemExit(f"{args.world} has no query tracks (geoloc sim world --query-tracks N)")
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench-track-"))
    figures: dict[str, Any] = {**run_figures(), "world": str(args.world), "workers": args.workers}
    print(f"machine: {figures['machine']}; work folder {workdir}")
    service = Service("current", Path(__file__).resolve().parent.parent, workdir / "data", args.workers, {})
    try:
        upload_map(service, osm=Path(world.manifest["map"]["path"]))
        references = [image.path for image in world.references]
        figures["labelling"] = label_references(service, references)
        print(f"{len(references)} references labelled and placed in {figures['labelling']['wall_s']} s")
        figures["tracks"] = {}
        for track, frames in tracks.items():
            row = post_track(service, frames, args.wait_s)
            row["load_average"] = load_average()
            figures["tracks"][str(track)] = row
            print(f"track {track}: {row['frames']} frames in {row['wall_s']} s (worker CPU {row['worker_cpu_s']} s)")
    finally:
        service.stop()
    figures["summary"] = summary = track_summary(list(figures["tracks"].values()))
    verdict = "passes" if summary["passes"] else "fails"
    print(
        f"wall time per track: median {summary['wall_s_median']} s, max {summary['wall_s_max']} s "
        f"(must hold <= {MUST_HOLD_S:.0f} s: {verdict}); frames within 1 / 5 / 10 m "
        f"{summary['within_1m']} / {summary['within_5m']} / {summary['within_10m']}"
    )
    if args.compare_eval is not None:
        figures["agreement_with_evaluation"] = agreement = track_agreement(
            figures["tracks"], json.loads(args.compare_eval.read_text())
        )
        print(
            f"frames answered as `geoloc eval world` answered them: {agreement['same']} of {agreement['photos']}"
            f"; differing (track, frame, API error m, evaluation error m): {agreement['differ']}"
        )
    args.json.write_text(json.dumps(figures, indent=2))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
