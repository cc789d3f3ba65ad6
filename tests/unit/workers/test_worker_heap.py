"""A worker settles its heap around jobs: the job's garbage cycles freed, the survivors out of the collector's walks.

Python's collections during a job then walk only that job's objects, not the worker's long-lived ones (the
imported modules, maps, networks).
"""

from __future__ import annotations

import gc
import weakref
from pathlib import Path

from contracts.jobs import JobPayload, JobResult
from contracts.settings import Settings
from db import Database, connect, migrate
from db import jobs as job_store
from workers.handlers import Registration
from workers.memory import settle_heap
from workers.worker import Worker


class _Node:
    """A weak-referenceable object to put in a reference cycle."""

    def __init__(self) -> None:
        self.other: object = None


def test_settling_collects_cycles_and_freezes_what_survives() -> None:
    """The job's cyclic garbage is freed; what outlives the job leaves the collector's generations."""
    garbage, kept = _Node(), _Node()
    garbage.other, kept.other = garbage, kept  # two cycles: one dropped, one kept
    gone = weakref.ref(garbage)
    del garbage
    frozen_before = gc.get_freeze_count()
    try:
        settle_heap()
        assert gone() is None  # collected before the freeze, not frozen with the rest
        assert gc.get_freeze_count() > frozen_before
        assert not any(obj is kept for obj in gc.get_objects())  # out of every collection's walk
        assert len(gc.get_objects()) < 1_000  # a collection walks only what was made since
    finally:
        gc.unfreeze()  # the rest of the test session collects as usual


class _Empty(JobPayload):
    """A payload with no fields."""


class _Seen(JobResult):
    """What the handler saw at the start of its job."""

    tracked_objects: int


def test_jobs_leave_no_cycles_and_collections_do_not_walk_the_workers_heap(tmp_path: Path) -> None:
    cycles: list[weakref.ref[_Node]] = []

    def handler(_db: Database, _payload: _Empty) -> _Seen:
        seen = _Seen(tracked_objects=len(gc.get_objects()))  # what a collection would walk now
        node = _Node()
        node.other = node  # garbage only the collector can free
        cycles.append(weakref.ref(node))
        return seen

    settings = Settings(data_dir=tmp_path / "data")
    settings.data_dir.mkdir()
    db = connect(settings.database)
    migrate(db)
    ids = [job_store.enqueue_job(db, "heap-test", _Empty()) for _ in range(3)]
    gc.disable()  # only the worker's own settling collects during the jobs
    try:
        Worker(settings, {"heap-test": Registration(_Empty, handler)}).run(max_jobs=3)
    finally:
        gc.enable()
        gc.unfreeze()  # the rest of the test session collects as usual
    results = [job_store.get_job(db, job_id) for job_id in ids]
    db.close()
    assert [row["status"] if row else None for row in results] == ["done"] * 3
    assert all(ref() is None for ref in cycles)  # each job's cycle freed after it, with the collector disabled
    tracked = [int(row["result"]["tracked_objects"]) for row in results if row and row["result"]]
    assert len(tracked) == 3 and max(tracked) < 5_000  # not the 100 k+ objects this process holds
