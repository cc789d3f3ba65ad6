"""Benchmark: the query on the CPU and on a GPU (``GEOLOC_DEVICE=cpu`` / ``cuda``) side by side, in one run.

    .venv/bin/python benchmarks/bench_device.py [--world /tmp/worlds/h1] [--references 20] [--queries 10]
                                                [--rounds 2] [--preset balanced] [--json device.json]

In process, as the workers run it: the world's first ``--references`` references (``geoloc sim world``) are
labelled once on the CPU as the evaluation labels them (:func:`geoloc.evaluation.references.label_references`),
then each of its first ``--queries`` query photos goes through :func:`geoloc.vision.evidence.analyze_photo`
and the query stage (:func:`geoloc.localize.query.geolocate`, the preset's configuration, the photo's EXIF
GPS and compass as priors like the service) once per device and round, the devices' order alternating by
round; one warm-up query per device first (sessions, CUDA kernels). Per device: the wall time's p50 and p95
(analysis and query stage, the photo already loaded) and the median of each stage of the answers'
``timings_ms``, with each stage's ratio to segmentation; how far each GPU answer's best pose lies from the CPU's
for the same photo and round (metres, degrees). With ``--aliked`` (the model built by
``geoloc models build --features aliked-n16``) the same photos also go through ALIKED
(:func:`geoloc.vision.aliked.aliked_keypoints`, its network and head, 1024 keypoints) on each device: the
``aliked`` row. Without onnxruntime's CUDA provider or a GPU it says why and measures the CPU alone (exit 0).
Prints a markdown table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from contracts.queries import QueryPreset
from geoloc.core.context import Device, MethodContext
from geoloc.core.geo import angle_difference_deg
from geoloc.evaluation.queries import photo_priors
from geoloc.evaluation.references import LabelledWorld, label_references
from geoloc.localize.query import geolocate, preset_config
from geoloc.localize.retrieval import Vocabulary, default_vocabulary
from geoloc.maps import CityMap
from geoloc.photos.photo import Photo, load_photo
from geoloc.sim.world import load_world
from geoloc.vision.aliked import aliked_keypoints, load_runtime
from geoloc.vision.evidence import analyze_photo
from geoloc.vision.onnx_session import DeviceUnavailableError, device_problems
from geoloc.vision.segmentation import load_session
from workers.context import worker_context


def cuda_problem(context: MethodContext) -> str | None:
    """Why the networks cannot run on CUDA here (None when a session gets the GPU)."""
    if problems := device_problems("cuda"):
        return problems[0]
    try:
        load_session(replace(context, device="cuda"))
    except DeviceUnavailableError as exc:
        return str(exc)
    return None


def ask_aliked(photo: Photo, context: MethodContext) -> float:
    """Milliseconds of ALIKED (network and head, 1024 keypoints, the whole image) on ``context``'s device."""
    runtime = load_runtime(context)
    t0 = time.perf_counter()
    aliked_keypoints(photo.image_rgb, 1024, runtime=runtime)
    return 1e3 * (time.perf_counter() - t0)


def ask(
    city: CityMap,
    photo: Photo,
    labelled: LabelledWorld,
    vocabulary: Vocabulary,
    preset: QueryPreset,
    context: MethodContext,
) -> dict[str, float]:
    """One query on ``context``'s device: stage timings, wall time (ms) and best pose (``x_m``, ``y_m``, ``yaw_deg``).

    The wall time is the analysis and the query stage; the pose is local metres and a bearing.
    """
    position_prior, heading_prior = photo_priors(photo, city, "gps")
    t0 = time.perf_counter()
    evidence = analyze_photo(photo, context=context)
    answer = geolocate(
        city,
        photo,
        evidence,
        labelled.store,
        vocabulary,
        preset_config(preset),
        position_prior=position_prior,
        heading_prior=heading_prior,
        context=context,
    )
    best = answer.poses[0]
    pose = {"x_m": best.x_m, "y_m": best.y_m, "yaw_deg": best.yaw_deg}
    return {**answer.timings_ms, "wall": 1e3 * (time.perf_counter() - t0), **pose}


NOT_STAGES = ("wall", "x_m", "y_m", "yaw_deg")
"""Keys of a run that are not stage timings: the wall time (ms) and the best pose (local m, bearing deg)."""


