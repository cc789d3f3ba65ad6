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
from geoloc.evaluation.walks import compass_prior_at
from geoloc.localize.grid import PositionPrior
from geoloc.localize.identity import IdentityMap, identity_accuracy
from geoloc.localize.query import QueryConfig, geolocate, retrieve, transfer
from geoloc.localize.query.answer import QueryAnswer
from geoloc.localize.query.stage import IdentityUse, locate, retrieve_and_transfer
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.store import ReferenceStore
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from geoloc.sim.world import World
from geoloc.vision.evidence import PhotoEvidence

KS = (1, 4, 8)
IDENTITY_LOSS_PARTS = ("outside_mask", "no_identity", "building_shown", "building_not_shown", "right")
"""Where a query's ground-truth building pixels end up after the transfer (:func:`identity_losses`)."""
LOSSES_K = 4
"""The transfer's k at which :func:`transfer_tables` breaks the identity accuracy down (issue 19's must-hold's)."""


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
    """Table II (transfer accuracy for k = 1, 4, 8, our and ground-truth reference labels), retrieval, and more.

    ``query_identity_losses``: where the shown queries' building pixels go at k = :data:`LOSSES_K` (the means of
    :func:`identity_losses`).
    """
    accuracy: dict[str, dict[int, list[float]]] = {"ours": defaultdict(list), "gt_reference_labels": defaultdict(list)}
    shown_accuracy: dict[int, list[float]] = defaultdict(list)
    shown_losses: list[dict[str, float]] = []
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
            predicted = transfer(evidence, stored, matches, k).pixel_ids()
            ours = identity_accuracy(predicted, truth)
            accuracy["ours"][k].append(ours)
            if k == LOSSES_K and shown[image.name]["building"]:
                shown_losses.append(identity_losses(predicted, truth, evidence.building_mask))
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
        "query_identity_losses": {
            part: mean_or_none([losses[part] for losses in shown_losses]) for part in IDENTITY_LOSS_PARTS
        },
        "retrieval": {f"best_overlap_in_top_{k}": mean_or_none([float(h) for h in hits[k]]) for k in KS},
    }


def identity_losses(predicted: np.ndarray, truth: np.ndarray, building_mask: np.ndarray) -> dict[str, float]:
    """Shares of a query's ground-truth building pixels, by what the transfer made of them (they sum to 1).

    predicted, truth: (H, W) building ids (-1 none); building_mask: (H, W) bool, the segmentation's building
    pixels. ``right``: the truth (:func:`geoloc.localize.identity.identity_accuracy`); of the others,
    ``outside_mask``: the segmentation did not call the pixel a building (the transfer does not reach it);
    ``no_identity``: a building pixel the transfer left without an identity; ``building_shown``: another building
    the query shows (neighbours confused); ``building_not_shown``: a building the query does not
    show at all (a wrong reference's). Empty truth: every share NaN.
    """
    on = truth >= 0
    n = int(on.sum())
    if n == 0:
        return dict.fromkeys(IDENTITY_LOSS_PARTS, math.nan)
    right = on & (predicted == truth)
    inside = on & ~right & building_mask
    wrong = inside & (predicted >= 0)
    shown = np.isin(predicted, np.unique(truth[on]))
    counts = {
        "outside_mask": on & ~right & ~building_mask,
        "no_identity": inside & (predicted < 0),
        "building_shown": wrong & shown,
        "building_not_shown": wrong & ~shown,
        "right": right,
    }
    return {part: float(mask.sum()) / n for part, mask in counts.items()}


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


def geolocate_with_identities(
    city: CityMap,
    photo: Photo,
    evidence: PhotoEvidence,
    store: ReferenceStore,
    vocabulary: Vocabulary,
    identity: IdentityMap,
    config: QueryConfig,
    position_prior: PositionPrior | None,
    heading_prior: HeadingPrior | None,
    context: MethodContext,
) -> QueryAnswer:
    """:func:`geolocate` with these identities (ground truth: the ablation's ceiling) in place of the transferred.

    The stage's own steps (:func:`geoloc.localize.query.stage.retrieve_and_transfer`, then
    :func:`geoloc.localize.query.stage.locate`); the identities are trusted fully and not read again at a trusted
    anchored pose. The answer's ``transferred`` is still what the retrieval transferred.
    """
    retrieved = retrieve_and_transfer(evidence, store, vocabulary, config, position_prior, context)
    use = IdentityUse(identity, 1.0, read_at_trusted_pose=False)
    return locate(city, photo, evidence, retrieved, use, config, position_prior, heading_prior, TOP_N, context)


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
        truth = gt_identity_map(gt["building_id"], evidence.building_mask) if run.identities == "gt" else None
        t0 = time.perf_counter()
        if truth is not None:
            answer = geolocate_with_identities(
                city, photo, evidence, labelled.store, vocabulary, truth, run.config, prior, heading_prior, context
            )
        else:
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
            "inliers": answer.search.anchors.inliers,
            "anchors_trusted": answer.search.anchors.trusted,
            "anchor_checks": answer.search.anchors.checks,
            "uncertainty_radius_m": round(best.uncertainty_radius_m, 2),
            "probability": round(best.probability, 4),
            # how far the answer lies from its position prior's centre (the query's GPS fix), None without one
            "prior_distance_m": None
            if prior is None
            else round(math.hypot(best.x_m - prior.x_m, best.y_m - prior.y_m), 2),
            "inside_radius": bool(errors[0] <= best.uncertainty_radius_m),
            "identity_accuracy": round(identity_accuracy(answer.identity.pixel_ids(), gt["building_id"]), 4),
            "transferred_identity_accuracy": round(
                identity_accuracy(answer.transferred.pixel_ids(), gt["building_id"]), 4
            ),
            "references_used": [str(r.reference_id) for r in answer.references],
            "anchor_references": answer.search.anchors.references,
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
