"""Evaluation of the whole method on a simulated world (``geoloc eval world DIR --json OUT``).

The world's references are ingested as a user would (EXIF GPS and focal length read from the JPEG),
labelled with the map, described by local features and indexed; its queries are then geolocated.
Everything is compared with the renderer's ground truth:

- ``reference_identity_accuracy``: greedy / marginalised per-pixel building identity of references
  (paper Table I), on ground-truth building pixels only;
- ``query_identity_accuracy``: for k = 1, 4, 8 retrieved references, with our reference labels and
  with ground-truth reference labels (paper Table II);
- ``reference_heading_error_deg`` / ``query_heading_error_deg``: median and share within 5 deg;
- ``localization``: for ``with_identity`` and ``geometry_only`` (same candidate grid, likelihood
  with or without identities), the error of the best of the top-N positions for N = 1..10 (mean and
  95 % confidence interval, the paper's Fig. 7) and recall within 5 m / 10 m at N = 1;
- ``facade_orientation``: image-side orientation accuracy per building column;
- ``retrieval``: how often a reference sharing the most building area with the query is in the top k
  (SBoW shortlist of 20, re-ranked by verified inliers), over queries that share at least 0.1 with one;
- ``timing_ms``: median per stage.

``segmentation="gt"`` replaces the network's labels by the ground-truth labels everywhere, to separate
segmentation error from the rest.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoloc.facade_metrics import orientation_errors
from geoloc.identity import identity_accuracy
from geoloc.localize import localize
from geoloc.pipeline import (
    LabelledReference,
    PhotoEvidence,
    analyze_photo,
    image_model_with_identity,
    label_reference_photo,
    load_photo,
)
from geoloc.retrieval import InvertedIndex, Vocabulary, default_vocabulary
from geoloc.sim.world import World, load_world
from geoloc.transfer import ReferenceEvidence, ReferenceMatch, rerank_by_inliers, transfer_identities

KS = (1, 4, 8)
SHORTLIST = 20  # SBoW candidates re-ranked by verified inliers before the top k are used
TOP_N = 10
DEFAULT_LOCALIZE_K = 4


@dataclass
class _Reference:
    name: str
    labelled: LabelledReference
    words: np.ndarray
    gt_keypoint_identity: np.ndarray  # (N, M_gt) one-hot from the renderer's building ids
    gt_building_ids: np.ndarray


def _angle_error_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def _summary(errors: list[float], within: float = 5.0) -> dict:
    arr = np.asarray(errors, dtype=float)
    if arr.size == 0:
        return {"median": None, f"within_{within:g}deg": None, "n": 0}
    return {
        "median": round(float(np.median(arr)), 3),
        f"within_{within:g}deg": round(float(np.mean(arr <= within)), 4),
        "n": int(arr.size),
    }


def _mean_ci(values: np.ndarray) -> dict:
    n = len(values)
    mean = float(np.mean(values))
    half = 1.96 * float(np.std(values, ddof=1)) / math.sqrt(n) if n > 1 else float("nan")
    return {"mean": round(mean, 3), "ci95": [round(mean - half, 3), round(mean + half, 3)]}


def _gt_keypoint_identity(xy: np.ndarray, building_id: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-hot identities of keypoints from a ground-truth building-id image."""
    h, w = building_id.shape
    ids_at = building_id[
        np.clip(np.round(xy[:, 1]).astype(int), 0, h - 1), np.clip(np.round(xy[:, 0]).astype(int), 0, w - 1)
    ]
    ids = np.unique(ids_at[ids_at >= 0])
    return (ids_at[:, None] == ids[None, :]).astype(np.float32), ids


def _stage_times(timings: dict[str, list[float]], stage_ms: dict[str, float]) -> None:
    for key, value in stage_ms.items():
        timings[key].append(float(value))


