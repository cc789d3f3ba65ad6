"""One worker process: claim a job, run its handler while extending the lease, record the outcome.

The handler runs in a thread with its own database connection; the main thread extends the lease
(every lease/3 s), refreshes the worker's liveness row and watches for SIGTERM/SIGINT. On a stop
signal the current job may finish within ``worker_grace_s``; past that it is released back to
the queue (the attempt is not counted) and the process exits. A SIGKILLed worker simply stops
heartbeating: its job is claimed again once the lease expires.

Between jobs (and while idle) the loop also applies the query retention (:mod:`workers.retention`).
A failure that cannot succeed on retry (:func:`workers.handlers.is_permanent`, or any failure once the
job's map or reference has been deleted) fails the job at once. After each job the heap is settled
(:func:`workers.memory.settle_heap`): the job's garbage collected, what outlives it frozen out of Python's
collections; the free pages go back to the system once the worker is idle (``GEOLOC_WORKER_TRIM_IDLE_S``) or
busy for many jobs in a row (:class:`workers.memory.HeapTrimmer`), so the process's resident memory follows what
it holds.
"""

from __future__ import annotations

import logging
import os
import secrets
import signal
import socket
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from contracts.logs import REQUEST_ID
from contracts.settings import Settings
from db import Database, connect, migrate
from db import jobs as job_store
from db.files import open_store
from db.rows import JobRow
from workers.handlers import HANDLERS, PermanentJobError, Registration, is_permanent
from workers.memory import HeapTrimmer, settle_heap
from workers.metrics import observe_job
from workers.retention import purge_expired_queries, purge_interval_s

log = logging.getLogger("geoloc.worker")

MIN_POLL_S = 0.02
MAX_RETRY_DELAY_S = 300.0
TRACEBACK_LINES = 12


def new_worker_id() -> str:
    """``host:pid:random`` — unique per process start."""
    return f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(3)}"


def error_summary(exc: BaseException) -> str:
    """``Type: message`` plus the last lines of the traceback."""
    lines = traceback.format_exception(type(exc), exc, exc.__traceback__)
    tail = "".join(lines).rstrip().splitlines()[-TRACEBACK_LINES:]
    return f"{type(exc).__name__}: {exc}\n" + "\n".join(tail)


@dataclass
class _Outcome:
    result: dict[str, Any] | None = None
    error: BaseException | None = None


