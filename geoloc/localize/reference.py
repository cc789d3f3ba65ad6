"""Reference labelling on photos: a geo-tagged photo -> its pose on the map, identities and map anchors.

:func:`label_reference_photo` is the labelling stage's entry (the workers' label job and ``geoloc eval world``):
heading and corrected position (:func:`geoloc.localize.labeling.label_reference`; the position's covariance as
:mod:`geoloc.localize.label_covariance` states it), per-column building
identities (greedy and marginalised), its keypoints' identity probabilities and their 3D anchors on the map's
facades (:mod:`geoloc.localize.anchors`). Positions are local metres of the map's frame; converting to WGS84
and compass headings is the caller's (``city_map.frame``).
"""

from __future__ import annotations

import time
from collections.abc import Hashable
from dataclasses import dataclass, field, replace

import numpy as np

from contracts.references import ReferenceKeypoints, ReferenceLabelArrays
from geoloc.core.camera import Intrinsics
from geoloc.core.context import MethodContext
from geoloc.core.geo import LocalFrame
from geoloc.localize.anchors import CameraPose, MapAnchors, anchor_keypoints
from geoloc.localize.identity import IdentityMap
from geoloc.localize.label_covariance import stated_position_covariance
from geoloc.localize.labeling import (
    KnownPose,
    LabelOptions,
    ReferenceLabel,
    label_known_pose,
    label_reference,
    resolve_heading_prior,
    stated_heading_prior,
)
from geoloc.localize.store import StoredReference
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior, compass_heading_prior
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import PhotoEvidence, analyze_photo
from geoloc.vision.features import Features
from geoloc.vision.ground import DEFAULT_CAMERA_HEIGHT_M
from geoloc.vision.image_model import ImageModel


@dataclass(frozen=True)
class LabelCues:
    """What labelling a photo at a pose needs of its analysis (:func:`label_at_pose`), and what is stored of it.

    features: its local features; image_model: its geometry-only facade evidence; building_mask: (H, W) bool
    building pixels; rotation_upright_from_cam: (3, 3) from its vertical vanishing point (pitch and roll).
    A walk's placement reads these back from the store (:mod:`geoloc.localize.sequence.frames`) instead of
    analysing the photo again.
    """

    features: Features
    image_model: ImageModel
    building_mask: np.ndarray
    rotation_upright_from_cam: np.ndarray

    @classmethod
    def of(cls, evidence: PhotoEvidence) -> LabelCues:
        """The cues of a photo's full analysis."""
        rotation = evidence.analysis.vanishing_points.rotation_upright_from_cam
        return cls(evidence.features, evidence.image_model, evidence.building_mask, rotation)


@dataclass
class LabelledReference:
    """A reference photo labelled with the map: its pose, identities and keypoint identities.

    cues: what its labelling used of the photo's analysis (:class:`LabelCues`); analysis: the full analysis when
    this process ran it (None when the cues were read back from the store; :attr:`evidence` needs it);
    identity: the identity map used downstream (marginalised by default);
    keypoint_identity: (N, M) identity probabilities of ``cues.features`` over ``identity.building_ids``;
    anchors: the keypoints' 3D points on the map's facades seen from the label's pose (:mod:`geoloc.localize.anchors`);
    alternative_anchors: the same from the runner-up pose when the label is ambiguous
    (:attr:`geoloc.localize.labeling.ReferenceLabel.is_ambiguous`), else None: a query that sees the scene from
    elsewhere can tell which of the two is right.
    """

    label: ReferenceLabel
    cues: LabelCues
    identity: IdentityMap
    keypoint_identity: np.ndarray
    anchors: MapAnchors
    timings_ms: dict[str, float] = field(default_factory=dict)
    alternative_anchors: MapAnchors | None = None
    analysis: PhotoEvidence | None = None

    @property
    def evidence(self) -> PhotoEvidence:
        """The photo's full analysis; ValueError for a reference whose cues were read back from the store."""
        if self.analysis is None:
            raise ValueError("this labelled reference was built from stored cues: its full analysis is not here")
        return self.analysis

    @property
    def camera_pose(self) -> CameraPose:
        """The labelled pose as a camera pose (pitch and roll from the photo's vertical vanishing point)."""
        return _camera_pose(self.label, self.cues.rotation_upright_from_cam)

    def keypoints(self) -> ReferenceKeypoints:
        """What is stored of its keypoints (:class:`contracts.references.ReferenceKeypoints`; the store casts)."""
        return stored_reference(None, self).keypoints()

    def label_arrays(self) -> ReferenceLabelArrays:
        """What is stored of its identity map (:class:`contracts.references.ReferenceLabelArrays`)."""
        identity = self.identity
        return ReferenceLabelArrays.from_mask(
            identity.building_ids, identity.column_prob, identity.building_mask, self.label.likelihood
        )


def _camera_pose(label: ReferenceLabel, rotation: np.ndarray, alternative: bool = False) -> CameraPose:
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
    evidence = evidence or analyze_photo(photo, context=context)
    return label_from_cues(
        city_map,
        photo.intrinsics,
        LabelCues.of(evidence),
        evidence.timings_ms,
        gps_xy,
        heading_prior=resolve_heading_prior(prior_yaw_deg, heading_prior),
        options=options,
        strategy=strategy,
        analysis=evidence,
    )


