"""The evaluation's queries: Tables I/II's transfer accuracy and retrieval, and one run's answers to every query."""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from contracts.queries import gps_prior_radius_m
from geoloc.core.context import MethodContext
from geoloc.core.geo import angle_difference_deg
from geoloc.evaluation.ground_truth import gt_identity_map
from geoloc.evaluation.references import LabelledWorld
from geoloc.evaluation.summaries import TOP_N, mean_or_none, run_summary
from geoloc.localize.grid import PositionPrior
from geoloc.localize.identity import identity_accuracy
from geoloc.localize.query import QueryConfig, geolocate, retrieve, transfer
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.sequence.stage import compass_prior_at
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from geoloc.sim.world import World

KS = (1, 4, 8)


@dataclass(frozen=True)
class EvalRun:
    """One way of answering the queries.

    Prior ("gps", "none", or "given": the caller's per-query priors, e.g. a named place's), segmentation
    ("model" or "gt"), identities ("transferred" or "gt"), the query configuration, and the references' poses
    ("placed": as the service labels and places them; "truth": each re-labelled at its manifest pose, its
    identities and anchors from there, :func:`geoloc.evaluation.references.references_at_truth`).
    """

    name: str
    prior: str
    segmentation: str
    identities: str
    config: QueryConfig
    references: str = "placed"


def transfer_tables(
    world: World,
    labelled: LabelledWorld,
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
            source: {str(k): mean_or_none(values[k]) for k in KS} for source, values in accuracy.items()
        }
        | {"ours_shown_queries": {str(k): mean_or_none(shown_accuracy[k]) for k in KS}},
        "retrieval": {f"best_overlap_in_top_{k}": mean_or_none([float(h) for h in hits[k]]) for k in KS},
    }


def photo_priors(photo: Photo, city: CityMap, prior: str) -> tuple[PositionPrior | None, HeadingPrior | None]:
    """A query's (position, heading) priors for a run's ``prior``.

    With "gps", what the service reads from the photo: its EXIF GPS (radius
    :func:`contracts.queries.gps_prior_radius_m` of the accuracy it states) and its compass when it has one;
    otherwise none.
    """
    if prior != "gps" or photo.gps is None:
        return None, None
    x, y = (float(v) for v in city.frame.to_local(*photo.gps))
    radius_m = gps_prior_radius_m(photo.capture.gps_accuracy_m)
    return PositionPrior.from_radius(x, y, radius_m), compass_prior_at(photo, city, (x, y))


def answer_run(
    world: World,
    city: CityMap,
    labelled: LabelledWorld,
    vocabulary: Vocabulary,
    run: EvalRun,
    queries: list[Any],
    shown: dict[str, dict[str, Any]],
    say: Callable[[str], None],
    context: MethodContext,
    given_priors: Mapping[str, PositionPrior] | None = None,
) -> dict[str, Any]:
    """Answer every query once as ``run`` says; the run's summary (:func:`run_summary`) with a per-query table.

    given_priors: the position prior of each query (by name) for a run with prior "given" (none if missing).
    """
    rows = []
    timings: dict[str, list[float]] = defaultdict(list)
    for i, image in enumerate(queries):
        photo, evidence = labelled.queries[image.name]
        gt = world.gt(image.name)
        prior, heading_prior = photo_priors(photo, city, run.prior)
        if run.prior == "given" and given_priors and image.name in given_priors:
            prior = given_priors[image.name]  # the compass still counts: the service reads it without GPS
            heading_prior = compass_prior_at(photo, city, (prior.x_m, prior.y_m))
        override = None
        if run.identities == "gt":
            override = gt_identity_map(gt["building_id"], evidence.building_mask)
        t0 = time.perf_counter()
        answer = geolocate(
            city,
            photo,
            evidence,
            labelled.store,
            vocabulary,
            run.config,
            position_prior=prior,
            heading_prior=heading_prior,
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
            "heading_error_deg": round(angle_difference_deg(best.yaw_deg, pose.yaw_deg), 2),
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
    summary = run_summary(rows)
    summary["run"] = {"prior": run.prior, "segmentation": run.segmentation, "identities": run.identities}
    summary["config"] = run.config.as_dict()
    summary["timing_ms"] = {k: round(float(np.median(v)), 1) for k, v in sorted(timings.items())}
    summary["per_query"] = rows
    return summary