class Worker:
    """Runs jobs from the database of ``settings`` (``settings.database``) until :meth:`stop`.

    The embedded profile's pool runs :meth:`run` (claim from the table, in a loop); the distributed
    profile's Celery task calls :meth:`run_job` for each job it claimed by id.
    """

    def __init__(self, settings: Settings, handlers: dict[str, Registration[Any]] | None = None) -> None:
        self.settings = settings
        self.handlers = HANDLERS if handlers is None else handlers
        self.worker_id = new_worker_id()
        self.stop_event = threading.Event()
        self.heap = HeapTrimmer(settings.worker_trim_idle_s)
        self.database: Path | str = settings.database
        self.parent_pid: int | None = None

    def stop(self, *_: object) -> None:
        """Ask the loop to stop (signal-handler compatible)."""
        self.stop_event.set()

    @property
    def heartbeat_interval_s(self) -> float:
        """Seconds between heartbeats: a third of the job lease, within 0.05-5 s."""
        return max(min(self.settings.job_lease_s / 3.0, 5.0), 0.05)

    def _parent_gone(self) -> bool:
        return self.parent_pid is not None and os.getppid() != self.parent_pid

    def run(self, *, max_jobs: int | None = None) -> int:
        """The main loop; returns the number of jobs run."""
        db = connect(self.database)
        migrate(db)
        job_store.register_worker(db, self.worker_id, os.getpid(), socket.gethostname(), self.settings.worker_kinds)
        settle_heap()  # the imported modules and handlers: out of the collector's walks from the first job on
        log.info("worker %s started (handlers: %s)", self.worker_id, ", ".join(sorted(self.handlers)) or "none")
        jobs_run = 0
        sleep_s = MIN_POLL_S
        last_beat = 0.0
        next_purge = 0.0
        try:
            while not self.stop_event.is_set():
                if self._parent_gone():
                    log.warning("parent process gone; stopping")
                    break
                now = time.monotonic()
                if now - last_beat >= self.heartbeat_interval_s:
                    job_store.heartbeat_worker(db, self.worker_id, None)
                    last_beat = now
                if self.settings.query_retention_s > 0 and now >= next_purge:
                    self.apply_retention(db)
                    next_purge = now + purge_interval_s(self.settings.query_retention_s)
                kinds = list(self.settings.worker_kinds) or None
                job = job_store.claim_job(db, self.worker_id, self.settings.job_lease_s, kinds)
                if job is None:
                    self.heap.idle(time.monotonic())
                    self.stop_event.wait(sleep_s)
                    sleep_s = min(sleep_s * 2, self.settings.worker_poll_max_s)
                    continue
                sleep_s = MIN_POLL_S
                finished = self.run_job(db, job)
                jobs_run += 1
                if not finished:  # released on shutdown with the handler still running
                    job_store.stop_worker(db, self.worker_id)
                    log.info("worker %s exiting with an abandoned handler thread", self.worker_id)
                    os._exit(0)
                if max_jobs is not None and jobs_run >= max_jobs:
                    break
        finally:
            job_store.stop_worker(db, self.worker_id)
            db.close()
            log.info("worker %s stopped after %d jobs", self.worker_id, jobs_run)
        return jobs_run

    def apply_retention(self, db: Database) -> None:
        """Delete expired queries; a failure (a busy or full disk) is logged and tried again next time."""
        try:
            purge_expired_queries(db, open_store(self.settings.file_store_dir), self.settings.query_retention_s)
        except Exception:
            log.exception("retention: deleting expired queries failed; will try again")

    def _execute(self, job: JobRow, outcome: _Outcome) -> None:
        REQUEST_ID.set(job.get("request_id"))  # this thread's log lines (and jobs it queues) carry the job's id
        registration = self.handlers.get(job["kind"])
        if registration is None:
            outcome.error = PermanentJobError(
                f"no handler registered for job kind {job['kind']!r} (known: {sorted(self.handlers)})"
            )
            return
        db = connect(self.database)
        try:
            outcome.result = registration.run(db, job["payload"])
        except BaseException as exc:  # every failure is recorded on the job
            outcome.error = exc
        finally:
            db.close()

    def run_job(self, db: Database, job: JobRow) -> bool:
        """Run one claimed job to its outcome; False if it was released with the handler still running.

        Its log lines carry the request id stored on the job (:data:`contracts.logs.REQUEST_ID`), its run is
        recorded in ``geoloc_job_duration_seconds`` (:mod:`workers.metrics`).
        """
        token = REQUEST_ID.set(job.get("request_id"))
        try:
            return self._run_job(db, job)
        finally:
            REQUEST_ID.reset(token)

    def _run_job(self, db: Database, job: JobRow) -> bool:
        job_id, lease_s, kind = int(job["id"]), self.settings.job_lease_s, job["kind"]
        fields: dict[str, Any] = {"job_id": job_id, "kind": kind, "attempt": job["attempts"]}
        log.info("job %d (%s) attempt %d/%d", job_id, kind, job["attempts"], job["max_attempts"], extra=fields)
        started = time.monotonic()
        outcome = _Outcome()
        thread = threading.Thread(target=self._execute, args=(job, outcome), name=f"job-{job_id}", daemon=True)
        thread.start()
        job_store.heartbeat_worker(db, self.worker_id, job_id)
        stop_deadline: float | None = None
        lease_held = True
        while True:
            thread.join(timeout=self.heartbeat_interval_s)
            if not thread.is_alive():
                break
            if lease_held and not job_store.heartbeat_job(db, job_id, self.worker_id, lease_s):
                lease_held = False
                log.warning("job %d: lease lost (taken over by another worker); its result will be dropped", job_id)
            job_store.heartbeat_worker(db, self.worker_id, job_id)
            if self.stop_event.is_set() or self._parent_gone():
                if stop_deadline is None:
                    stop_deadline = time.monotonic() + self.settings.worker_grace_s
                    log.info("job %d: stop requested, waiting up to %.0f s", job_id, self.settings.worker_grace_s)
                elif time.monotonic() >= stop_deadline:
                    released = job_store.release_job(db, job_id, self.worker_id)
                    log.info("job %d: released back to the queue (%s)", job_id, released, extra=fields)
                    observe_job(kind, "released", time.monotonic() - started)
                    return False
        elapsed = time.monotonic() - started
        fields["duration_ms"] = round(elapsed * 1e3, 1)
        if outcome.error is None:
            if job_store.complete_job(db, job_id, self.worker_id, outcome.result or {}):
                log.info("job %d done in %.2f s", job_id, elapsed, extra={**fields, "outcome": "done"})
                observe_job(kind, "done", elapsed)
            else:
                log.warning("job %d finished but its lease was lost; result dropped", job_id, extra=fields)
        else:
            self._record_failure(db, job, outcome.error, fields, elapsed)
        del outcome  # its result and error (with the handler's frames) before the heap is settled
        self.heap.job_done(time.monotonic())
        job_store.heartbeat_worker(db, self.worker_id, None)
        return True

    def _record_failure(
        self, db: Database, job: JobRow, exc: BaseException, fields: dict[str, Any], elapsed: float
    ) -> None:
        """A failed attempt recorded on the job (retried or failed), logged and counted."""
        job_id = int(job["id"])
        permanent = is_permanent(exc)
        error = error_summary(exc)
        if gone := job_store.deleted_subject(db, job):  # whatever the attempt hit, this is why it cannot succeed
            permanent, error = True, f"{gone} while the job ran (not retried)\n{error}"
        delay = min(self.settings.job_retry_delay_s * 2 ** max(int(job["attempts"]) - 1, 0), MAX_RETRY_DELAY_S)
        status = job_store.fail_job(db, job_id, self.worker_id, error, retry_delay_s=delay, permanent=permanent)
        outcome = "retry" if status == "queued" else "failed"
        log.warning("job %d attempt failed (%s) -> %s", job_id, exc, status, extra={**fields, "outcome": outcome})
        if status is not None:
            observe_job(job["kind"], outcome, elapsed)


def install_signal_handlers(worker: Worker) -> None:
    """SIGTERM and SIGINT stop the worker gracefully."""
    signal.signal(signal.SIGTERM, worker.stop)
    signal.signal(signal.SIGINT, worker.stop)
