"""The distributed profile's worker: a Celery worker whose one task claims a job by id and runs its handler.

``geoloc worker`` (and ``geoloc serve`` with workers, when ``GEOLOC_BROKER_URL`` is set) runs
``python -m workers.celery_worker --concurrency N``: a Celery worker with N prefork processes on the
queue :data:`workers.broker.QUEUE`. Each process:

- registers in the ``workers`` table and keeps its heartbeat there (what ``/readyz`` counts, in both
  profiles), from a background thread that also runs the reconciler (:func:`workers.broker.reconcile`)
  every :data:`workers.broker.RECONCILE_INTERVAL_S` and the query retention;
- for each message, claims the job in the database (:func:`db.jobs.claim_job_by_id`) and runs it exactly
  as the embedded pool does (:meth:`workers.worker.Worker.run_job`: the handler in a thread, the lease
  renewed every lease/3 s, the outcome and retries recorded in the table). A message whose job cannot be
  claimed (a duplicate, a job already done or waiting for its retry delay) is acknowledged and dropped.

A process killed mid-job (SIGKILL, OOM) stops renewing its lease: once the lease expires the reconciler
publishes the job again and another process claims it (the attempt counts). On SIGTERM Celery stops
taking messages and lets running jobs finish (a warm shutdown); a job still running when the process is
killed after that comes back through its lease the same way.

A watchdog in the main process (:func:`watch_consumer`) restarts the worker when its consumer stalls:
messages wait in the queue while a pool process is free, for :data:`CONSUMER_STALL_S`. Measured: when an
acknowledgement fails during a Redis outage, Celery 5.7's Redis consumer logs "Couldn't ack" and never
takes another message (kombu kept the message counted against the prefetch limit; the broker's transport,
:mod:`workers.redis_transport`, now frees it); the watchdog stays for a stall of any other cause: the supervisor
starts a fresh worker, and leases bring back any job the restart interrupts.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import sys
import threading
import time
from typing import Any

from contracts.logs import configure_logging
from contracts.settings import Settings, SettingsError, get_settings
from db import Database, connect, migrate
from db import jobs as job_store
from db.outages import is_database_unavailable, outage_reason
from workers.broker import RECONCILE_INTERVAL_S, RUN_JOB_TASK, CeleryPublisher, celery_app, reconcile
from workers.context import model_problems, needs_models
from workers.handlers import load_builtin_handlers, load_plugins
from workers.metrics import enable_metrics
from workers.retention import purge_interval_s
from workers.worker import Worker

log = logging.getLogger("geoloc.worker")

CONSUMER_STALL_S = 30.0
"""Messages waiting this long while a pool process is free: the consumer is stuck, restart the worker."""
WATCHDOG_INTERVAL_S = 5.0
STALL_EXIT_CODE = 75


class ProcessState:
    """What one worker process holds: its :class:`Worker` (id, settings, handlers) and the background thread."""

    def __init__(self, settings: Settings) -> None:
        assert settings.broker_url is not None
        self.settings = settings
        self.worker = Worker(settings)
        self.publisher = CeleryPublisher(settings.broker_url)
        self.current_job_id: int | None = None
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self._background, name="geoloc-background", daemon=True)

    def start(self) -> None:
        """Register the process and start its heartbeat/reconciler/retention thread."""
        db = connect(self.settings.database)
        try:
            job_store.register_worker(
                db, self.worker.worker_id, os.getpid(), socket.gethostname(), self.settings.worker_kinds
            )
        finally:
            db.close()
        self.thread.start()
        log.info("worker %s ready", self.worker.worker_id)

    def stop(self) -> None:
        """Stop the background thread and mark the process stopped."""
        self.stop_event.set()
        db = connect(self.settings.database)
        try:
            job_store.stop_worker(db, self.worker.worker_id)
        finally:
            db.close()

    def _background(self) -> None:
        next_beat = next_reconcile = next_purge = 0.0
        db: Database | None = None
        while not self.stop_event.is_set():
            now = time.monotonic()
            try:
                if db is None:
                    db = connect(self.settings.database)
                if now >= next_beat:
                    job_store.heartbeat_worker(db, self.worker.worker_id, self.current_job_id)
                    next_beat = now + self.worker.heartbeat_interval_s
                if now >= next_reconcile:
                    reconcile(db, self.publisher)
                    next_reconcile = now + RECONCILE_INTERVAL_S
                if self.settings.query_retention_s > 0 and now >= next_purge:
                    self.worker.apply_retention(db)
                    next_purge = now + purge_interval_s(self.settings.query_retention_s)
                if self.current_job_id is None:  # idle between tasks: the heap's free pages go back in time
                    self.worker.heap.idle(now)
            except Exception:  # the database or the broker is away: try again shortly, on a new connection
                log.exception("worker background task failed; retrying")
                if db is not None:
                    db.close()
                    db = None
                self.stop_event.wait(1.0)
            self.stop_event.wait(min(RECONCILE_INTERVAL_S, self.worker.heartbeat_interval_s) / 2)

    def run_job(self, job_id: int) -> str:
        """Claim job ``job_id`` and run it to its outcome; returns what happened (for the log).

        With the database away the message is dropped: the reconciler publishes the job again once the
        database is back and the broker's queue is empty (the job is still claimable then).
        """
        try:
            db = connect(self.settings.database)
        except Exception as exc:
            if not is_database_unavailable(exc):
                raise
            return f"the database is unavailable ({outage_reason(exc)}): left to the reconciler"
        try:
            kinds = self.settings.worker_kinds
            if kinds and (row := job_store.get_job(db, job_id)) is not None and row["kind"] not in kinds:
                return "not a kind this worker claims (GEOLOC_WORKER_KINDS): left queued"
            job = job_store.claim_job_by_id(db, job_id, self.worker.worker_id, self.settings.job_lease_s)
            if job is None:
                return "not claimable (duplicate, finished, or waiting for its retry)"
            self.current_job_id = job_id
            try:
                self.worker.run_job(db, job)
            finally:
                self.current_job_id = None
            return "ran"
        except Exception as exc:
            if not is_database_unavailable(exc):
                raise
            return f"the database is unavailable ({outage_reason(exc)}): left to the reconciler"
        finally:
            db.close()


_process: dict[str, ProcessState] = {}
"""This worker process's :class:`ProcessState` (under ``"state"``), set when Celery starts the process."""


