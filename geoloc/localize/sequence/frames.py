"""What a walk's placement needs of a frame labelled alone (:class:`FrameLabel`), and that as stored arrays.

The workers' label job stores a walk reference's :class:`FrameLabel` beside its labels
(:func:`frame_arrays`), and the sequence job reads it back (:func:`frame_from_arrays`) instead of analysing
and labelling the photo again. Every array is stored in its own dtype (descriptors float32, anchors
float64/int64: not the query format's float16/float32; the building mask bit-packed along rows), so what is
read back is bit-identical to what the label job computed and the placement's answer is the same as when the
photo is labelled again. Frames: pose in local metres and bearings (deg) of the map; pixels of the
working-size photo.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.anchors import MapAnchors
from geoloc.localize.labeling import LabelOptions, says_little
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.reference import LabelCues, LabelledReference
from geoloc.localize.refinement import position_spread
from geoloc.maps import CityMap
from geoloc.vision.evidence import PhotoEvidence
from geoloc.vision.features import Features
from geoloc.vision.image_model import ImageModel

MAP_SPREAD_HALF_SIZE_M = 10.0
MAP_SPREAD_CELL_M = 2.0
"""The grid (half-size, spacing, m) over which :func:`map_position_covariance` weighs the map's likelihood.

The label's own grid: on Helsinki seed 1's walks, +-15 m at 1 m placed the references the same (within 2 m
0.57 against 0.58) for ten times the CPU (33 against 3.5 ms a frame)."""
MAP_SPREAD_YAW_OFFSETS_DEG = (-1.0, 0.0, 1.0)
"""Headings around the label's at which the spread is weighed (deg)."""

_OPTIONAL_MODEL_ARRAYS = ("identity_building_ids", "identity_prob", "distance_m", "top_tan_elevation")
"""The image model's optional arrays, stored only when set."""


@dataclass(frozen=True)
class FrameLabel:
    """A frame's label alone as the placement sees it.

    x_m, y_m, yaw_deg, position_covariance: the label's pose and (2, 2) m^2 covariance; anchors: its keypoints
    on the map seen from that pose; intrinsics, cues: its camera and what labelling at a pose needs of its
    analysis; timings_ms: its label's timings; analysis: the full analysis when this process ran it (the
    evaluation's), else None.
    """

    x_m: float
    y_m: float
    yaw_deg: float
    position_covariance: np.ndarray
    anchors: MapAnchors
    intrinsics: Intrinsics
    cues: LabelCues
    timings_ms: dict[str, float] = field(default_factory=dict)
    analysis: PhotoEvidence | None = None

    @classmethod
    def of(cls, labelled: LabelledReference, intrinsics: Intrinsics) -> FrameLabel:
        """The frame label of a reference labelled alone (and its photo's intrinsics)."""
        label = labelled.label
        return cls(
            label.x_m,
            label.y_m,
            label.yaw_deg,
            label.position_covariance,
            labelled.anchors,
            intrinsics,
            labelled.cues,
            dict(labelled.timings_ms),
            labelled.analysis,
        )


def map_position_covariance(
    city_map: CityMap,
    image_model: ImageModel,
    x_m: float,
    y_m: float,
    yaw_deg: float,
    options: LabelOptions = LabelOptions(),
) -> np.ndarray:
    """(2, 2) m^2 spread of the map's likelihood alone around a label's pose, at its heading: what the map says.

    image_model: the photo's (its identities are not used); x_m, y_m, yaw_deg: the label's pose (local m, bearing).

    The label's own covariance weighs its GPS prior and is cut off by its refinement's +-6 m grid, so a label on
    a uniform facade, which the map cannot place along the street, looks sure of itself and, in a walk's graph,
    counts the GPS a second time. Here the weights are the geometry-only likelihood ** ``options.sharpness``
    over :data:`MAP_SPREAD_HALF_SIZE_M` / :data:`MAP_SPREAD_CELL_M` positions around the pose (not inside a
    building) at :data:`MAP_SPREAD_YAW_OFFSETS_DEG` from its heading, with no GPS prior; the spread is about
    their weighted mean, plus the cell's own variance. Where nothing has weight: the grid's half-size squared.
    """
    if says_little(image_model):  # the label sits at its GPS: the map adds nothing to the walk's graph
        return np.eye(2) * MAP_SPREAD_HALF_SIZE_M**2
    offsets = np.arange(-MAP_SPREAD_HALF_SIZE_M, MAP_SPREAD_HALF_SIZE_M + MAP_SPREAD_CELL_M / 2, MAP_SPREAD_CELL_M)
    east, north = np.meshgrid(offsets, offsets, indexing="ij")
    positions = np.stack([east.ravel(), north.ravel()], axis=1) + np.array([x_m, y_m])
    positions = positions[~city_map.inside_buildings(positions)]
    likelihood = MapLikelihood(city_map, image_model.without_identity(), options.likelihood)
    yaws = yaw_deg + np.asarray(MAP_SPREAD_YAW_OFFSETS_DEG)
    weights = np.power(likelihood.of_poses(positions, yaws).astype(float), options.sharpness).sum(axis=1)
    spread = position_spread(positions, weights, MAP_SPREAD_CELL_M)
    return spread if spread is not None else np.eye(2) * MAP_SPREAD_HALF_SIZE_M**2


