"""The evaluation's references: a world's reference photos labelled as the service labels them, and their store."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.core.context import MethodContext
from geoloc.evaluation.facades import orientation_errors
from geoloc.evaluation.ground_truth import gt_keypoint_identity
from geoloc.evaluation.store import InMemoryReferenceStore
from geoloc.evaluation.summaries import (
    angle_error_deg,
    mean_or_none,
    per_walk_summary,
    reference_heading_summary,
    reference_position_summary,
)
from geoloc.localize.identity import identity_accuracy
from geoloc.localize.reference import LabelledReference, label_reference_photo, stored_reference
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.sequence import SequenceMember, group_sequences, place_labelled_sequence
from geoloc.localize.sequence.stage import LabelledFrame
from geoloc.maps import CityMap
from geoloc.photos.capture import photo_device
from geoloc.photos.heading_prior import HeadingPrior, heading_prior_from_compass
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


def analyze(path: Path, labels: np.ndarray | None, context: MethodContext) -> tuple[Photo, PhotoEvidence]:
    """The photo at ``path`` and its evidence (segmentation from ``labels`` when given, e.g. ground truth)."""
    photo = load_photo(path)
    return photo, analyze_photo(photo, labels, context=context)


def compass_prior(photo: Photo, city: CityMap, gps_xy: tuple[float, ...]) -> HeadingPrior | None:
    """The photo's compass as the service's robust prior (None without one), at its GPS tag (local m)."""
    compass = photo.capture.compass
    return None if compass is None else heading_prior_from_compass(compass, city.frame, gps_xy[0], gps_xy[1])


def _place_sequences(
    world: World,
    city: CityMap,
    photos: dict[str, Photo],
    labelled: dict[str, LabelledReference],
    say: Callable[[str], None],
) -> int:
    """Place the world's sequences jointly as the workers do; returns how many sequences there were.

    Groups (:func:`geoloc.localize.sequence.group_sequences`) and places (:mod:`geoloc.localize.sequence`) the
    references, replacing their frames' labels in ``labelled``.
    """
    members = []
    for order, image in enumerate(world.references):
        photo = photos[image.name]
        gps_xy = tuple(float(v) for v in city.frame.to_local(*photo.gps)) if photo.gps else (0.0, 0.0)
        device = photo_device(photo.exif.make, photo.exif.model)
        members.append(
            SequenceMember(
                image.name, photo.capture.sequence_id, photo.capture.time, device, (gps_xy[0], gps_xy[1]), order
            )
        )
    groups = group_sequences(members)
    for names in groups:
        frames = []
        for name in names:
            photo = photos[str(name)]
            assert photo.gps is not None  # checked when labelled
            gps_xy = tuple(float(v) for v in city.frame.to_local(*photo.gps))
            prior = compass_prior(photo, city, gps_xy)
            frames.append(LabelledFrame(photo, labelled[str(name)], (gps_xy[0], gps_xy[1]), heading_prior=prior))
        placed = place_labelled_sequence(city, frames)
        for name, ref in zip(names, placed.references, strict=True):
            labelled[str(name)] = ref
        say(f"sequence of {len(names)} references placed ({placed.n_edges} relative poses)")
    return len(groups)


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
    labelled: dict[str, LabelledReference] = {}
    accuracy: dict[str, list[float]] = {"greedy": [], "marginalized": []}
    heading_errors, position_errors, radius_held, orientation = [], [], [], []
    walk_ids: list[int | None] = []  # each reference's walk (walk worlds; None in a scattered one)
    timings: dict[str, list[float]] = defaultdict(list)
    photos: dict[str, Photo] = {}
    for i, image in enumerate(world.references):
        gt = world.gt(image.name)
        photo, evidence = analyze(image.path, gt["labels"] if segmentation == "gt" else None, context)
        if photo.gps is None:
            raise ValueError(f"reference {image.name} has no EXIF GPS")
        gps_xy = tuple(float(v) for v in city.frame.to_local(*photo.gps))
        prior = compass_prior(photo, city, gps_xy)
        labelled[image.name] = label_reference_photo(
            city, photo, (gps_xy[0], gps_xy[1]), heading_prior=prior, evidence=evidence, context=context
        )
        photos[image.name] = photo
        say(f"[{segmentation}] reference {i + 1}/{len(world.references)} {image.name} labelled")
    n_sequences = _place_sequences(world, city, photos, labelled, say)
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
        "sequences": n_sequences,
    }
    if any(w is not None for w in walk_ids):
        summary["per_walk"] = per_walk_summary(walk_ids, position_errors, heading_errors)
    return LabelledWorld(store, gt_store, labelled, summary, {})
