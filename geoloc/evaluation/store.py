"""The evaluation's reference store: labelled references and their SBoW index held in memory.

It holds what the service's store holds, so that the evaluation answers as the workers do: each reference as
read back from the stored format (:meth:`geoloc.localize.store.StoredReference.read_back`: float16 descriptors,
float32 anchors), indexed by the words of its descriptors as computed (the label job indexes them before it
stores the reference). It ranks with :class:`geoloc.localize.sbow_index.SbowIndex`, the workers' index (the one
SBoW index): the same scores as :func:`geoloc.localize.retrieval.tfidf_scores` on the postings. Reference ids of
any hashable kind (the evaluation's are image names) are given index ids 0, 1, 2, ... in the order they are first
added, so the index's ties (lower id first) fall in insertion order.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.sbow_index import SbowIndex
from geoloc.localize.store import StoredReference


class InMemoryReferenceStore:
    """Labelled references and their SBoW index held in memory (a :class:`geoloc.localize.store.ReferenceStore`)."""

    def __init__(self, vocabulary: Vocabulary) -> None:
        self.vocabulary = vocabulary
        self.index = SbowIndex(vocabulary.n_words)
        self.references: dict[Hashable, StoredReference] = {}
        self._index_id: dict[Hashable, int] = {}
        self._reference_id: list[Hashable] = []

    def add(self, reference: StoredReference) -> None:
        """Index a labelled reference and keep it as the service's store reads it back (replacing one of its id)."""
        ref_id = reference.reference_id
        if ref_id not in self._index_id:
            self._index_id[ref_id] = len(self._reference_id)
            self._reference_id.append(ref_id)
        self.index.add_words(self._index_id[ref_id], self.vocabulary.words(reference.features.descriptors))
        self.references[ref_id] = reference.read_back()

    def shortlist(self, words: np.ndarray, n: int) -> list[tuple[Hashable, float]]:
        """The ``n`` best references by SBoW score, best first (ties: the one added first)."""
        return [(self._reference_id[doc], score) for doc, score in self.index.top(words, n)]

    def load(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, StoredReference]:
        """The references of these ids."""
        return {ref_id: self.references[ref_id] for ref_id in reference_ids if ref_id in self.references}

    def positions(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, np.ndarray]:
        """The estimated positions of these references."""
        return {ref_id: self.references[ref_id].position_xy for ref_id in reference_ids if ref_id in self.references}
