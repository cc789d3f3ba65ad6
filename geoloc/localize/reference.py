"""Reference labelling on photos: a geo-tagged photo -> its pose on the map, identities and map anchors.

:func:`label_reference_photo` is the labelling stage's entry (the workers' label job and ``geoloc eval world``):
heading and corrected position (:func:`geoloc.localize.labeling.label_reference`), per-column building
identities (greedy and marginalised), its keypoints' identity probabilities and their 3D anchors on the map's
facades (:mod:`geoloc.localize.anchors`). Positions are local metres of the map's frame; converting to WGS84
and compass headings is the caller's (``city_map.frame``).
"""

from __future__ import annotations

import time
from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np

from contracts.references import ReferenceKeypoints, ReferenceLabelArrays
from geoloc.core.context import MethodContext
from geoloc.localize.anchors import CameraPose, MapAnchors, anchor_keypoints
from geoloc.localize.identity import IdentityMap
from geoloc.localize.labeling import KnownPose, LabelOptions, ReferenceLabel, label_known_pose, label_reference
from geoloc.localize.store import StoredReference
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import PhotoEvidence, analyze_photo
from geoloc.vision.ground import DEFAULT_CAMERA_HEIGHT_M


@dataclass
class LabelledReference:
    """A reference photo labelled with the map: its pose, identities and keypoint identities.

    identity: the identity map used downstream (marginalised by default);
    keypoint_identity: (N, M) identity probabilities of ``evidence.features`` over ``identity.building_ids``;
    anchors: the keypoints' 3D points on the map's facades seen from the label's pose (:mod:`geoloc.localize.anchors`);
    alternative_anchors: the same from the runner-up pose when the label is ambiguous
    (:attr:`geoloc.localize.labeling.ReferenceLabel.is_ambiguous`), else None: a query that sees the scene from
    elsewhere can tell which of the two is right.
    """

    label: ReferenceLabel
    evidence: PhotoEvidence
    identity: IdentityMap
    keypoint_identity: np.ndarray
    anchors: MapAnchors
    timings_ms: dict[str, float] = field(default_factory=dict)
    alternative_anchors: MapAnchors | None = None

    @property
    def camera_pose(self) -> CameraPose:
        """The labelled pose as a camera pose (pitch and roll from the photo's vertical vanishing point)."""
        return _camera_pose(self.label, self.evidence)

    def keypoints(self) -> ReferenceKeypoints:
        """What is stored of its keypoints (:class:`contracts.references.ReferenceKeypoints`; the store casts)."""
        return stored_reference(None, self).keypoints()

    def label_arrays(self) -> ReferenceLabelArrays:
        """What is stored of its identity map (:class:`contracts.references.ReferenceLabelArrays`)."""
        identity = self.identity
        return ReferenceLabelArrays.from_mask(
            identity.building_ids, identity.column_prob, identity.building_mask, self.label.likelihood
        )


def _camera_pose(label: ReferenceLabel, evidence: PhotoEvidence, alternative: bool = False) -> CameraPose:
    rotation = evidence.analysis.vanishing_points.rotation_upright_from_cam
    if alternative and label.alternative is not None:
        alt = label.alternative
        return CameraPose(alt.x_m, alt.y_m, alt.yaw_deg, DEFAULT_CAMERA_HEIGHT_M, rotation)
    return CameraPose(label.x_m, label.y_m, label.yaw_deg, DEFAULT_CAMERA_HEIGHT_M, rotation)


def label_reference_photo(
    city_map: CityMap,
    photo: Photo,
    gps_xy: tuple[float, float],
    *,
    prior_yaw_deg: float | None = None,
    heading_prior: HeadingPrior | None = None,
    evidence: PhotoEvidence | None = None,
    strategy: str = "marginalized",
    options: LabelOptions | None = None,
    context: MethodContext,
) -> LabelledReference:
    """Label a geo-tagged reference photo (GPS tag in local metres) with the map.

    prior_yaw_deg: optional stated heading (local bearing, deg; today's Gaussian), or heading_prior: a
    :class:`HeadingPrior` (the compass's robust prior), not both. evidence: the photo's analysis when already
    done. strategy: "marginalized" (default, the paper's better one) or "greedy" chooses which identity
    map the keypoints carry. options: the labelling's tuning (default :class:`LabelOptions`). context: the
    models and threads the photo's analysis runs with (:func:`geoloc.vision.evidence.analyze_photo`).
    """
    if strategy not in ("marginalized", "greedy"):
        raise ValueError(f"strategy must be 'marginalized' or 'greedy', got {strategy!r}")
    options = options or LabelOptions()
    evidence = evidence or analyze_photo(photo, context=context)
    t0 = time.perf_counter()
    label = label_reference(
        city_map,
        evidence.image_model,
        evidence.building_mask,
        photo.intrinsics,
        gps_xy,
        prior_yaw_deg=prior_yaw_deg,
        heading_prior=heading_prior,
        options=options,
    )
    timings = dict(evidence.timings_ms, labeling=1e3 * (time.perf_counter() - t0))
    return _labelled(city_map, photo, evidence, label, strategy, timings)


def label_at_pose(
    city_map: CityMap, photo: Photo, labelled: LabelledReference, pose: KnownPose, strategy: str = "marginalized"
) -> LabelledReference:
    """``labelled`` re-labelled at a pose placed elsewhere (a sequence's joint placement).

    Its identities come from the map around ``pose`` (:func:`geoloc.localize.labeling.label_known_pose`), its
    anchors are cast from it.
    """
    evidence = labelled.evidence
    t0 = time.perf_counter()
    label = label_known_pose(city_map, evidence.image_model, evidence.building_mask, photo.intrinsics, pose)
    timings = dict(labelled.timings_ms, placed_labeling=1e3 * (time.perf_counter() - t0))
    return _labelled(city_map, photo, evidence, label, strategy, timings)


def _labelled(
    city_map: CityMap,
    photo: Photo,
    evidence: PhotoEvidence,
    label: ReferenceLabel,
    strategy: str,
    timings: dict[str, float],
) -> LabelledReference:
    """The labelled reference of a label: its keypoints' identities and anchors (and the runner-up's anchors)."""
    identity = label.marginalized if strategy == "marginalized" else label.greedy
    keypoint_identity = identity.probabilities_at(evidence.features.xy)
    t0 = time.perf_counter()
    anchors = anchor_keypoints(city_map, _camera_pose(label, evidence), photo.intrinsics, evidence.features.xy)
    alternative = None
    if label.is_ambiguous:
        pose = _camera_pose(label, evidence, alternative=True)
        alternative = anchor_keypoints(city_map, pose, photo.intrinsics, evidence.features.xy)
    timings["anchors"] = 1e3 * (time.perf_counter() - t0)
    return LabelledReference(label, evidence, identity, keypoint_identity, anchors, timings, alternative)


def stored_reference(reference_id: Hashable, labelled: LabelledReference) -> StoredReference:
    """What the query stage keeps of a labelled reference (:class:`geoloc.localize.store.StoredReference`)."""
    return StoredReference(
        reference_id,
        labelled.evidence.features,
        labelled.keypoint_identity,
        labelled.identity.building_ids,
        labelled.anchors,
        labelled.label.position_covariance,
        np.array([labelled.label.x_m, labelled.label.y_m]),
        labelled.alternative_anchors,
    )