def label_from_cues(
    city_map: CityMap,
    intrinsics: Intrinsics,
    cues: LabelCues,
    timings_ms: dict[str, float],
    gps_xy: tuple[float, float],
    *,
    heading_prior: HeadingPrior | None = None,
    options: LabelOptions | None = None,
    strategy: str = "marginalized",
    analysis: PhotoEvidence | None = None,
    timing_key: str = "labeling",
) -> LabelledReference:
    """A photo labelled from its camera and :class:`LabelCues` around its GPS tag (local m).

    :func:`label_reference_photo`'s labelling, also used on the cues a walk's placement reads back instead of the
    photo (a label done again with another prior). timings_ms: the analysis's or the earlier label's (copied,
    ``timing_key`` added: the labelling's ms); analysis: kept on the result; heading_prior: a stated heading too
    (:func:`geoloc.localize.labeling.resolve_heading_prior`); the rest as :func:`label_reference_photo`.
    """
    t0 = time.perf_counter()
    label = label_reference(
        city_map,
        cues.image_model,
        cues.building_mask,
        intrinsics,
        gps_xy,
        heading_prior=heading_prior,
        options=options or LabelOptions(),
    )
    stated = stated_position_covariance(label.position_covariance, (label.x_m, label.y_m), gps_xy)
    label = replace(label, position_covariance=stated)
    timings = dict(timings_ms, **{timing_key: 1e3 * (time.perf_counter() - t0)})
    return _labelled(city_map, intrinsics, cues, label, strategy, timings, analysis)


def label_at_pose(
    city_map: CityMap,
    intrinsics: Intrinsics,
    cues: LabelCues,
    timings_ms: dict[str, float],
    pose: KnownPose,
    *,
    analysis: PhotoEvidence | None = None,
    strategy: str = "marginalized",
) -> LabelledReference:
    """A photo (its camera and :class:`LabelCues`) labelled at a pose placed elsewhere (a sequence's placement).

    Its identities come from the map around ``pose`` (:func:`geoloc.localize.labeling.label_known_pose`), its
    anchors are cast from it. timings_ms: its label's own (copied, ``placed_labeling`` added); analysis: the
    photo's full analysis when there is one (kept on the result).
    """
    t0 = time.perf_counter()
    label = label_known_pose(city_map, cues.image_model, cues.building_mask, intrinsics, pose)
    timings = dict(timings_ms, placed_labeling=1e3 * (time.perf_counter() - t0))
    return _labelled(city_map, intrinsics, cues, label, strategy, timings, analysis)


def _labelled(
    city_map: CityMap,
    intrinsics: Intrinsics,
    cues: LabelCues,
    label: ReferenceLabel,
    strategy: str,
    timings: dict[str, float],
    analysis: PhotoEvidence | None,
) -> LabelledReference:
    """The labelled reference of a label: its keypoints' identities and anchors (and the runner-up's anchors)."""
    identity = label.marginalized if strategy == "marginalized" else label.greedy
    xy = cues.features.xy
    keypoint_identity = identity.probabilities_at(xy)
    t0 = time.perf_counter()
    rotation = cues.rotation_upright_from_cam
    anchors = anchor_keypoints(city_map, _camera_pose(label, rotation), intrinsics, xy)
    alternative = None
    if label.is_ambiguous:
        alternative = anchor_keypoints(city_map, _camera_pose(label, rotation, alternative=True), intrinsics, xy)
    timings["anchors"] = 1e3 * (time.perf_counter() - t0)
    return LabelledReference(label, cues, identity, keypoint_identity, anchors, timings, alternative, analysis)


def stored_reference(reference_id: Hashable, labelled: LabelledReference) -> StoredReference:
    """What the query stage keeps of a labelled reference (:class:`geoloc.localize.store.StoredReference`)."""
    return StoredReference(
        reference_id,
        labelled.cues.features,
        labelled.keypoint_identity,
        labelled.identity.building_ids,
        labelled.anchors,
        labelled.label.position_covariance,
        np.array([labelled.label.x_m, labelled.label.y_m]),
        labelled.alternative_anchors,
    )


def heading_prior_at(
    frame: LocalFrame, heading_deg: float | None, accuracy_deg: float | None, east_m: float = 0.0, north_m: float = 0.0
) -> HeadingPrior | None:
    """The heading prior of a heading (deg from true north) at a local point (m) of ``frame``: the one way it is built.

    The workers' (a stored reference's or query's heading) and the evaluation's (a photo's compass, its accuracy
    :func:`geoloc.photos.heading_prior.compass_accuracy_deg`, as the service stores it).

    No accuracy: a heading the uploader stated (or one stored before accuracies were), today's plain Gaussian
    (:func:`geoloc.localize.labeling.stated_heading_prior`). With one: the photo's compass, the robust prior
    (:func:`geoloc.photos.heading_prior.compass_heading_prior`: sigma floored, uniform outlier floor).
    """
    if heading_deg is None:
        return None
    if accuracy_deg is None:
        return stated_heading_prior(float(frame.heading_to_bearing(heading_deg, east_m, north_m)))
    return compass_heading_prior(heading_deg, accuracy_deg, frame, east_m, north_m)
