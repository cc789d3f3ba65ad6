"""The query's answer: ranked poses (:class:`AnswerPose`), the :class:`QueryAnswer`, and what is read at a pose."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from contracts.answers import QuerySearch
from geoloc.core.camera import Intrinsics
from geoloc.localize.absolute_pose import PoseEstimate
from geoloc.localize.grid import Localization
from geoloc.localize.identity import BuildingExtent, IdentityMap
from geoloc.localize.labeling import column_building_ids, identity_from_poses
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.matching import ReferenceMatch


@dataclass
class AnswerPose:
    """One ranked answer (local frame): position, yaw, probability and the radius of its 90 % region.

    source: "anchors" (PnP on map-anchored reference points, refined on the map) or "likelihood".
    """

    rank: int
    x_m: float
    y_m: float
    yaw_deg: float
    probability: float
    uncertainty_radius_m: float
    source: str
    likelihood: float = float("nan")
    inliers: int = 0


@dataclass
class QueryAnswer:
    """A geolocated query: ranked poses, the likelihood's probability map, identities and evidence used.

    localization: the likelihood's grid search (its heatmap is the answer's probability map). identity:
    the query's per-column identities (read from the map at the anchored pose when one is trusted, else
    transferred). transferred: the paper's transferred identities. buildings: the buildings ``identity``
    names, with their column extents (working-size pixels). references: the retrieved references' verified
    matches, best first. anchored: the PnP estimate (trusted or not) and ``search`` says which.
    """

    poses: list[AnswerPose]
    localization: Localization
    identity: IdentityMap
    transferred: IdentityMap
    buildings: list[BuildingExtent]
    references: list[ReferenceMatch]
    anchored: PoseEstimate | None
    search: QuerySearch
    timings_ms: dict[str, float] = field(default_factory=dict)


def identity_at(
    likelihood: MapLikelihood, pose: AnswerPose, building_mask: np.ndarray, intrinsics: Intrinsics
) -> IdentityMap:
    """The query's per-column building identities read from the map at a trusted pose (greedy labelling).

    The photo's image model (``likelihood.image_model``) gives the bins; ``building_mask``: (H, W) bool.
    """
    model = likelihood.image_model
    panorama = likelihood.panoramas(np.array([[pose.x_m, pose.y_m]]))
    ids = column_building_ids(panorama, np.array([pose.yaw_deg]), intrinsics, model.offsets_deg, model.bin_deg)
    return identity_from_poses(ids[0, 0][None, :], np.ones(1), building_mask)
