"""Request ids on jobs (``jobs.request_id``, migration 12) and the job counts the metrics read (``db/stats.py``)."""

from __future__ import annotations

from pathlib import Path

from contracts.jobs import JobPayload
from contracts.logs import REQUEST_ID
from db import connect, migrate
from db import jobs as job_store
from db.stats import job_counts


class _Payload(JobPayload):
    n: int


def test_a_job_stores_the_current_request_id_or_the_one_given(tmp_path: Path) -> None:
    db = connect(tmp_path / "geoloc.sqlite3")
    migrate(db)
    token = REQUEST_ID.set("req-a")
    try:
        inherited = job_store.enqueue_job(db, "k", _Payload(n=1))
        given = job_store.enqueue_job(db, "k", _Payload(n=2), request_id="req-b")
    finally:
        REQUEST_ID.reset(token)
    outside = job_store.enqueue_job(db, "k", _Payload(n=3))
    ids = {job: (job_store.get_job(db, job) or {}).get("request_id") for job in (inherited, given, outside)}
    assert ids == {inherited: "req-a", given: "req-b", outside: None}


def test_job_counts_tell_retrying_from_queued(tmp_path: Path) -> None:
    db = connect(tmp_path / "geoloc.sqlite3")
    migrate(db)
    for n in range(3):
        job_store.enqueue_job(db, "k", _Payload(n=n))
    first = job_store.claim_job(db, "w", 30.0)
    second = job_store.claim_job(db, "w", 30.0)
    assert first is not None and second is not None
    assert job_store.fail_job(db, first["id"], "w", "boom", retry_delay_s=60.0) == "queued"
    assert job_counts(db) == {("k", "retrying"): 1, ("k", "running"): 1, ("k", "queued"): 1}
    assert job_store.fail_job(db, second["id"], "w", "boom", permanent=True) == "failed"
    assert job_counts(db) == {("k", "retrying"): 1, ("k", "failed"): 1, ("k", "queued"): 1}