def frame_arrays(frame: FrameLabel) -> dict[str, np.ndarray]:
    """The frame label as named arrays, every one in its own dtype (module docstring; the analysis is not stored)."""
    features, model, intr = frame.cues.features, frame.cues.image_model, frame.intrinsics
    arrays = {
        "pose": np.array([frame.x_m, frame.y_m, frame.yaw_deg], np.float64),
        "position_covariance": np.asarray(frame.position_covariance),
        "anchor_xyz": frame.anchors.xyz,
        "anchor_facade_id": frame.anchors.facade_id,
        "anchor_building_id": frame.anchors.building_id,
        "anchor_distance_m": frame.anchors.distance_m,
        "intrinsics": np.array([intr.width, intr.height, intr.focal_px, intr.cx, intr.cy], np.float64),
        "intrinsics_source": np.array(intr.source),
        "building_mask_bits": np.packbits(frame.cues.building_mask, axis=1),
        "building_mask_width": np.array(frame.cues.building_mask.shape[1], np.int64),
        "rotation_upright_from_cam": np.asarray(frame.cues.rotation_upright_from_cam),
        "features_xy": features.xy,
        "features_descriptors": features.descriptors,
        "features_sizes": features.sizes,
        "features_angles": features.angles,
        "features_responses": features.responses,
        "features_image_shape": np.array(features.image_shape, np.int64),
        "features_scale": np.array(features.scale, np.float64),
        "features_method": np.array(features.method),
        "model_offsets_deg": model.offsets_deg,
        "model_facade_present": model.facade_present,
        "model_orientation_deg": model.orientation_deg,
        "model_bin_deg": np.array(model.bin_deg, np.float64),
        "timing_names": np.array(list(frame.timings_ms), dtype=str),
        "timing_values_ms": np.array(list(frame.timings_ms.values()), np.float64),
    }
    for name in _OPTIONAL_MODEL_ARRAYS:
        value = getattr(model, name)
        if value is not None:
            arrays[f"model_{name}"] = value
    return arrays


def frame_from_arrays(arrays: Mapping[str, np.ndarray]) -> FrameLabel:
    """The frame label stored by :func:`frame_arrays` (bit-identical arrays; no full analysis)."""
    x_m, y_m, yaw_deg = (float(v) for v in arrays["pose"])
    width, height, focal_px, cx, cy = (float(v) for v in arrays["intrinsics"])
    intrinsics = Intrinsics(int(width), int(height), focal_px, cx, cy, str(arrays["intrinsics_source"]))
    features = Features(
        arrays["features_xy"],
        arrays["features_descriptors"],
        arrays["features_sizes"],
        arrays["features_angles"],
        arrays["features_responses"],
        (int(arrays["features_image_shape"][0]), int(arrays["features_image_shape"][1])),
        float(arrays["features_scale"]),
        str(arrays["features_method"]),
    )
    model = ImageModel(
        arrays["model_offsets_deg"],
        arrays["model_facade_present"],
        arrays["model_orientation_deg"],
        identity_building_ids=arrays.get("model_identity_building_ids"),
        identity_prob=arrays.get("model_identity_prob"),
        distance_m=arrays.get("model_distance_m"),
        top_tan_elevation=arrays.get("model_top_tan_elevation"),
        bin_deg=float(arrays["model_bin_deg"]),
    )
    anchors = MapAnchors(
        arrays["anchor_xyz"], arrays["anchor_facade_id"], arrays["anchor_building_id"], arrays["anchor_distance_m"]
    )
    width = int(arrays["building_mask_width"])
    mask = np.unpackbits(arrays["building_mask_bits"], axis=1, count=width).astype(bool)
    cues = LabelCues(features, model, mask, arrays["rotation_upright_from_cam"])
    timings = {str(k): float(v) for k, v in zip(arrays["timing_names"], arrays["timing_values_ms"], strict=True)}
    return FrameLabel(x_m, y_m, yaw_deg, arrays["position_covariance"], anchors, intrinsics, cues, timings)