def watch_consumer(publisher: CeleryPublisher, concurrency: int, stop: threading.Event) -> None:
    """Exit the worker (its supervisor starts another) when its consumer stalls; runs in the main process.

    Stalled: the broker's queue has messages and fewer than ``concurrency`` tasks run here, continuously for
    :data:`CONSUMER_STALL_S` (any healthy worker would have taken one). Also stops the worker (SIGTERM to
    itself, a warm shutdown) when the supervisor that started it is gone.
    """
    from celery.worker import state

    parent = os.environ.get("GEOLOC_SUPERVISOR_PID")
    stalled_s = 0.0
    while not stop.wait(WATCHDOG_INTERVAL_S):
        if parent and os.getppid() != int(parent):  # the supervisor died: stop as its built-in workers do
            log.warning("supervisor gone; stopping (warm shutdown)")
            os.kill(os.getpid(), signal.SIGTERM)
            return
        try:
            waiting = publisher.queue_length()
        except Exception:  # the broker is away: the consumer's own reconnection handles that
            stalled_s = 0.0
            continue
        stalled_s = stalled_s + WATCHDOG_INTERVAL_S if waiting and len(state.active_requests) < concurrency else 0.0
        if stalled_s >= CONSUMER_STALL_S:
            log.error(
                "consumer stalled: %d message(s) waiting for %.0f s with a free process; restarting", waiting, stalled_s
            )
            if os.getpgid(0) == os.getpid():  # our own process group (the supervisor's child): the pool goes too
                os.killpg(os.getpid(), signal.SIGKILL)
            os._exit(STALL_EXIT_CODE)


