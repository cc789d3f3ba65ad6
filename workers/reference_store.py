"""The query stage's reference store backed by the service's database (:class:`geoloc.query.ReferenceStore`).

The SBoW shortlist reads the postings of the query's words from the map's inverted index and ranks with
:func:`geoloc.retrieval.tfidf_scores`, the formula the evaluation's in-memory index uses, so both rank
alike; references come back with their stored features, keypoint identities and map anchors.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

from db import Database, sbow
from db import references as reference_store
from geoloc.anchors import MapAnchors
from geoloc.features import Features
from geoloc.query import StoredReference
from geoloc.retrieval import tfidf_scores

UNKNOWN_POSITION_SIGMA_M = 10.0
"""Position uncertainty credited to a reference stored before labelling recorded one."""


class DatabaseReferenceStore:
    """Labelled references of one map, read from the database."""

    def __init__(self, db: Database, map_id: int) -> None:
        self.db = db
        self.map_id = map_id

    def shortlist(self, words: np.ndarray, n: int) -> list[tuple[Hashable, float]]:
        """The ``n`` best labelled references of the map for a query's visual words: [(id, score)]."""
        postings = sbow.postings_for_words(self.db, self.map_id, words)
        if postings.n_docs == 0 or len(postings.reference_ids) == 0:
            return []
        scores = tfidf_scores(words, postings.word, postings.doc, postings.count, postings.doc_lengths, postings.n_docs)
        order = np.argsort(-scores, kind="stable")[:n]
        return [(int(postings.reference_ids[i]), float(scores[i])) for i in order if scores[i] > 0]

    def load(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, StoredReference]:
        """The stored references of these ids (ones deleted meanwhile are left out)."""
        out: dict[Hashable, StoredReference] = {}
        for reference_id in reference_ids:
            arrays = reference_store.load_keypoints(self.db, int(reference_id))  # type: ignore[call-overload]
            if arrays is not None:
                out[reference_id] = stored_reference_from_arrays(reference_id, arrays)
        return out


def stored_reference_from_arrays(reference_id: Hashable, arrays: dict[str, np.ndarray]) -> StoredReference:
    """A :class:`StoredReference` from a reference's stored keypoint arrays."""
    features = Features.from_arrays(arrays)
    if "anchor_xyz" in arrays:
        anchors = MapAnchors.from_arrays(arrays)
    else:  # labelled before map anchors existed: no 3D points
        n = len(features)
        anchors = MapAnchors(np.full((n, 3), np.nan), np.full(n, -1), np.full(n, -1), np.full(n, np.nan))
    covariance = arrays.get("position_covariance")
    if covariance is None:
        covariance = np.eye(2) * UNKNOWN_POSITION_SIGMA_M**2
    position = arrays.get("position_xy")
    return StoredReference(
        reference_id,
        features,
        arrays["identity"],
        arrays["building_ids"],
        anchors,
        np.asarray(covariance, float),
        np.full(2, np.nan) if position is None else np.asarray(position, float),
        MapAnchors.from_arrays(arrays, "alt_anchor") if "alt_anchor_xyz" in arrays else None,
    )
