"""Evaluation of the whole method on a simulated world (``geoloc eval world DIR --json OUT``).

It runs exactly what the service runs: references are labelled with
:func:`geoloc.localize.reference.label_reference_photo` (EXIF GPS and focal length read from the JPEG) and kept as
:class:`geoloc.localize.store.StoredReference`; queries go through :func:`geoloc.localize.query.geolocate` with one
:class:`geoloc.localize.query.QueryConfig`, recorded in the output. Only the reference store differs from the
service's (memory instead of the database; both rank with the same SBoW formula).

Runs (each query is answered once per run; :func:`default_runs`):

- ``ours/gps``: the service's default: the query's EXIF GPS as the position prior (radius
  :data:`geoloc.localize.grid.DEFAULT_PRIOR_RADIUS_M`), network segmentation, transferred identities;
- ``ours/none``: the same without any prior;
- ablation ladder under the GPS prior: ``gt_identities/gps`` (perfect transfer: the query's identities
  from the renderer), ``gt_segmentation/gps`` (ground-truth labels for references and queries);
- the paper's method without the map anchors, no prior: ``paper_identity/none`` and
  ``paper_geometry/none`` (Fig. 7's two curves).

Reported per world: reference labelling (Table I identity accuracy, heading and position errors), query
identity accuracy of the transfer for k = 1, 4, 8 with our and with ground-truth reference labels
(Table II), retrieval, the raw-GPS baseline, and per run: errors at N = 1 (all queries, queries whose
buildings some reference shows, per query kind), best of top N = 1..10 (Fig. 7), heading errors, how
often the uncertainty radius holds the truth, and a per-query table.

A query's buildings are "shown by some reference" when a reference shares at least 0.1 of the image in
building pixels with it (:func:`shown_by_references`; the share at the level of facades is reported too).
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.core.context import MethodContext
from geoloc.evaluation.facades import orientation_errors
from geoloc.localize.grid import DEFAULT_PRIOR_RADIUS_M, PositionPrior
from geoloc.localize.identity import IdentityMap, identity_accuracy
from geoloc.localize.query import InMemoryReferenceStore, QueryConfig, geolocate, retrieve, transfer
from geoloc.localize.reference import LabelledReference, label_reference_photo, stored_reference
from geoloc.localize.retrieval import Vocabulary, default_vocabulary
from geoloc.maps import CityMap
from geoloc.photos.photo import Photo, load_photo
from geoloc.sim.world import World, load_world
from geoloc.vision.evidence import PhotoEvidence, analyze_photo

KS = (1, 4, 8)
TOP_N = 10
QUERY_KINDS = ("between", "offset", "unseen")
SHOWN_MIN_SHARE = 0.1


@dataclass(frozen=True)
class EvalRun:
    """One way of answering the queries.

    Prior ("gps" or "none"), segmentation ("model" or "gt"), identities ("transferred" or "gt") and
    the query configuration.
    """

    name: str
    prior: str
    segmentation: str
    identities: str
    config: QueryConfig


def default_runs(config: QueryConfig) -> list[EvalRun]:
    """The runs of the module docstring."""
    paper = replace(config, use_anchors=False)
    return [
        EvalRun("ours/gps", "gps", "model", "transferred", config),
        EvalRun("ours/none", "none", "model", "transferred", config),
        EvalRun("gt_identities/gps", "gps", "model", "gt", config),
        EvalRun("gt_segmentation/gps", "gps", "gt", "transferred", config),
        EvalRun("paper_identity/none", "none", "model", "transferred", paper),
        EvalRun("paper_geometry/none", "none", "model", "transferred", replace(paper, use_identity=False)),
    ]


def evaluate_world(
    world_dir: str | Path,
    *,
    config: QueryConfig | None = None,
    runs: list[EvalRun] | None = None,
    vocabulary: Vocabulary | None = None,
    max_queries: int | None = None,
    progress: Callable[[str], None] | None = None,
    context: MethodContext,
) -> dict[str, Any]:
    """Run the method on a world folder and compare with its ground truth; returns a JSON-ready dict.

    context: the models and threads the method runs with (the figures do not depend on the thread counts).
    """
    say = progress or (lambda _msg: None)
    started = time.perf_counter()
    config = config or QueryConfig()
    runs = runs if runs is not None else default_runs(config)
    world = load_world(world_dir)
    city = world.load_map()
    vocabulary = vocabulary or default_vocabulary(context.models_dir)
    queries = world.queries[:max_queries] if max_queries else world.queries
    reference_names = [r.name for r in world.references]
    shown = {q.name: shown_by_references(world, q.name, reference_names) for q in queries}

    worlds: dict[str, _Labelled] = {}
    segmentations = sorted({run.segmentation for run in runs}) or ["model"]
    for segmentation in segmentations:
        worlds[segmentation] = _label_references(world, city, vocabulary, segmentation, say, context)
        worlds[segmentation].queries = {
            q.name: _analyze(q.path, world.gt(q.name)["labels"] if segmentation == "gt" else None, context)
            for q in queries
        }

    result: dict[str, Any] = {
        "world": str(world_dir),
        "map": world.manifest.get("map", {}).get("path") if hasattr(world, "manifest") else None,
        "references": len(world.references),
        "queries": len(queries),
        "query_kinds": {k: sum(q.record["kind"] == k for q in queries) for k in QUERY_KINDS},
        "shown_by_references": sum(bool(s["building"]) for s in shown.values()),
        "config": config.as_dict(),
        "reference_labelling": {seg: labelled.summary for seg, labelled in worlds.items()},
        "gps_baseline": _gps_baseline(world, city, queries),
    }
    # Tables I/II with the network's labels when a run uses them (the service's case).
    table_segmentation = "model" if "model" in worlds else segmentations[0]
    result["tables_segmentation"] = table_segmentation
    result.update(_transfer_tables(world, worlds[table_segmentation], vocabulary, config, queries, shown))
    result["runs"] = {}
    for run in runs:
        say(f"run {run.name}")
        labelled = worlds[run.segmentation]
        result["runs"][run.name] = _run(world, city, labelled, vocabulary, run, queries, shown, say, context)
    result["total_s"] = round(time.perf_counter() - started, 1)
    return result


# ----------------------------------------------------------------------------------------------
# References


@dataclass
class _Labelled:
    """References of one world labelled with one segmentation, their store, and the analysed queries."""

    store: InMemoryReferenceStore
    gt_store: InMemoryReferenceStore  # same references with ground-truth keypoint identities
    labelled: dict[str, LabelledReference]
    summary: dict[str, Any]
    queries: dict[str, tuple[Photo, PhotoEvidence]]


def _analyze(path: Path, labels: np.ndarray | None, context: MethodContext) -> tuple[Photo, PhotoEvidence]:
    photo = load_photo(path)
    return photo, analyze_photo(photo, labels, context=context)


def _label_references(
    world: World,
    city: CityMap,
    vocabulary: Vocabulary,
    segmentation: str,
    say: Callable[[str], None],
    context: MethodContext,
) -> _Labelled:
    store, gt_store = InMemoryReferenceStore(vocabulary), InMemoryReferenceStore(vocabulary)
    labelled: dict[str, LabelledReference] = {}
    accuracy: dict[str, list[float]] = {"greedy": [], "marginalized": []}
    heading_errors, position_errors, radius_held, orientation = [], [], [], []
    timings: dict[str, list[float]] = defaultdict(list)
    for i, image in enumerate(world.references):
        gt = world.gt(image.name)
        photo, evidence = _analyze(image.path, gt["labels"] if segmentation == "gt" else None, context)
        if photo.gps is None:
            raise ValueError(f"reference {image.name} has no EXIF GPS")
        gps_xy = tuple(float(v) for v in city.frame.to_local(*photo.gps))
        ref = label_reference_photo(city, photo, (gps_xy[0], gps_xy[1]), evidence=evidence, context=context)
        labelled[image.name] = ref
        for key, value in ref.timings_ms.items():
            timings[key].append(value)
        truth = gt["building_id"]
        accuracy["greedy"].append(identity_accuracy(ref.label.greedy.pixel_ids(), truth))
        accuracy["marginalized"].append(identity_accuracy(ref.label.marginalized.pixel_ids(), truth))
        pose = image.pose
        heading_errors.append(angle_error_deg(ref.label.yaw_deg, pose.yaw_deg))
        error = math.hypot(ref.label.x_m - pose.x_m, ref.label.y_m - pose.y_m)
        position_errors.append(error)
        sigma = math.sqrt(float(np.linalg.eigvalsh(ref.label.position_covariance).max()))
        radius_held.append(error <= math.sqrt(4.605) * sigma)
        orientation.append(
            orientation_errors(
                evidence.image_model, gt["column_theta_deg"], gt["column_building_id"] >= 0, photo.intrinsics
            )
        )
        store.add(stored_reference(image.name, ref))
        gt_kp, gt_ids = _gt_keypoint_identity(evidence.features.xy, truth)
        gt_store.add(replace(stored_reference(image.name, ref), keypoint_prob=gt_kp, building_ids=gt_ids))
        say(
            f"[{segmentation}] reference {i + 1}/{len(world.references)} {image.name}: "
            f"heading error {heading_errors[-1]:.1f} deg, position error {error:.1f} m"
        )
    summary = {
        "identity_accuracy": {k: _mean(v) for k, v in accuracy.items()},
        "heading_error_deg": _angle_summary(heading_errors),
        "position_error_m": _distance_summary(position_errors),
        "position_90_region_holds_truth": _mean([float(v) for v in radius_held]),
        "facade_orientation": {
            "median_abs_error_deg": _mean([o.median_abs_error_deg for o in orientation]),
            "within_5deg": _mean([o.within_5deg for o in orientation]),
            "coverage": _mean([o.coverage for o in orientation]),
        },
        "timing_ms": {k: round(float(np.median(v)), 1) for k, v in sorted(timings.items())},
    }
    return _Labelled(store, gt_store, labelled, summary, {})


def _gt_keypoint_identity(xy: np.ndarray, building_id: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-hot identities of keypoints from a ground-truth building-id image."""
    h, w = building_id.shape
    ids_at = building_id[
        np.clip(np.round(xy[:, 1]).astype(int), 0, h - 1), np.clip(np.round(xy[:, 0]).astype(int), 0, w - 1)
    ]
    ids = np.unique(ids_at[ids_at >= 0])
    return (ids_at[:, None] == ids[None, :]).astype(np.float32), ids


