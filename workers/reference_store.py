"""The query stage's reference store backed by the service's database (:class:`geoloc.localize.store.ReferenceStore`).

Shortlist: each worker process keeps every map's SBoW index in memory (:class:`geoloc.localize.sbow_index.SbowIndex`,
which ranks exactly as :func:`geoloc.localize.retrieval.tfidf_scores` on the database's postings, the formula the
evaluation's in-memory index uses too). The database stays the source of truth: the first query on a map
reads its whole index in one snapshot together with the change log's high-water mark
(:func:`db.sbow.index_snapshot`); every later query first reads the log past the mark
(:func:`db.sbow.changes_after`) and reloads the postings of the references changed there (re-indexed
ones replace theirs, deleted ones leave), so a query sees exactly the references committed before it
started. The log is read from :data:`LOOKBACK_CHANGES` rows behind the mark, skipping the changes
already applied: with concurrent writers (PostgreSQL) a sequence number can become visible after a larger
one, and SQLite's single writer never does that, so there it costs one short read.

Load: references come back with their stored features, keypoint identities and map anchors, decoded
once per process and kept (:data:`DECODED_CACHE_SIZE` of them, least recently used out) while the
stored keypoints row is unchanged (its ``created_at``); positions are read without the features and kept
the same way (:data:`POSITION_CACHE_SIZE`), so that filtering the shortlist by the query's prior reads only
the keypoints rows' times.

Shared: given a folder (``shared_dir``, the workers pass ``DATA_DIR/cache/sbow``), the base segment of a map's
index is not built per process but mapped from one file per machine (:mod:`workers.sbow_share`); the documents
changed since that file's mark are read from the log as above, per process.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from db import Database, database_key, sbow
from db import references as reference_store
from geoloc.localize.sbow_index import SbowIndex
from geoloc.localize.store import StoredReference
from workers.sbow_files import shared_base_path
from workers.sbow_share import index_words, shared_base

LOOKBACK_CHANGES = 256
"""Change-log rows re-read behind the high-water mark (see the module docstring)."""
CACHED_MAP_INDEXES = 4
"""In-memory SBoW indexes kept per process (least recently used maps are dropped)."""
DECODED_CACHE_SIZE = 64
"""Decoded references kept per process (~0.8 MB each with 1,500 keypoints)."""
POSITION_CACHE_SIZE = 200_000
"""Reference positions kept per process (~0.2 kB each)."""


@dataclass
class _LiveIndex:
    """A map's in-memory SBoW index and how far it has read the change log."""

    index: SbowIndex
    mark: int
    applied: set[int] = field(default_factory=set)  # change seqs applied within the look-back window


_INDEXES: OrderedDict[tuple[str, int, float], _LiveIndex] = OrderedDict()
_DECODED: OrderedDict[tuple[str, int], tuple[float, StoredReference]] = OrderedDict()
_POSITIONS: OrderedDict[tuple[str, int], tuple[float, np.ndarray]] = OrderedDict()
_LOCK = threading.Lock()


