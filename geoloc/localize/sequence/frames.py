"""What a walk's placement needs of a frame labelled alone (:class:`FrameLabel`), and that as stored arrays.

The workers' label job stores a walk reference's :class:`FrameLabel` beside its labels
(:meth:`FrameLabel.stored`: a :class:`contracts.references.WalkFrameArrays`), and the sequence job reads it back
(:meth:`FrameLabel.from_stored`) instead of analysing and labelling the photo again. Every array is stored in
its own dtype (descriptors float32, anchors float64/int64: not the query format's float16/float32; the building
mask bit-packed along rows), so what is read back is bit-identical to what the label job computed and the
placement's answer is the same as when the photo is labelled again. Frames: pose in local metres and bearings
(deg) of the map; pixels of the working-size photo.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from contracts.references import WalkFrameArrays
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

    def stored(self, original_size: tuple[int, int]) -> WalkFrameArrays:
        """The frame label as stored, every array in its own dtype (module docstring; the analysis is not stored).

        original_size: the uploaded photo's (width, height) in pixels, stored beside it.
        """
        features, model, intr = self.cues.features, self.cues.image_model, self.intrinsics
        return WalkFrameArrays(
            pose=np.array([self.x_m, self.y_m, self.yaw_deg], np.float64),
            position_covariance=np.asarray(self.position_covariance),
            anchor_xyz=self.anchors.xyz,
            anchor_facade_id=self.anchors.facade_id,
            anchor_building_id=self.anchors.building_id,
            anchor_distance_m=self.anchors.distance_m,
            intrinsics=np.array([intr.width, intr.height, intr.focal_px, intr.cx, intr.cy], np.float64),
            intrinsics_source=intr.source,
            building_mask_bits=np.packbits(self.cues.building_mask, axis=1),
            building_mask_width=int(self.cues.building_mask.shape[1]),
            rotation_upright_from_cam=np.asarray(self.cues.rotation_upright_from_cam),
            features_xy=features.xy,
            features_descriptors=features.descriptors,
            features_sizes=features.sizes,
            features_angles=features.angles,
            features_responses=features.responses,
            features_image_shape=(int(features.image_shape[0]), int(features.image_shape[1])),
            features_scale=float(features.scale),
            features_method=features.method,
            model_offsets_deg=model.offsets_deg,
            model_facade_present=model.facade_present,
            model_orientation_deg=model.orientation_deg,
            model_bin_deg=float(model.bin_deg),
            timings_ms=dict(self.timings_ms),
            original_size=original_size,
            model_identity_building_ids=model.identity_building_ids,
            model_identity_prob=model.identity_prob,
            model_distance_m=model.distance_m,
            model_top_tan_elevation=model.top_tan_elevation,
        )

    @classmethod
    def from_stored(cls, stored: WalkFrameArrays) -> FrameLabel:
        """The frame label :meth:`stored` wrote (bit-identical arrays; no full analysis)."""
        x_m, y_m, yaw_deg = (float(v) for v in stored.pose)
        width, height, focal_px, cx, cy = (float(v) for v in stored.intrinsics)
        intrinsics = Intrinsics(int(width), int(height), focal_px, cx, cy, stored.intrinsics_source)
        features = Features(
            stored.features_xy,
            stored.features_descriptors,
            stored.features_sizes,
            stored.features_angles,
            stored.features_responses,
            (stored.features_image_shape[0], stored.features_image_shape[1]),
            stored.features_scale,
            stored.features_method,
        )
        model = ImageModel(
            stored.model_offsets_deg,
            stored.model_facade_present,
            stored.model_orientation_deg,
            identity_building_ids=stored.model_identity_building_ids,
            identity_prob=stored.model_identity_prob,
            distance_m=stored.model_distance_m,
            top_tan_elevation=stored.model_top_tan_elevation,
            bin_deg=stored.model_bin_deg,
        )
        anchors = MapAnchors(
            stored.anchor_xyz, stored.anchor_facade_id, stored.anchor_building_id, stored.anchor_distance_m
        )
        mask = np.unpackbits(stored.building_mask_bits, axis=1, count=stored.building_mask_width).astype(bool)
        cues = LabelCues(features, model, mask, stored.rotation_upright_from_cam)
        return cls(x_m, y_m, yaw_deg, stored.position_covariance, anchors, intrinsics, cues, dict(stored.timings_ms))


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
