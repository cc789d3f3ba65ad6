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
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from contracts.logs import REQUEST_ID
from contracts.settings import Settings
from db import Database, connect, migrate
from db import jobs as job_store
from db.files import open_store
from db.outages import (
    DatabaseUnavailableError,
    Reconnecting,
    is_connection_lost,
    is_database_unavailable,
    outage_reason,
    retry_pause_s,
    until_available,
)
from db.rows import JobRow
from workers.handlers import HANDLERS, PermanentJobError, Registration, is_permanent
from workers.memory import HeapTrimmer, settle_heap
from workers.metrics import observe_job
from workers.retention import purge_expired_queries, purge_interval_s

log = logging.getLogger("geoloc.worker")
T = TypeVar("T")

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
        self._last_beat = self._next_purge = 0.0

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
        """The main loop; returns the number of jobs run.

        While the database is away (PostgreSQL down or restarting, SQLite's file read-only or locked) the loop
        claims nothing: it waits (0.2 s doubling to 5 s) and opens a new connection until one answers.
        """
        db = connect(self.database)
        migrate(db)
        job_store.register_worker(db, self.worker_id, os.getpid(), socket.gethostname(), self.settings.worker_kinds)
        link = Reconnecting(self.database, db)
        settle_heap()  # the imported modules and handlers: out of the collector's walks from the first job on
        log.info("worker %s started (handlers: %s)", self.worker_id, ", ".join(sorted(self.handlers)) or "none")
        jobs_run = failures = 0
        sleep_s = MIN_POLL_S
        self._last_beat = self._next_purge = 0.0
        try:
            while not self.stop_event.is_set():
                if self._parent_gone():
                    log.warning("parent process gone; stopping")
                    break
                try:
                    job = link.attempt(self._poll)
                except Exception as exc:
                    failures = self._pause(exc, failures + 1)
                    continue
                if failures:
                    log.info("the database is back after %d failed tries: claiming again", failures)
                    failures = 0
                if job is None:
                    self.heap.idle(time.monotonic())
                    self.stop_event.wait(sleep_s)
                    sleep_s = min(sleep_s * 2, self.settings.worker_poll_max_s)
                    continue
                sleep_s = MIN_POLL_S
                finished = self.run_job(link.get(), job)
                jobs_run += 1
                if not finished:  # released on shutdown with the handler still running
                    with suppress(Exception):
                        job_store.stop_worker(link.get(), self.worker_id)
                    log.info("worker %s exiting with an abandoned handler thread", self.worker_id)
                    os._exit(0)
                if max_jobs is not None and jobs_run >= max_jobs:
                    break
        finally:
            try:
                link.attempt(lambda conn: job_store.stop_worker(conn, self.worker_id))
            except Exception as exc:  # the database is away: the heartbeat going stale says the same
                log.warning("could not mark worker %s stopped: %s", self.worker_id, outage_reason(exc))
            link.close()
            db.close()
            log.info("worker %s stopped after %d jobs", self.worker_id, jobs_run)
        return jobs_run

    def _pause(self, exc: Exception, failures: int) -> int:
        """After a failed turn: re-raised unless the database is away, else a wait (longer each time)."""
        if not is_database_unavailable(exc):
            raise exc
        if failures == 1:
            log.warning("the database is unavailable (%s): not claiming until it is back", outage_reason(exc))
        self.stop_event.wait(retry_pause_s(failures))
        return failures

    def _poll(self, db: Database) -> JobRow | None:
        """One turn of the idle loop: the worker's heartbeat and the retention when due, then a claim."""
        now = time.monotonic()
        if now - self._last_beat >= self.heartbeat_interval_s:
            job_store.heartbeat_worker(db, self.worker_id, None)
            self._last_beat = now
        if self.settings.query_retention_s > 0 and now >= self._next_purge:
            self.apply_retention(db)
            self._next_purge = now + purge_interval_s(self.settings.query_retention_s)
        kinds = list(self.settings.worker_kinds) or None
        return job_store.claim_job(db, self.worker_id, self.settings.job_lease_s, kinds)

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
        recorded in ``geoloc_job_duration_seconds`` (:mod:`workers.metrics`). The database may go away meanwhile:
        the lease is then not renewed (a lease that runs out lets another worker take the job; this one's result
        is dropped), and the outcome is recorded once it is back. An attempt that failed because the connection
        was lost is given back uncounted (:func:`is_connection_lost`).
        """
        token = REQUEST_ID.set(job.get("request_id"))
        try:
            return self._run_job(db, job)
        finally:
            REQUEST_ID.reset(token)

    def _run_job(self, db: Database, job: JobRow) -> bool:
        job_id, kind = int(job["id"]), job["kind"]
        fields: dict[str, Any] = {"job_id": job_id, "kind": kind, "attempt": job["attempts"]}
        log.info("job %d (%s) attempt %d/%d", job_id, kind, job["attempts"], job["max_attempts"], extra=fields)
        started = time.monotonic()
        outcome = _Outcome()
        thread = threading.Thread(target=self._execute, args=(job, outcome), name=f"job-{job_id}", daemon=True)
        thread.start()
        link = Reconnecting(self.database, db)
        try:
            return self._follow(link, job, thread, outcome, started, fields)
        finally:
            link.close()

    def _beat(self, link: Reconnecting, job_id: int | None, lease: bool) -> bool | None:
        """Renew the job's lease (``lease``) and the worker's heartbeat; None while the database is away."""
        try:
            held = (
                link.attempt(lambda db: job_store.heartbeat_job(db, job_id, self.worker_id, self.settings.job_lease_s))
                if lease and job_id is not None
                else True
            )
            link.attempt(lambda db: job_store.heartbeat_worker(db, self.worker_id, job_id))
        except Exception as exc:
            if not is_database_unavailable(exc):
                raise
            log.warning("job %s: heartbeat skipped, the database is unavailable (%s)", job_id, outage_reason(exc))
            return None
        return held

    def _record(self, link: Reconnecting, what: str, call: Callable[[Database], T]) -> T:
        """``call`` on the database, waiting for it while it is away (until a stop is requested)."""
        return until_available(lambda: link.attempt(call), self.stop_event, what)

    def _follow(
        self,
        link: Reconnecting,
        job: JobRow,
        thread: threading.Thread,
        outcome: _Outcome,
        started: float,
        fields: dict[str, Any],
    ) -> bool:
        job_id, kind = int(job["id"]), job["kind"]
        self._beat(link, job_id, lease=False)
        stop_deadline: float | None = None
        lease_held = True
        while True:
            thread.join(timeout=self.heartbeat_interval_s)
            if not thread.is_alive():
                break
            if lease_held and self._beat(link, job_id, lease=True) is False:
                lease_held = False
                log.warning("job %d: lease lost (taken over by another worker); its result will be dropped", job_id)
            if self.stop_event.is_set() or self._parent_gone():
                if stop_deadline is None:
                    stop_deadline = time.monotonic() + self.settings.worker_grace_s
                    log.info("job %d: stop requested, waiting up to %.0f s", job_id, self.settings.worker_grace_s)
                elif time.monotonic() >= stop_deadline:
                    with suppress(Exception):  # the database away: the job comes back when its lease runs out
                        released = link.attempt(lambda db: job_store.release_job(db, job_id, self.worker_id))
                        log.info("job %d: released back to the queue (%s)", job_id, released, extra=fields)
                    observe_job(kind, "released", time.monotonic() - started)
                    return False
        elapsed = time.monotonic() - started
        fields["duration_ms"] = round(elapsed * 1e3, 1)
        try:
            self._outcome(link, job, outcome, elapsed, fields)
        except DatabaseUnavailableError:  # stopping while the database is away: the lease brings the job back
            log.warning(
                "job %d: outcome not recorded (stopped while the database was unavailable)", job_id, extra=fields
            )
        del outcome  # its result and error (with the handler's frames) before the heap is settled
        self.heap.job_done(time.monotonic())
        self._beat(link, None, lease=False)
        return True

    def _outcome(
        self, link: Reconnecting, job: JobRow, outcome: _Outcome, elapsed: float, fields: dict[str, Any]
    ) -> None:
        """Record the attempt's outcome: done, given back (the connection was lost), or failed (retried or not)."""
        job_id, worker_id, kind = int(job["id"]), self.worker_id, job["kind"]
        if outcome.error is None:
            result = outcome.result or {}
            if self._record(link, f"job {job_id}", lambda db: job_store.complete_job(db, job_id, worker_id, result)):
                log.info("job %d done in %.2f s", job_id, elapsed, extra={**fields, "outcome": "done"})
                observe_job(kind, "done", elapsed)
            else:
                log.warning("job %d finished but its lease was lost; result dropped", job_id, extra=fields)
            return
        if is_connection_lost(outcome.error):
            released = self._record(link, f"job {job_id}", lambda db: job_store.release_job(db, job_id, worker_id))
            log.warning(
                "job %d: the database connection was lost mid-job (%s); given back uncounted (%s)",
                job_id,
                outage_reason(outcome.error),
                released,
                extra={**fields, "outcome": "released"},
            )
            observe_job(kind, "released", elapsed)
            return
        self._record_failure(link, job, outcome.error, fields, elapsed)

    def _record_failure(
        self, link: Reconnecting, job: JobRow, exc: BaseException, fields: dict[str, Any], elapsed: float
    ) -> None:
        """A failed attempt recorded on the job (retried or failed, waiting for the database), logged and counted."""
        job_id, worker_id = int(job["id"]), self.worker_id
        permanent = is_permanent(exc)
        error = error_summary(exc)
        gone = self._record(link, f"job {job_id}", lambda db: job_store.deleted_subject(db, job))
        if gone:  # whatever the attempt hit, this is why it cannot succeed
            permanent, error = True, f"{gone} while the job ran (not retried)\n{error}"
        delay = min(self.settings.job_retry_delay_s * 2 ** max(int(job["attempts"]) - 1, 0), MAX_RETRY_DELAY_S)
        status = self._record(
            link,
            f"job {job_id}",
            lambda db: job_store.fail_job(db, job_id, worker_id, error, retry_delay_s=delay, permanent=permanent),
        )
        outcome = "retry" if status == "queued" else "failed"
        log.warning("job %d attempt failed (%s) -> %s", job_id, exc, status, extra={**fields, "outcome": outcome})
        if status is not None:
            observe_job(job["kind"], outcome, elapsed)


def install_signal_handlers(worker: Worker) -> None:
    """SIGTERM and SIGINT stop the worker gracefully."""
    signal.signal(signal.SIGTERM, worker.stop)
    signal.signal(signal.SIGINT, worker.stop)
