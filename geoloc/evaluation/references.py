"""The evaluation's references: a world's reference photos labelled as the service labels them, and their store."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.core.context import MethodContext
from geoloc.core.geo import angle_difference_deg
from geoloc.evaluation.facades import orientation_errors
from geoloc.evaluation.ground_truth import gt_keypoint_identity
from geoloc.evaluation.store import InMemoryReferenceStore
from geoloc.evaluation.summaries import (
    mean_or_none,
    per_walk_summary,
    reference_heading_summary,
    reference_position_summary,
)
from geoloc.evaluation.walks import compass_prior_at, place_photo_walks
from geoloc.localize.identity import identity_accuracy
from geoloc.localize.labeling import KnownPose
from geoloc.localize.reference import LabelledReference, label_at_pose, label_reference_photo, stored_reference
from geoloc.localize.retrieval import Vocabulary
from geoloc.maps import CityMap
from geoloc.photos.photo import Photo, load_photo
from geoloc.sim.world import World
from geoloc.vision.evidence import PhotoEvidence, analyze_photo


@dataclass
class LabelledWorld:
    """References of one world labelled with one segmentation, their store, and the analysed queries."""

    store: InMemoryReferenceStore
    gt_store: InMemoryReferenceStore  # same references with ground-truth keypoint identities
    labelled: dict[str, LabelledReference]
    summary: dict[str, Any]
    queries: dict[str, tuple[Photo, PhotoEvidence]]
    intrinsics: dict[str, Intrinsics] = field(default_factory=dict)  # each reference's camera, from its EXIF


def analyze(path: Path, labels: np.ndarray | None, context: MethodContext) -> tuple[Photo, PhotoEvidence]:
    """The photo at ``path`` and its evidence (segmentation from ``labels`` when given, e.g. ground truth)."""
    photo = load_photo(path)
    return photo, analyze_photo(photo, labels, context=context)


def label_world_alone(
    world: World, city: CityMap, segmentation: str, say: Callable[[str], None], context: MethodContext
) -> tuple[dict[str, Photo], dict[str, LabelledReference]]:
    """Every reference of ``world`` labelled alone, as the workers' label job does (its compass the heading prior).

    The world's counterpart of the workers' :func:`workers.reference_labels.label_alone` (one stored row): both
    are :func:`geoloc.localize.reference.label_reference_photo` with the photo's GPS and compass prior.

    segmentation: "model" (the network) or "gt" (ground-truth labels). Returns the photos and their labels, by
    name in the world's order (a walk's frames are placed afterwards: :func:`place_photo_walks`).
    """
    photos: dict[str, Photo] = {}
    labelled: dict[str, LabelledReference] = {}
    for i, image in enumerate(world.references):
        gt = world.gt(image.name)
        photo, evidence = analyze(image.path, gt["labels"] if segmentation == "gt" else None, context)
        if photo.gps is None:
            raise ValueError(f"reference {image.name} has no EXIF GPS")
        gps_xy = tuple(float(v) for v in city.frame.to_local(*photo.gps))
        prior = compass_prior_at(photo, city, (gps_xy[0], gps_xy[1]))
        labelled[image.name] = label_reference_photo(
            city, photo, (gps_xy[0], gps_xy[1]), heading_prior=prior, evidence=evidence, context=context
        )
        photos[image.name] = photo
        say(f"[{segmentation}] reference {i + 1}/{len(world.references)} {image.name} labelled")
    return photos, labelled


def label_references(
    world: World,
    city: CityMap,
    vocabulary: Vocabulary,
    segmentation: str,
    say: Callable[[str], None],
    context: MethodContext,
) -> LabelledWorld:
    """Label every reference of ``world`` with ``segmentation`` ("model" or "gt"); stores and Table I figures."""
    store, gt_store = InMemoryReferenceStore(vocabulary), InMemoryReferenceStore(vocabulary)
    accuracy: dict[str, list[float]] = {"greedy": [], "marginalized": []}
    heading_errors, position_errors, radius_held, orientation = [], [], [], []
    walk_ids: list[int | None] = []  # each reference's walk (walk worlds; None in a scattered one)
    timings: dict[str, list[float]] = defaultdict(list)
    photos, labelled = label_world_alone(world, city, segmentation, say, context)
    walks = place_photo_walks(city, photos, labelled)  # the workers' sequence job, on the same photos
    for walk in walks:
        say(f"walk of {len(walk.references)} references placed ({walk.n_edges} relative poses)")
    for image in world.references:
        gt = world.gt(image.name)
        ref, photo = labelled[image.name], photos[image.name]
        evidence = ref.evidence
        walk_ids.append(image.record["walk"]["walk_id"] if "walk" in image.record else None)
        for key, value in ref.timings_ms.items():
            timings[key].append(value)
        truth = gt["building_id"]
        accuracy["greedy"].append(identity_accuracy(ref.label.greedy.pixel_ids(), truth))
        accuracy["marginalized"].append(identity_accuracy(ref.label.marginalized.pixel_ids(), truth))
        pose = image.pose
        heading_errors.append(angle_difference_deg(ref.label.yaw_deg, pose.yaw_deg))
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
        gt_kp, gt_ids = gt_keypoint_identity(evidence.features.xy, truth)
        gt_store.add(replace(stored_reference(image.name, ref), keypoint_prob=gt_kp, building_ids=gt_ids))
        say(
            f"[{segmentation}] reference {image.name}: "
            f"heading error {heading_errors[-1]:.1f} deg, position error {error:.1f} m"
        )
    summary: dict[str, Any] = {
        "identity_accuracy": {k: mean_or_none(v) for k, v in accuracy.items()},
        "heading_error_deg": reference_heading_summary(heading_errors),
        "position_error_m": reference_position_summary(position_errors),
        "position_90_region_holds_truth": mean_or_none([float(v) for v in radius_held]),
        "facade_orientation": {
            "median_abs_error_deg": mean_or_none([o.median_abs_error_deg for o in orientation]),
            "within_5deg": mean_or_none([o.within_5deg for o in orientation]),
            "coverage": mean_or_none([o.coverage for o in orientation]),
        },
        "timing_ms": {k: round(float(np.median(v)), 1) for k, v in sorted(timings.items())},
        "sequences": len(walks),
    }
    if any(w is not None for w in walk_ids):
        summary["per_walk"] = per_walk_summary(walk_ids, position_errors, heading_errors)
    intrinsics = {name: photo.intrinsics for name, photo in photos.items()}
    return LabelledWorld(store, gt_store, labelled, summary, {}, intrinsics)


TRUTH_POSITION_SIGMA_M = 0.1
"""Position sigma (m) a reference re-labelled at its true pose reports (:func:`references_at_truth`)."""


def relabelled_at_truth(
    world: World,
    city: CityMap,
    labelled: Mapping[str, LabelledReference],
    intrinsics: Mapping[str, Intrinsics],
    position_covariance: np.ndarray | None = None,
) -> dict[str, LabelledReference]:
    """Each reference of ``world`` re-labelled at its manifest pose, by name in the world's order.

    labelled, intrinsics: each reference's label and camera by name. Each keeps its own photo's analysis
    (segmentation, features, vanishing points); only its planar pose (position, heading) is the truth, from which
    its identities are marginalised and its anchors cast, as the sequence stage does at a placed pose
    (:func:`geoloc.localize.reference.label_at_pose`). position_covariance: the known pose's (m^2; None: each
    label's own).
    """
    out = {}
    for image in world.references:
        ref, pose = labelled[image.name], image.pose
        covariance = ref.label.position_covariance if position_covariance is None else position_covariance
        known = KnownPose(pose.x_m, pose.y_m, pose.yaw_deg, covariance)
        out[image.name] = label_at_pose(
            city, intrinsics[image.name], ref.cues, ref.timings_ms, known, analysis=ref.analysis
        )
    return out


def references_at_truth(
    world: World, city: CityMap, labelled: LabelledWorld, vocabulary: Vocabulary
) -> InMemoryReferenceStore:
    """A store of the world's references, each re-labelled at its manifest pose (the ``gt_poses`` run).

    :func:`relabelled_at_truth` with a known pose of :data:`TRUTH_POSITION_SIGMA_M`. Its answers are the ceiling of
    what right anchors give the rest of the method.
    """
    store = InMemoryReferenceStore(vocabulary)
    truth_covariance = TRUTH_POSITION_SIGMA_M**2 * np.eye(2)
    at_truth = relabelled_at_truth(world, city, labelled.labelled, labelled.intrinsics, truth_covariance)
    for name, ref in at_truth.items():
        store.add(stored_reference(name, ref))
    return store