# ----------------------------------------------------------------------------------------------
# Queries


def _transfer_tables(
    world: World,
    labelled: _Labelled,
    vocabulary: Vocabulary,
    config: QueryConfig,
    queries: list[Any],
    shown: dict[str, dict[str, Any]],
) -> dict[str, Any]:
    """Table II (transfer accuracy for k = 1, 4, 8, our and ground-truth reference labels) and retrieval."""
    accuracy: dict[str, dict[int, list[float]]] = {"ours": defaultdict(list), "gt_reference_labels": defaultdict(list)}
    shown_accuracy: dict[int, list[float]] = defaultdict(list)
    hits: dict[int, list[bool]] = defaultdict(list)
    for image in queries:
        photo, evidence = labelled.queries[image.name]
        truth = world.gt(image.name)["building_id"]
        stored, matches = retrieve(evidence.features, labelled.store, vocabulary, config)  # the paper's: no prior
        gt_stored = labelled.gt_store.load(list(stored))
        best = shown[image.name]["references"]
        for k in KS:
            if best:
                hits[k].append(bool(best & {str(m.reference_id) for m in matches[:k]}))
            ours = identity_accuracy(transfer(evidence, stored, matches, k).pixel_ids(), truth)
            accuracy["ours"][k].append(ours)
            accuracy["gt_reference_labels"][k].append(
                identity_accuracy(transfer(evidence, gt_stored, matches, k).pixel_ids(), truth)
            )
            if shown[image.name]["building"]:
                shown_accuracy[k].append(ours)
    return {
        "query_identity_accuracy": {
            source: {str(k): _mean(values[k]) for k in KS} for source, values in accuracy.items()
        }
        | {"ours_shown_queries": {str(k): _mean(shown_accuracy[k]) for k in KS}},
        "retrieval": {f"best_overlap_in_top_{k}": _mean([float(h) for h in hits[k]]) for k in KS},
    }