def evaluate_world(
    world_dir: str | Path,
    *,
    segmentation: str = "model",
    vocabulary: Vocabulary | None = None,
    localize_k: int = DEFAULT_LOCALIZE_K,
    max_queries: int | None = None,
    progress: Callable[[str], None] | None = None,
    **localize_options: float,
) -> dict:
    """Run the method on a world folder and compare with its ground truth; returns a JSON-ready dict."""
    if segmentation not in ("model", "gt"):
        raise ValueError("segmentation must be 'model' or 'gt'")
    say = progress or (lambda _msg: None)
    started = time.perf_counter()
    world: World = load_world(world_dir)
    city = world.load_map()
    frame = city.frame
    vocabulary = vocabulary or default_vocabulary(progress=False)
    timings: dict[str, list[float]] = defaultdict(list)

    def evidence_of(image, gt) -> tuple[PhotoEvidence, object]:
        photo = load_photo(image.path)
        return analyze_photo(photo, gt["labels"] if segmentation == "gt" else None), photo

    # -- references ---------------------------------------------------------------------------
    references: list[_Reference] = []
    ref_acc = {"greedy": [], "marginalized": []}
    ref_heading_errors, orientation = [], []
    index = InvertedIndex()
    for i, image in enumerate(world.references):
        gt = world.gt(image.name)
        evidence, photo = evidence_of(image, gt)
        if photo.gps is None:
            raise ValueError(f"reference {image.name} has no EXIF GPS")
        gps_xy = tuple(float(v) for v in frame.to_local(*photo.gps))
        labelled = label_reference_photo(city, photo, gps_xy, evidence=evidence)
        _stage_times(timings, {f"reference_{k}": v for k, v in labelled.timings_ms.items()})
        truth = gt["building_id"]
        ref_acc["greedy"].append(identity_accuracy(labelled.label.greedy.pixel_ids(), truth))
        ref_acc["marginalized"].append(identity_accuracy(labelled.label.marginalized.pixel_ids(), truth))
        ref_heading_errors.append(_angle_error_deg(labelled.label.yaw_deg, image.pose.yaw_deg))
        orientation.append(
            orientation_errors(
                evidence.image_model, gt["column_theta_deg"], gt["column_building_id"] >= 0, photo.intrinsics
            )
        )
        t0 = time.perf_counter()
        words = vocabulary.words(evidence.features.descriptors)
        index.add(image.name, words)
        timings["reference_index"].append(1e3 * (time.perf_counter() - t0))
        gt_kp, gt_ids = _gt_keypoint_identity(evidence.features.xy, truth)
        references.append(_Reference(image.name, labelled, words, gt_kp, gt_ids))
        say(f"reference {i + 1}/{len(world.references)} {image.name}: heading error {ref_heading_errors[-1]:.1f} deg")
    by_name = {r.name: r for r in references}

    # -- queries ------------------------------------------------------------------------------
    queries = world.queries[:max_queries] if max_queries else world.queries
    query_acc: dict[str, dict[int, list[float]]] = {"ours": defaultdict(list), "gt_reference_labels": defaultdict(list)}
    errors = {"with_identity": [], "geometry_only": []}
    query_heading_errors = {"with_identity": [], "geometry_only": []}
    retrieval_hits = defaultdict(list)
    for i, image in enumerate(queries):
        gt = world.gt(image.name)
        truth = gt["building_id"]
        evidence, photo = evidence_of(image, gt)
        _stage_times(timings, {f"query_{k}": v for k, v in evidence.timings_ms.items()})
        t0 = time.perf_counter()
        shortlist = index.query(vocabulary.words(evidence.features.descriptors), SHORTLIST)
        timings["query_retrieval"].append(1e3 * (time.perf_counter() - t0))
        t0 = time.perf_counter()
        candidates = [(name, score, by_name[name].labelled.evidence.features) for name, score in shortlist]
        matches = rerank_by_inliers(evidence.features, candidates, max(KS))
        timings["query_rerank"].append(1e3 * (time.perf_counter() - t0))
        ranked_names = [m.reference_id for m in matches]
        best_overlap = _best_overlapping_references(world, image.name, [r.name for r in references])
        for k in KS:
            retrieval_hits[k].append(bool(best_overlap & set(ranked_names[:k])) if best_overlap else None)

        identity_k = {}
        for k in KS:
            for source in ("ours", "gt_reference_labels"):
                evidences = [_reference_evidence(by_name[m.reference_id], m, source) for m in matches[:k]]
                t0 = time.perf_counter()
                transferred = transfer_identities(evidence.features, evidence.building_mask, evidences)
                if source == "ours":
                    timings[f"query_transfer_k{k}"].append(1e3 * (time.perf_counter() - t0))
                    identity_k[k] = transferred.identity
                query_acc[source][k].append(identity_accuracy(transferred.identity.pixel_ids(), truth))

        model = image_model_with_identity(evidence, identity_k[localize_k], photo.intrinsics)
        true_xy = np.array([image.pose.x_m, image.pose.y_m])
        for mode, use_identity in (("with_identity", True), ("geometry_only", False)):
            t0 = time.perf_counter()
            found = localize(city, model, use_identity=use_identity, top_n=TOP_N, **localize_options)
            timings[f"query_localize_{mode}"].append(1e3 * (time.perf_counter() - t0))
            xy = np.array([[p.x_m, p.y_m] for p in found.poses])
            dist = np.hypot(*(xy - true_xy).T)
            best_of_n = np.minimum.accumulate(np.pad(dist, (0, TOP_N - len(dist)), mode="edge"))
            errors[mode].append(best_of_n)
            query_heading_errors[mode].append(_angle_error_deg(found.poses[0].yaw_deg, image.pose.yaw_deg))
        say(
            f"query {i + 1}/{len(queries)} {image.name}: error {errors['with_identity'][-1][0]:.1f} m with identity, "
            f"{errors['geometry_only'][-1][0]:.1f} m geometry only"
        )

    def localization_block(mode: str) -> dict:
        arr = np.array(errors[mode])  # (Q, TOP_N)
        return {
            "top_n_error_m": {str(n): _mean_ci(arr[:, n - 1]) for n in range(1, TOP_N + 1)},
            "median_error_m_at_1": round(float(np.median(arr[:, 0])), 3),
            "recall_5m_at_1": round(float(np.mean(arr[:, 0] <= 5.0)), 4),
            "recall_10m_at_1": round(float(np.mean(arr[:, 0] <= 10.0)), 4),
        }

    def mean(values: list[float]) -> float | None:
        vals = [v for v in values if v is not None and not math.isnan(v)]
        return round(float(np.mean(vals)), 4) if vals else None

    return {
        "world": str(world_dir),
        "segmentation": segmentation,
        "references": len(references),
        "queries": len(queries),
        "reference_identity_accuracy": {k: mean(v) for k, v in ref_acc.items()},
        "query_identity_accuracy": {
            source: {str(k): mean(query_acc[source][k]) for k in KS} for source in ("ours", "gt_reference_labels")
        },
        "reference_heading_error_deg": _summary(ref_heading_errors),
        "query_heading_error_deg": {mode: _summary(v) for mode, v in query_heading_errors.items()},
        "localization": {mode: localization_block(mode) for mode in errors},
        "localize_k": localize_k,
        "facade_orientation": {
            "median_abs_error_deg": mean([o.median_abs_error_deg for o in orientation]),
            "within_5deg": mean([o.within_5deg for o in orientation]),
            "within_10deg": mean([o.within_10deg for o in orientation]),
            "coverage": mean([o.coverage for o in orientation]),
        },
        "retrieval": {
            f"best_overlap_in_top_{k}": mean([float(h) for h in hits if h is not None])
            for k, hits in retrieval_hits.items()
        },
        "timing_ms": {k: round(float(np.median(v)), 1) for k, v in sorted(timings.items())},
        "total_s": round(time.perf_counter() - started, 1),
    }