def create_app(settings: Settings, concurrency: int = 1) -> Any:
    """The Celery app with the ``run_job`` task, the per-process start and stop hooks and the consumer watchdog."""
    from celery.signals import (
        setup_logging,
        worker_process_init,
        worker_process_shutdown,
        worker_ready,
        worker_shutting_down,
    )

    assert settings.broker_url is not None
    app = celery_app(settings.broker_url)

    @app.task(name=RUN_JOB_TASK, ignore_result=True)  # type: ignore[untyped-decorator]
    def run_job(job_id: int) -> None:
        outcome = _process["state"].run_job(int(job_id))
        log.debug("message for job %s: %s", job_id, outcome)

    @setup_logging.connect(weak=False)  # type: ignore[untyped-decorator]
    def _keep_our_logging(**_: Any) -> None:  # connected: Celery leaves the logging that main() configured
        pass

    @worker_process_init.connect(weak=False)  # type: ignore[untyped-decorator]
    def _process_started(**_: Any) -> None:
        state = _process["state"] = ProcessState(settings)
        state.start()

    @worker_process_shutdown.connect(weak=False)  # type: ignore[untyped-decorator]
    def _process_stopped(**_: Any) -> None:
        if "state" in _process:
            _process["state"].stop()

    watchdog_stop = threading.Event()

    @worker_ready.connect(weak=False)  # type: ignore[untyped-decorator]
    def _start_watchdog(**_: Any) -> None:
        publisher = CeleryPublisher(settings.broker_url or "")
        args = (publisher, concurrency, watchdog_stop)
        threading.Thread(target=watch_consumer, args=args, name="geoloc-watchdog", daemon=True).start()

    @worker_shutting_down.connect(weak=False)  # type: ignore[untyped-decorator]
    def _stop_watchdog(**_: Any) -> None:
        watchdog_stop.set()

    return app


def main(argv: list[str] | None = None) -> int:
    """Check settings and models, prepare the database, run the Celery worker until it is stopped."""
    parser = argparse.ArgumentParser(prog="python -m workers.celery_worker", description="Run a geoloc Celery worker.")
    parser.add_argument("--concurrency", "-c", type=int, default=1, help="worker processes (prefork)")
    parser.add_argument("--log-level", default=None, help="default: GEOLOC_LOG_LEVEL")
    args = parser.parse_args(argv)
    try:
        settings = get_settings()
    except SettingsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if settings.broker_url is None:
        print("error: GEOLOC_BROKER_URL is not set (the embedded profile runs `python -m workers`)", file=sys.stderr)
        return 2
    level = (args.log_level or settings.log_level).upper()
    configure_logging(level, settings.log_format, "worker")
    enable_metrics(settings)  # before the fork of its pool: each process writes its own files (workers/metrics.py)
    problems = model_problems() if needs_models(settings) else []
    if problems:
        print("error: the worker cannot run jobs:\n  " + "\n  ".join(problems), file=sys.stderr)
        return 2
    db = connect(settings.database)
    try:
        migrate(db)
    finally:
        db.close()
    if settings.worker_nice:
        os.nice(settings.worker_nice)
    load_builtin_handlers()
    load_plugins(settings.worker_plugins)
    app = create_app(settings, max(args.concurrency, 1))
    app.worker_main(
        [
            "worker",
            "--pool=prefork",
            f"--concurrency={max(args.concurrency, 1)}",
            f"--loglevel={level}",
            f"--hostname=geoloc-{os.getpid()}@{socket.gethostname()}",
            "--without-gossip",
            "--without-mingle",
            "--without-heartbeat",
        ]
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