def _run(
    world: World,
    city: CityMap,
    labelled: _Labelled,
    vocabulary: Vocabulary,
    run: EvalRun,
    queries: list[Any],
    shown: dict[str, dict[str, Any]],
    say: Callable[[str], None],
    context: MethodContext,
) -> dict[str, Any]:
    rows = []
    timings: dict[str, list[float]] = defaultdict(list)
    for i, image in enumerate(queries):
        photo, evidence = labelled.queries[image.name]
        gt = world.gt(image.name)
        prior = None
        if run.prior == "gps" and photo.gps is not None:
            x, y = (float(v) for v in city.frame.to_local(*photo.gps))
            prior = PositionPrior.from_radius(x, y, DEFAULT_PRIOR_RADIUS_M)
        override = None
        if run.identities == "gt":
            override = _gt_identity_map(gt["building_id"], evidence.building_mask)
        t0 = time.perf_counter()
        answer = geolocate(
            city,
            photo,
            evidence,
            labelled.store,
            vocabulary,
            run.config,
            position_prior=prior,
            top_n=TOP_N,
            identity_override=override,
            context=context,
        )
        timings["total"].append(1e3 * (time.perf_counter() - t0))
        for key, value in answer.timings_ms.items():
            timings[key].append(value)
        pose = image.pose
        errors = [math.hypot(p.x_m - pose.x_m, p.y_m - pose.y_m) for p in answer.poses]
        best = answer.poses[0]
        row = {
            "name": image.name,
            "kind": image.record["kind"],
            "shown": bool(shown[image.name]["building"]),
            "shown_facade_share": round(shown[image.name]["facade_share"], 3),
            "error_m": round(errors[0], 2),
            "heading_error_deg": round(angle_error_deg(best.yaw_deg, pose.yaw_deg), 2),
            "source": best.source,
            "inliers": answer.search["anchors"]["inliers"],
            "anchors_trusted": answer.search["anchors"]["trusted"],
            "anchor_checks": answer.search["anchors"]["checks"],
            "uncertainty_radius_m": round(best.uncertainty_radius_m, 2),
            "inside_radius": bool(errors[0] <= best.uncertainty_radius_m),
            "identity_accuracy": round(identity_accuracy(answer.identity.pixel_ids(), gt["building_id"]), 4),
            "transferred_identity_accuracy": round(
                identity_accuracy(answer.transferred.pixel_ids(), gt["building_id"]), 4
            ),
            "references_used": [str(r["reference_id"]) for r in answer.references],
            "anchor_references": answer.search["anchors"]["references"],
            "best_of_top_n_m": [
                round(v, 2) for v in np.minimum.accumulate(errors + [errors[-1]] * (TOP_N - len(errors)))
            ],
        }
        rows.append(row)
        say(
            f"  {run.name} {i + 1}/{len(queries)} {image.name} ({row['kind']}): {row['error_m']} m, "
            f"heading {row['heading_error_deg']} deg, {row['source']} ({row['inliers']} inliers), "
            f"radius {row['uncertainty_radius_m']} m"
        )
    summary = _run_summary(rows)
    summary["run"] = {"prior": run.prior, "segmentation": run.segmentation, "identities": run.identities}
    summary["config"] = run.config.as_dict()
    summary["timing_ms"] = {k: round(float(np.median(v)), 1) for k, v in sorted(timings.items())}
    summary["per_query"] = rows
    return summary


