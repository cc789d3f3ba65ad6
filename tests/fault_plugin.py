"""Worker plugin for the distributed fault tests: a quick stand-in for the labelling handler.

Loaded with ``GEOLOC_WORKER_PLUGINS=<this file>``, it replaces ``label_reference`` with a handler that
sleeps ``GEOLOC_TEST_LABEL_S`` seconds (so a fault can hit a job mid-run), appends ``reference_id pid`` to
``GEOLOC_TEST_LABEL_LOG`` when it starts, and then, like the real handler, writes its outcome in one
transaction with replace semantics (the reference ``done`` with its timings). The job machinery around it
(claims, leases, the broker, the reconciler) is the real one.
"""

from __future__ import annotations

import os
import time

from contracts.jobs import LABEL_REFERENCE, JobResult, LabelReferencePayload
from db import Database, transaction
from db import references as reference_store
from workers.handlers import PermanentJobError, register


class SlowLabelResult(JobResult):
    """The stand-in's result: which reference it labelled."""

    reference_id: int


@register(LABEL_REFERENCE, LabelReferencePayload)
def label_slowly(db: Database, payload: LabelReferencePayload) -> SlowLabelResult:
    """Log the start, sleep, store the reference as labelled."""
    reference_id = payload.reference_id
    fd = os.open(os.environ["GEOLOC_TEST_LABEL_LOG"], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, f"{reference_id} {os.getpid()}\n".encode())
    finally:
        os.close(fd)
    seconds = float(os.environ.get("GEOLOC_TEST_LABEL_S", "0.5"))
    time.sleep(seconds)
    with transaction(db):
        if not reference_store.update_reference_result(
            db, reference_id, status="done", estimated_heading_deg=0.0, timings={"total": 1e3 * seconds}
        ):
            raise PermanentJobError(f"reference {reference_id} no longer exists")
    return SlowLabelResult(reference_id=reference_id)
