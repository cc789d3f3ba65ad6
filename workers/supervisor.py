"""Start child processes (workers, the API), restart the ones that die, stop them all on a signal.

Used by ``geoloc serve`` (API + N workers) and ``geoloc worker --concurrency N``: the workers are one
forking pool (:func:`pool_spec`, ``GEOLOC_WORKER_START=fork``) or N ``python -m workers`` (``spawn``); in the
distributed profile the workers are one Celery worker with N processes (:func:`celery_worker_spec`). Children run in
their own session (Ctrl-C reaches only the supervisor, which then sends them SIGTERM, waits for
their grace period, and SIGKILLs stragglers); they get ``GEOLOC_SUPERVISOR_PID`` and stop by
themselves if the supervisor disappears.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field

log = logging.getLogger("geoloc.supervisor")

STARTUP_FAILURE_S = 3.0
"""A child that exits with an error this soon after its first start (bad setting, port in use) is a
startup failure: stop everything. Killed by a signal, it is restarted like any later death."""
MAX_RESTART_DELAY_S = 30.0


@dataclass
class ChildSpec:
    """A process to keep running: a name for logs and its command line."""

    name: str
    argv: list[str]
    env: dict[str, str] = field(default_factory=dict)


@dataclass
class _Child:
    spec: ChildSpec
    process: subprocess.Popen[bytes] | None = None
    started_at: float = 0.0
    starts: int = 0
    restart_delay_s: float = 0.5
    restart_at: float | None = None


def worker_spec(index: int, log_level: str = "info") -> ChildSpec:
    """The command line of worker number ``index``."""
    return ChildSpec(f"worker-{index}", [sys.executable, "-m", "workers", "--log-level", log_level])


def pool_spec(count: int, log_level: str = "info") -> ChildSpec:
    """The forking pool's command line (:mod:`workers.pool`) with ``count`` workers (``GEOLOC_WORKER_START=fork``)."""
    return ChildSpec(
        "worker-pool", [sys.executable, "-m", "workers.pool", "--workers", str(count), "--log-level", log_level]
    )


def celery_worker_spec(concurrency: int, log_level: str = "info") -> ChildSpec:
    """The command line of a Celery worker (distributed profile) with ``concurrency`` processes."""
    return ChildSpec(
        "celery-worker",
        [sys.executable, "-m", "workers.celery_worker", "--concurrency", str(concurrency), "--log-level", log_level],
    )


def api_spec(host: str, port: int, log_level: str = "info") -> ChildSpec:
    """The command line of the API server (uvicorn)."""
    return ChildSpec(
        "api", [sys.executable, "-m", "service", "--host", host, "--port", str(port), "--log-level", log_level]
    )


class Supervisor:
    """Keeps ``specs`` running until SIGTERM/SIGINT (or :meth:`request_stop`)."""

    def __init__(self, specs: list[ChildSpec], *, stop_timeout_s: float = 30.0) -> None:
        self.children = [_Child(spec) for spec in specs]
        self.stop_timeout_s = stop_timeout_s
        self._stopping = False

    def request_stop(self, *_: object) -> None:
        """Begin shutdown (signal-handler compatible)."""
        self._stopping = True

    def _start(self, child: _Child) -> None:
        env = {**os.environ, **child.spec.env, "GEOLOC_SUPERVISOR_PID": str(os.getpid())}
        child.process = subprocess.Popen(child.spec.argv, env=env, start_new_session=True)
        child.started_at = time.monotonic()
        child.starts += 1
        child.restart_at = None
        log.info("started %s (pid %d)", child.spec.name, child.process.pid)

    def run(self) -> int:
        """Supervise until asked to stop; returns the exit code (0, or 1 after a startup failure)."""
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)
        exit_code = 0
        for child in self.children:
            self._start(child)
        try:
            while not self._stopping:
                time.sleep(0.2)
                now = time.monotonic()
                for child in self.children:
                    if child.process is not None and child.process.poll() is not None:
                        code = child.process.returncode
                        lived = now - child.started_at
                        child.process = None
                        if child.starts == 1 and lived < STARTUP_FAILURE_S and code > 0:
                            log.error("%s failed to start (exit code %s); stopping", child.spec.name, code)
                            exit_code = 1
                            self._stopping = True
                            break
                        child.restart_delay_s = (
                            0.5 if lived > 60 else min(child.restart_delay_s * 2, MAX_RESTART_DELAY_S)
                        )
                        child.restart_at = now + child.restart_delay_s
                        log.warning(
                            "%s exited (code %s) after %.1f s; restarting in %.1f s",
                            child.spec.name,
                            code,
                            lived,
                            child.restart_delay_s,
                        )
                    elif child.process is None and child.restart_at is not None and now >= child.restart_at:
                        self._start(child)
        finally:
            self._stop_all()
        return exit_code

    def _stop_all(self) -> None:
        running = [c.process for c in self.children if c.process is not None and c.process.poll() is None]
        for process in running:
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + self.stop_timeout_s
        for process in running:
            try:
                process.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                log.warning("pid %d did not stop in time; killing it and its children", process.pid)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGKILL)  # its own session: a Celery worker's pool goes too
                process.wait()
        log.info("all children stopped")