def _run_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    def block(subset: list[dict[str, Any]]) -> dict[str, Any]:
        errors = np.array([r["error_m"] for r in subset], dtype=float)
        heading = np.array([r["heading_error_deg"] for r in subset], dtype=float)
        if len(errors) == 0:
            return {"n": 0}
        return {
            "n": len(errors),
            "median_error_m": round(float(np.median(errors)), 2),
            "within_1m": round(float(np.mean(errors <= 1.0)), 4),
            "within_5m": round(float(np.mean(errors <= 5.0)), 4),
            "within_10m": round(float(np.mean(errors <= 10.0)), 4),
            "heading_median_deg": round(float(np.median(heading)), 2),
            "heading_within_5deg": round(float(np.mean(heading <= 5.0)), 4),
        }

    best_of_n = np.array([r["best_of_top_n_m"] for r in rows], dtype=float)
    shown_rows = [r for r in rows if r["shown"]]
    return {
        "all": block(rows),
        "shown": block(shown_rows),
        "by_kind": {kind: block([r for r in rows if r["kind"] == kind]) for kind in QUERY_KINDS},
        "uncertainty_radius_holds_truth": _mean([float(r["inside_radius"]) for r in rows]),
        "uncertainty_radius_median_m": round(float(np.median([r["uncertainty_radius_m"] for r in rows])), 2),
        "anchored_share": _mean([float(r["source"] == "anchors") for r in rows]),
        "identity_accuracy_shown": _mean([r["identity_accuracy"] for r in shown_rows]),
        "top_n_error_m": {str(n): _mean_ci(best_of_n[:, n - 1]) for n in range(1, TOP_N + 1)},
    }


