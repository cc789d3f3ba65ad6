"""One suite world evaluated by a tree's own evaluation, reduced to per-item outcomes (run as a script).

``python outcomes.py WORLD_DIR OUT.json`` with ``PYTHONPATH`` a source tree evaluates the world with that tree's
:func:`geoloc.evaluation.world.evaluate_world` (the workers' own stages: labelling, walk placement, the query and
track stages), one run, ``ours/gps`` (each query's EXIF GPS and compass as its priors, as the API reads a photo),
and its tracks with the GPS prior only. The suite runs it on this checkout and, copied out, on a baseline
commit's exported tree: so it imports nothing of the suite and only what ``evaluate_world`` has long offered. Of
the labelled references it needs their placed poses and stated covariances, which the evaluation's JSON does not
carry; it takes them from the evaluation's own ``label_references`` as it returns them (wrapped for the call).

The outcomes (all errors in metres or degrees, against the world's truth; ``gps_error_m``: the photo's own EXIF
fix against its truth, None without one):

- ``queries``: per single query ``name``, ``kind``, ``shown``, ``error_m``, ``heading_error_deg``,
  ``radius_m``, ``inside_radius``, ``gps_error_m``, and of its rank-1 answer ``source`` (anchors, likelihood),
  ``inliers``, ``probability`` and ``prior_distance_m`` (from its GPS fix; None where a tree's evaluation does
  not report them);
- ``references``: per reference ``name``, ``error_m``, ``heading_error_deg``, ``gps_error_m``,
  ``mahalanobis``: the truth's distance in the label's stated position covariance (sigmas);
- ``track_frames``: per track frame ``name``, ``track``, ``error_m``, ``heading_error_deg``, ``alone_error_m``
  (the same frame answered alone), ``inside_radius``, ``gps_error_m``.
"""

from __future__ import annotations

import inspect
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

OUTCOMES_VERSION = 2
"""Bumped when the outcomes' content changes (part of a result's cache key)."""


def _rounded(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), 3)


def _gps_errors(world: Any, city: Any) -> dict[str, float | None]:
    """Each image's EXIF fix against its true position (m) in the map's frame; None for an image without GPS."""
    out: dict[str, float | None] = {}
    for image in world.images:
        gps = image.record.get("gps")
        if not gps:
            out[image.name] = None
            continue
        x, y = city.frame.to_local(gps["lat"], gps["lon"])
        out[image.name] = math.hypot(float(x) - image.pose.x_m, float(y) - image.pose.y_m)
    return out


def _reference_rows(world: Any, labelled: Any, gps: dict[str, float | None]) -> list[dict[str, Any]]:
    rows = []
    for image in world.references:
        label, pose = labelled.labelled[image.name].label, image.pose
        delta = np.array([label.x_m - pose.x_m, label.y_m - pose.y_m])
        covariance = np.asarray(label.position_covariance, dtype=float)
        try:
            mahalanobis = float(np.sqrt(delta @ np.linalg.solve(covariance, delta)))
        except np.linalg.LinAlgError:
            mahalanobis = math.inf
        heading = abs((label.yaw_deg - pose.yaw_deg + 180.0) % 360.0 - 180.0)
        rows.append(
            {
                "name": image.name,
                "error_m": _rounded(float(np.hypot(*delta))),
                "heading_error_deg": _rounded(heading),
                "gps_error_m": _rounded(gps[image.name]),
                "mahalanobis": _rounded(mahalanobis) if math.isfinite(mahalanobis) else 1e9,
            }
        )
    return rows


def _method_context() -> Any:
    """The method's context from the settings, as a worker builds it (``workers.context``, a layer above)."""
    # The evaluated tree's modules (see evaluate_outcomes); BLAS and OpenCV run one thread, as in a worker.
    import cv2
    from threadpoolctl import threadpool_limits

    from contracts.settings import default_threads, get_settings, models_dir
    from geoloc.core.context import MethodContext
    from geoloc.core.parallel import JobThreads

    settings = get_settings()
    threadpool_limits(limits=settings.worker_threads, user_api="blas")
    cv2.setNumThreads(settings.worker_threads)
    return MethodContext(models_dir(), JobThreads(settings.job_threads), default_threads(), settings.device)


def evaluate_outcomes(world_dir: Path) -> dict[str, Any]:
    """The module docstring's outcomes of the world at ``world_dir``, with the evaluation's seconds."""
    # The evaluated tree's modules: whichever tree PYTHONPATH names (this checkout's or a baseline's).
    from geoloc.evaluation import world as evaluation
    from geoloc.localize.query import QueryConfig

    captured: dict[str, Any] = {}
    label_references = evaluation.label_references  # type: ignore[attr-defined]  # wrapped below, not exported

    def capturing(world: Any, city: Any, *args: Any, **kwargs: Any) -> Any:
        labelled = label_references(world, city, *args, **kwargs)
        captured.update(world=world, city=city, labelled=labelled)
        return labelled

    config = QueryConfig()
    runs = [run for run in evaluation.default_runs(config) if run.name == "ours/gps"]
    options: dict[str, Any] = {}
    if "track_priors" in inspect.signature(evaluation.evaluate_world).parameters:
        options["track_priors"] = ("gps",)
    context = _method_context()
    started = time.perf_counter()
    evaluation.label_references = capturing  # type: ignore[attr-defined]
    try:
        result = evaluation.evaluate_world(world_dir, config=config, runs=runs, context=context, **options)
    finally:
        evaluation.label_references = label_references  # type: ignore[attr-defined]
    world, city, labelled = captured["world"], captured["city"], captured["labelled"]
    gps = _gps_errors(world, city)
    queries = [
        {
            "name": row["name"],
            "kind": row["kind"],
            "shown": bool(row["shown"]),
            "error_m": _rounded(row["error_m"]),
            "heading_error_deg": _rounded(row["heading_error_deg"]),
            "radius_m": _rounded(row["uncertainty_radius_m"]),
            "inside_radius": bool(row["inside_radius"]),
            "gps_error_m": _rounded(gps[row["name"]]),
            "source": row.get("source"),
            "inliers": row.get("inliers"),
            "probability": _rounded(row.get("probability")),
            "prior_distance_m": _rounded(row.get("prior_distance_m")),
        }
        for row in result.get("runs", {}).get("ours/gps", {}).get("per_query", [])
    ]
    frames = [
        {
            "name": row["name"],
            "track": int(row["track"]),
            "error_m": _rounded(row["error_m"]),
            "heading_error_deg": _rounded(row["heading_error_deg"]),
            "alone_error_m": _rounded(row["alone_error_m"]),
            "inside_radius": bool(row["inside_radius"]),
            "gps_error_m": _rounded(gps[row["name"]]),
        }
        for row in result.get("tracks", {}).get("gps", {}).get("per_frame", [])
    ]
    return {
        "outcomes_version": OUTCOMES_VERSION,
        "seconds": round(time.perf_counter() - started, 1),
        "queries": queries,
        "references": _reference_rows(world, labelled, gps),
        "track_frames": frames,
    }


def main(argv: list[str]) -> int:
    """``outcomes.py WORLD_DIR OUT.json``: evaluate and write the outcomes (atomically); exit code 0."""
    world_dir, out = Path(argv[0]), Path(argv[1])
    outcomes = evaluate_outcomes(world_dir)
    partial = out.with_name(out.name + ".partial")
    partial.write_text(json.dumps(outcomes))
    partial.replace(out)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
