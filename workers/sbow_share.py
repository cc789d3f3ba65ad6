"""A map's SBoW base segment in one file per machine, memory-mapped by every worker process (issue 23).

Without it each worker process holds its own copy of a map's SBoW index (350 MB of postings at 100,000
references, and more while the database snapshot is decoded). With it the first process that needs the
index of a map reads the database's snapshot (:func:`db.sbow.index_snapshot`), builds the word-major base
segment (:class:`geoloc.localize.sbow_segments.Segment`) and writes it, with the snapshot's change-log mark and
the changes it already holds, to ``DATA_DIR/cache/sbow`` (:mod:`geoloc.core.array_file`), under an exclusive
file lock so that processes starting together build it once; every process, that one included, then maps the
file read-only: the postings' pages are the page cache's, shared by all the processes of the machine (both
profiles: the embedded pool's processes and a machine's Celery prefork children alike). Each process keeps its
own small parts: the documents added since the file's mark (read from the change log as before, the *recent*
documents), which base documents it has seen removed (``live``), and the id -> row table.

Deleting the map removes its file (:func:`workers.sbow_files.remove_shared_base`, from the API's delete).
The file is rewritten (under the lock) when a process finds the map's change log more than
:data:`REBUILD_AFTER_CHANGES` changes past its mark, so that a process starting late does not replay a long log;
processes that mapped the old file keep it (a replaced file's pages live while mapped). A file is named after
the database, the map's id and its creation time, so a map that reuses an id in a new database never reads
another's. Ranking is the in-memory index's: the same base segment, built by the same code from the same
snapshot, gives the same scores to the last bit (a test answers the same queries both ways).
"""

from __future__ import annotations

import fcntl
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from db import Database, sbow
from geoloc.core.array_file import map_arrays, write_arrays
from geoloc.localize.sbow_index import SbowIndex
from geoloc.localize.sbow_segments import Segment
from geoloc.vision.model_files import DEFAULT_WORDS

REBUILD_AFTER_CHANGES = 2048
"""Change-log rows of a map past the shared file's mark beyond which a process rewrites the file."""


@dataclass
class SharedBase:
    """A map's index on a mapped base segment: the index, the file's change-log mark and the changes it holds."""

    index: SbowIndex
    mark: int
    applied: set[int]


def shared_base(db: Database, map_id: int, path: Path, lookback: int) -> SharedBase:
    """The map's index on the shared file at ``path``, written first when missing or too far behind the log.

    lookback: change-log rows kept behind the mark as already applied
    (:data:`workers.reference_store.LOOKBACK_CHANGES`).
    The caller then catches up with the log past the mark, as after a snapshot.
    """
    found = _fresh(db, map_id, path)
    if found is None:
        with _file_lock(path.with_name(path.name + ".lock")):
            found = _fresh(db, map_id, path)  # another process may have written it while this one waited
            if found is None:
                _write(db, map_id, path, lookback)
                found = _open(path)
    return found


def index_words(db: Database, map_id: int, snapshot: sbow.IndexSnapshot) -> int:
    """The word count of a map's index: its vocabulary's (the default one's if none is stored), or more if used."""
    n_words = sbow.vocabulary_size(db, map_id) or DEFAULT_WORDS
    if len(snapshot.word):
        n_words = max(n_words, int(snapshot.word.max()) + 1)
    return n_words


def _fresh(db: Database, map_id: int, path: Path) -> SharedBase | None:
    """The file's index when it exists, reads, and is within :data:`REBUILD_AFTER_CHANGES` of the log."""
    if not path.is_file():
        return None
    try:
        found = _open(path)
    except (ValueError, KeyError):
        return None  # damaged or foreign: rewritten
    if len(sbow.changes_after(db, map_id, found.mark)) > REBUILD_AFTER_CHANGES:
        return None
    return found


def _open(path: Path) -> SharedBase:
    arrays = map_arrays(path)
    index = SbowIndex(int(arrays["n_words"][0]))
    index.load_segment(Segment.from_arrays(arrays))
    return SharedBase(index, int(arrays["mark"][0]), {int(seq) for seq in arrays["applied"].tolist()})


def _write(db: Database, map_id: int, path: Path, lookback: int) -> None:
    """Build the base segment from a snapshot of the database and write it with its mark."""
    snapshot = sbow.index_snapshot(db, map_id, lookback=lookback)
    n_words = index_words(db, map_id, snapshot)
    postings = (snapshot.word, snapshot.doc, snapshot.weight)
    segment = Segment.from_postings(n_words, snapshot.ids, snapshot.lengths, *postings)
    write_arrays(
        path,
        {
            **segment.arrays(),
            "n_words": np.array([n_words], np.int64),
            "mark": np.array([snapshot.mark], np.int64),
            "applied": np.array([seq for seq, _ in snapshot.recent_changes], np.int64),
        },
    )


@contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    """An exclusive lock between the processes of this machine (``flock`` on ``path``, made if missing)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a+b") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