def disagreement(cpu_runs: list[dict[str, float]], gpu_runs: list[dict[str, float]]) -> dict[str, float]:
    """Largest distance (m) and heading difference (deg) between the two devices' best poses, photo by photo."""
    distance_m = [math.hypot(c["x_m"] - g["x_m"], c["y_m"] - g["y_m"]) for c, g in zip(cpu_runs, gpu_runs, strict=True)]
    heading_deg = [angle_difference_deg(c["yaw_deg"], g["yaw_deg"]) for c, g in zip(cpu_runs, gpu_runs, strict=True)]
    return {
        "max_distance_m": round(max(distance_m), 3),
        "max_heading_deg": round(max(heading_deg), 3),
        "answers_over_1_m": sum(d > 1.0 for d in distance_m),
    }


def summary(runs: list[dict[str, float]]) -> dict[str, Any]:
    """p50/p95 of the wall time, each stage's median and its ratio to segmentation's."""
    walls = np.array([r["wall"] for r in runs])
    stages = {k: round(statistics.median(r.get(k, 0.0) for r in runs), 1) for k in runs[0] if k not in NOT_STAGES}
    seg = stages.get("segmentation") or float("nan")
    return {
        "queries": len(runs),
        "wall_ms_p50": round(float(np.percentile(walls, 50)), 1),
        "wall_ms_p95": round(float(np.percentile(walls, 95)), 1),
        "stages_ms_median": stages,
        "stage_per_segmentation": {k: round(v / seg, 2) for k, v in stages.items()},
    }


def table(results: dict[str, dict[str, Any]]) -> str:
    """Rows: p50, p95, then each stage's median (and ratio to segmentation); one column per device."""
    devices = list(results)
    rows = ["| | " + " | ".join(devices) + " |", "| --- |" + " --- |" * len(devices)]
    rows.append(
        "| query p50 / p95 | "
        + " | ".join(f"{results[d]['wall_ms_p50']:.0f} / {results[d]['wall_ms_p95']:.0f} ms" for d in devices)
        + " |"
    )
    for stage in results[devices[0]]["stages_ms_median"]:
        cells = [
            f"{results[d]['stages_ms_median'].get(stage, 0.0):.1f} ms "
            f"(x{results[d]['stage_per_segmentation'].get(stage, 0.0):.2f} seg)"
            for d in devices
        ]
        rows.append(f"| {stage} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--world", type=Path, default=Path("/tmp/worlds/h1"))
    parser.add_argument("--references", type=int, default=20, help="the world's first N references")
    parser.add_argument("--queries", type=int, default=10, help="the world's first N query photos")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--preset", default="balanced", choices=["fast", "balanced", "accurate"])
    parser.add_argument("--aliked", action="store_true", help="also time ALIKED (aliked-n16) on each device")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    world = load_world(args.world)
    kept = {im.name for im in world.references[: args.references]}
    world = replace(world, images=[im for im in world.images if im.role != "reference" or im.name in kept])
    cpu = replace(worker_context(), device="cpu")
    problem = cuda_problem(cpu)
    devices: dict[Device, MethodContext] = {"cpu": cpu}
    if problem is None:
        devices["cuda"] = replace(cpu, device="cuda")
    else:
        print(f"no GPU here, measuring the CPU alone: {problem}")
    city = world.load_map()
    vocabulary = default_vocabulary(cpu.models_dir)
    labelled = label_references(world, city, vocabulary, "model", lambda _: None, cpu)
    photos = [load_photo(q.path) for q in world.queries[: args.queries]]
    print(f"{len(labelled.labelled)} references labelled; {len(photos)} queries x {args.rounds} rounds")
    for context in devices.values():  # warm-up
        ask(city, photos[0], labelled, vocabulary, args.preset, context)
        if args.aliked:
            ask_aliked(photos[0], context)
    runs: dict[str, list[dict[str, float]]] = {d: [] for d in devices}
    for round_index in range(args.rounds):
        order = list(devices) if round_index % 2 == 0 else list(reversed(devices))
        for photo in photos:
            for device in order:
                run = ask(city, photo, labelled, vocabulary, args.preset, devices[device])
                if args.aliked:
                    run["aliked"] = ask_aliked(photo, devices[device])
                runs[device].append(run)
    results = {d: summary(r) for d, r in runs.items()}
    if "cuda" in runs:
        agreement = disagreement(runs["cpu"], runs["cuda"])
        results["cuda"]["cpu_disagreement"] = agreement
        print(f"GPU answers against the CPU's, same photo and round: {agreement}")
    print(f"{platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}, preset {args.preset}")
    print(table(results))
    if args.json:
        report = {"world": str(args.world), "cuda_problem": problem, "runs": runs, "devices": results}
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
