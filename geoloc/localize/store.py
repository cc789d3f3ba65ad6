"""What the query stage reads of labelled references: :class:`StoredReference` and the :class:`ReferenceStore`.

A store gives an SBoW shortlist and the references themselves: the workers' reads the service's database
(:class:`workers.reference_store.DatabaseReferenceStore`), the evaluation's keeps them in memory.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from contracts.references import ReferenceKeypoints
from geoloc.localize.anchors import MapAnchors
from geoloc.vision.features import Features


@dataclass
class StoredReference:
    """What the query stage needs of a labelled reference.

    features: its local features; keypoint_prob: (N, M) identity probabilities over ``building_ids``;
    anchors: its keypoints' 3D points on the map (:mod:`geoloc.localize.anchors`); position_covariance: (2, 2) m^2
    uncertainty of its estimated position (the anchors inherit it); position_xy: (2,) its estimated
    position (local metres; NaN when unknown); alternative_anchors: anchors from the runner-up pose of an
    ambiguous label (else None).
    """

    reference_id: Hashable
    features: Features
    keypoint_prob: np.ndarray
    building_ids: np.ndarray
    anchors: MapAnchors
    position_covariance: np.ndarray
    position_xy: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    alternative_anchors: MapAnchors | None = None

    def keypoints(self) -> ReferenceKeypoints:
        """What is stored of it (:class:`contracts.references.ReferenceKeypoints`; the format casts the dtypes)."""
        features, anchors, alternative = self.features, self.anchors, self.alternative_anchors
        return ReferenceKeypoints(
            xy=features.xy,
            descriptors=features.descriptors,
            sizes=features.sizes,
            angles=features.angles,
            responses=features.responses,
            image_shape=features.image_shape,
            scale=features.scale,
            method=features.method,
            identity=self.keypoint_prob,
            building_ids=self.building_ids,
            anchor_xyz=anchors.xyz,
            anchor_facade_id=anchors.facade_id,
            anchor_building_id=anchors.building_id,
            anchor_distance_m=anchors.distance_m,
            position_covariance=self.position_covariance,
            position_xy=self.position_xy,
            alt_anchor_xyz=None if alternative is None else alternative.xyz,
            alt_anchor_facade_id=None if alternative is None else alternative.facade_id,
            alt_anchor_building_id=None if alternative is None else alternative.building_id,
            alt_anchor_distance_m=None if alternative is None else alternative.distance_m,
        )

    def read_back(self) -> StoredReference:
        """Itself as the workers read it back from the service's store: through the stored format's dtypes.

        The store keeps descriptors as float16 and anchors as float32
        (:class:`contracts.references.ReferenceKeypoints`), so a query matches what comes back, not what was
        computed: a descriptor rounded to float16 can swap a nearest neighbour or a ratio test, and so an answer.
        What is read back is exactly this (the format's arrays are written and read losslessly, :mod:`db.blobs`).
        """
        return StoredReference.from_keypoints(
            self.reference_id, ReferenceKeypoints.from_arrays(self.keypoints().to_arrays())
        )

    @classmethod
    def from_keypoints(cls, reference_id: Hashable, keypoints: ReferenceKeypoints) -> StoredReference:
        """A reference read back from its stored keypoints (:class:`contracts.references.ReferenceKeypoints`)."""
        k = keypoints
        features = Features(k.xy, k.descriptors, k.sizes, k.angles, k.responses, k.image_shape, k.scale, k.method)
        alternative = None
        if k.alt_anchor_xyz is not None:
            assert k.alt_anchor_facade_id is not None and k.alt_anchor_building_id is not None
            assert k.alt_anchor_distance_m is not None
            alternative = MapAnchors(
                k.alt_anchor_xyz, k.alt_anchor_facade_id, k.alt_anchor_building_id, k.alt_anchor_distance_m
            )
        return cls(
            reference_id,
            features,
            k.identity,
            k.building_ids,
            MapAnchors(k.anchor_xyz, k.anchor_facade_id, k.anchor_building_id, k.anchor_distance_m),
            k.position_covariance,
            k.position_xy,
            alternative,
        )


class ReferenceStore(Protocol):
    """Where the query stage finds labelled references: an SBoW shortlist and the references themselves."""

    def shortlist(self, words: np.ndarray, n: int) -> list[tuple[Hashable, float]]:
        """The ``n`` best references for a query's visual words, as (reference id, SBoW score), best first."""
        ...

    def load(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, StoredReference]:
        """The stored references of these ids (missing ones are left out)."""
        ...

    def positions(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, np.ndarray]:
        """The estimated (2,) positions of these references (NaN when unknown; missing ones left out).

        Read without loading their features: retrieval with a position prior ranks more references than it
        keeps.
        """
        ...