def _gt_identity_map(building_id: np.ndarray, building_mask: np.ndarray) -> IdentityMap:
    """Per-column identities from the renderer's building ids (each column: its buildings' pixel shares)."""
    ids = np.unique(building_id[building_id >= 0])
    width = building_id.shape[1]
    prob = np.zeros((width, len(ids)), np.float32)
    if len(ids):
        slot = np.searchsorted(ids, building_id)
        rows, cols = np.nonzero(building_id >= 0)
        np.add.at(prob, (cols, slot[rows, cols]), 1.0)
        prob /= np.maximum(prob.sum(axis=1, keepdims=True), 1.0)
    return IdentityMap(ids, prob, building_mask)


def _gps_baseline(world: World, city: CityMap, queries: list[Any]) -> dict[str, Any]:
    errors = []
    for image in queries:
        gps = image.record.get("gps")
        if not gps:
            continue
        x, y = city.frame.to_local(gps["lat"], gps["lon"])
        errors.append(math.hypot(float(x) - image.pose.x_m, float(y) - image.pose.y_m))
    return _distance_summary(errors)


def shown_by_references(world: World, query_name: str, reference_names: list[str]) -> dict[str, Any]:
    """Which references show the query's buildings (building pixels shared >= 0.1 of the image).

    Returns ``building`` (bool), ``references`` (the names sharing the most, ties within 0.02; empty when
    none shares 0.1) and ``facade_share`` (the best share counted per facade instead of per building).
    """
    query_record = world.image(query_name).record
    shares = {b["building_id"]: b["pixel_share"] for b in query_record["buildings"]}
    overlap = {}
    for name in reference_names:
        ref_shares = {b["building_id"]: b["pixel_share"] for b in world.image(name).record["buildings"]}
        overlap[name] = sum(min(s, ref_shares.get(b, 0.0)) for b, s in shares.items())
    top = max(overlap.values(), default=0.0)
    best = {name for name, value in overlap.items() if value >= top - 0.02} if top >= SHOWN_MIN_SHARE else set()
    return {
        "building": bool(best),
        "references": best,
        "facade_share": _facade_share(world, query_name, reference_names),
    }


def _facade_share(world: World, query_name: str, reference_names: list[str]) -> float:
    def shares(name: str) -> dict[int, float]:
        facade = world.gt(name)["facade_id"]
        ids, counts = np.unique(facade[facade >= 0], return_counts=True)
        return dict(zip(ids.tolist(), (counts / facade.size).tolist(), strict=True))

    query = shares(query_name)
    return max((sum(min(v, shares(n).get(f, 0.0)) for f, v in query.items()) for n in reference_names), default=0.0)


# ----------------------------------------------------------------------------------------------
# Small helpers