class DatabaseReferenceStore:
    """Labelled references of one map, read from the database.

    shared_dir: where the machine's shared SBoW base segments live (:mod:`workers.sbow_share`); None: this
    process builds its own from the database.
    """

    def __init__(self, db: Database, map_id: int, shared_dir: Path | None = None) -> None:
        self.db = db
        self.map_id = map_id
        self.shared_dir = shared_dir
        self._database = database_key(db)

    def shortlist(self, words: np.ndarray, n: int) -> list[tuple[Hashable, float]]:
        """The ``n`` best labelled references of the map for a query's visual words: [(id, score)]."""
        live = self.live_index()
        if live is None:
            return []
        return [(ref_id, score) for ref_id, score in live.index.top(words, n)]

    def live_index(self) -> _LiveIndex | None:
        """The map's in-memory index, brought up to date with the database (None when the map is gone)."""
        row = self.db.execute("SELECT created_at FROM maps WHERE id = ?", (self.map_id,)).fetchone()
        if row is None:
            return None
        # The map's creation time tells a map apart from a later one that reuses its id in a new database.
        key = (self._database, self.map_id, float(row[0]))
        with _LOCK:
            live = _INDEXES.get(key)
            if live is None:
                live = self._load_index(key[2])
                _INDEXES[key] = live
                while len(_INDEXES) > CACHED_MAP_INDEXES:
                    _INDEXES.popitem(last=False)
            else:
                self._catch_up(live)
            _INDEXES.move_to_end(key)
            return live

    def _load_index(self, created_at: float) -> _LiveIndex:
        if self.shared_dir is not None:
            path = shared_base_path(self.shared_dir, self._database, self.map_id, created_at)
            shared = shared_base(self.db, self.map_id, path, LOOKBACK_CHANGES)
            live = _LiveIndex(shared.index, shared.mark, shared.applied)
            self._catch_up(live)  # the file may be behind the log: the rest as recent documents
            return live
        snapshot = sbow.index_snapshot(self.db, self.map_id, lookback=LOOKBACK_CHANGES)
        index = SbowIndex(index_words(self.db, self.map_id, snapshot))
        index.load(snapshot.ids, snapshot.lengths, snapshot.word, snapshot.doc, snapshot.weight)
        live = _LiveIndex(index, snapshot.mark)
        # Changes already in the snapshot (a later read of the window must not apply them twice).
        live.applied = {seq for seq, _ in snapshot.recent_changes}
        return live

    def _catch_up(self, live: _LiveIndex) -> None:
        changes = sbow.changes_after(self.db, self.map_id, live.mark - LOOKBACK_CHANGES)
        new = [(seq, ref) for seq, ref in changes if seq not in live.applied]
        if not new:
            return
        changed = sorted({ref for _, ref in new})
        postings = sbow.document_postings(self.db, self.map_id, changed)
        for reference_id in changed:
            if reference_id in postings:
                words, weights, total = postings[reference_id]
                if len(words) and int(words.max()) >= live.index.n_words:
                    raise ValueError(f"reference {reference_id} has words beyond the map's vocabulary")
                live.index.upsert(reference_id, words, weights, total)
            else:
                live.index.remove(reference_id, missing_ok=True)
        live.mark = max([live.mark, *(seq for seq, _ in new)])
        live.applied.update(seq for seq, _ in new)
        live.applied = {seq for seq in live.applied if seq > live.mark - LOOKBACK_CHANGES}

    def load(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, StoredReference]:
        """The stored references of these ids (ones deleted meanwhile are left out)."""
        ids = [int(r) for r in reference_ids]  # type: ignore[call-overload]
        stamps = reference_store.keypoint_stamps(self.db, ids)
        out: dict[Hashable, StoredReference] = {}
        for reference_id, original in zip(ids, reference_ids, strict=True):
            if reference_id not in stamps:
                continue
            key = (self._database, reference_id)
            with _LOCK:
                cached = _DECODED.get(key)
                if cached is not None and cached[0] == stamps[reference_id]:
                    _DECODED.move_to_end(key)
                    out[original] = cached[1]
                    continue
            keypoints = reference_store.load_keypoints(self.db, reference_id)
            if keypoints is None:
                continue
            stored = StoredReference.from_keypoints(original, keypoints)
            with _LOCK:
                _DECODED[key] = (stamps[reference_id], stored)
                while len(_DECODED) > DECODED_CACHE_SIZE:
                    _DECODED.popitem(last=False)
            out[original] = stored
        return out

    def positions(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, np.ndarray]:
        """The estimated positions of these references (NaN when labelled before positions were stored)."""
        ids = [int(r) for r in reference_ids]  # type: ignore[call-overload]
        stamps = reference_store.keypoint_stamps(self.db, ids)
        found: dict[int, np.ndarray] = {}
        with _LOCK:
            for reference_id, stamp in stamps.items():
                cached = _POSITIONS.get((self._database, reference_id))
                if cached is not None and cached[0] == stamp:
                    found[reference_id] = cached[1]
        missing = [reference_id for reference_id in stamps if reference_id not in found]
        for reference_id, position in reference_store.keypoint_positions(self.db, missing).items():
            found[reference_id] = position
            with _LOCK:
                _POSITIONS[(self._database, reference_id)] = (stamps[reference_id], found[reference_id])
                while len(_POSITIONS) > POSITION_CACHE_SIZE:
                    _POSITIONS.popitem(last=False)
        return {original: found[i] for i, original in zip(ids, reference_ids, strict=True) if i in found}