def _reference_evidence(ref: _Reference, match: ReferenceMatch, source: str) -> ReferenceEvidence:
    if source == "ours":
        identity, ids = ref.labelled.keypoint_identity, ref.labelled.identity.building_ids
    else:
        identity, ids = ref.gt_keypoint_identity, ref.gt_building_ids
    return ReferenceEvidence(
        reference_id=ref.name,
        features=ref.labelled.evidence.features,
        keypoint_prob=identity,
        building_ids=ids,
        score=match.score,
        match=match,
    )


def _best_overlapping_references(world: World, query_name: str, reference_names: list[str]) -> set[str]:
    """The references sharing the most building area with the query (sum over buildings of the smaller
    of the two pixel shares), ties within 0.02 included; empty when none shares 0.1 ("unseen" queries)."""
    shares = {b["building_id"]: b["pixel_share"] for b in world.image(query_name).record["buildings"]}
    overlap = {}
    for name in reference_names:
        ref_shares = {b["building_id"]: b["pixel_share"] for b in world.image(name).record["buildings"]}
        overlap[name] = sum(min(s, ref_shares.get(b, 0.0)) for b, s in shares.items())
    top = max(overlap.values(), default=0.0)
    return {name for name, value in overlap.items() if value >= top - 0.02} if top >= 0.1 else set()