def angle_error_deg(a: float, b: float) -> float:
    """Absolute difference of two angles (deg), in [0, 180]."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def _mean(values: list[float]) -> float | None:
    vals = [v for v in values if v is not None and not math.isnan(v)]
    return round(float(np.mean(vals)), 4) if vals else None


def _mean_ci(values: np.ndarray) -> dict[str, Any]:
    n = len(values)
    mean = float(np.mean(values))
    half = 1.96 * float(np.std(values, ddof=1)) / math.sqrt(n) if n > 1 else float("nan")
    return {"mean": round(mean, 3), "ci95": [round(mean - half, 3), round(mean + half, 3)]}


def _angle_summary(errors: list[float]) -> dict[str, Any]:
    arr = np.asarray(errors, dtype=float)
    if arr.size == 0:
        return {"n": 0}
    return {
        "n": int(arr.size),
        "median": round(float(np.median(arr)), 3),
        "within_5deg": round(float(np.mean(arr <= 5.0)), 4),
    }


def _distance_summary(errors: list[float]) -> dict[str, Any]:
    arr = np.asarray(errors, dtype=float)
    if arr.size == 0:
        return {"n": 0}
    return {
        "n": int(arr.size),
        "median_m": round(float(np.median(arr)), 2),
        "within_5m": round(float(np.mean(arr <= 5.0)), 4),
        "within_10m": round(float(np.mean(arr <= 10.0)), 4),
    }


def evaluate_photos(
    photos_dir: str | Path, map_path: str | Path, truth_csv: str | Path | None = None, *, context: MethodContext
) -> dict[str, Any]:
    """Label real geo-tagged photos on a map with their EXIF GPS (the service's reference labelling).

    context: the models and threads the labelling runs with.

    truth_csv: optional CSV with ``name`` and ``true_heading_deg`` columns (e.g. the phone's compass). Returns
    per photo the estimated compass heading and position, how far labelling moved it from the GPS tag,
    the buildings named, and the heading error against the truth.
    """
    import csv

    from geoloc.maps import load_map

    city = load_map(map_path)
    truth: dict[str, dict[str, str]] = {}
    if truth_csv is not None:
        with open(truth_csv, newline="") as handle:
            truth = {row["name"]: row for row in csv.DictReader(handle)}
    rows = []
    for path in sorted(Path(photos_dir).iterdir()):
        if path.suffix.lower() not in (".jpg", ".jpeg", ".png"):
            continue
        photo = load_photo(path)
        if photo.gps is None:
            continue
        gps_x, gps_y = (float(v) for v in city.frame.to_local(*photo.gps))
        labelled = label_reference_photo(city, photo, (gps_x, gps_y), context=context)
        label = labelled.label
        heading = float(city.frame.bearing_to_heading(label.yaw_deg, label.x_m, label.y_m)) % 360.0
        lat, lon = (float(v) for v in city.frame.to_wgs84(label.x_m, label.y_m))
        names = []
        for entry in labelled.identity.building_extents():
            building = city.buildings[entry["building_id"]]
            names.append(building.name or building.osm_id)
        row: dict[str, Any] = {
            "name": path.name,
            "heading_deg": round(heading, 2),
            "lat": round(lat, 7),
            "lon": round(lon, 7),
            "moved_m": round(math.hypot(label.x_m - gps_x, label.y_m - gps_y), 2),
            "buildings": names,
            "vanishing_point_bins": label.vp_bins,
        }
        if path.name in truth:
            compass = float(truth[path.name]["true_heading_deg"])
            row["compass_heading_deg"] = compass
            row["heading_error_deg"] = round(angle_error_deg(heading, compass), 2)
        rows.append(row)
    errors = [r["heading_error_deg"] for r in rows if "heading_error_deg" in r]
    return {
        "map": str(map_path),
        "photos_dir": str(photos_dir),
        "photos": rows,
        "heading_within_10deg": _mean([float(e <= 10.0) for e in errors]),
        "heading_error_median_deg": round(float(np.median(errors)), 2) if errors else None,
    }
