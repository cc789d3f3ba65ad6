"""``python -m workers.pool --workers N``: N embedded-profile workers forked from one warmed parent.

Why: the workers' own memory. A worker process's private pages are mostly what every worker holds alike: the
imported modules (numpy, numba, shapely, OpenCV, pyproj, pydantic, osmium...: 67 MB Private_Dirty per process,
``/proc/self/smaps_rollup``) and numba's LLVM with the SBoW kernels loaded (25 MB). Started separately (``python -m
workers`` N times, ``GEOLOC_WORKER_START=spawn``) each process holds its own copy; forked from a parent that has
imported and warmed them, the children share those pages copy-on-write. Measured on the 100 k-reference database
(``benchmarks/bench_sbow.py --references 100000 --workers 4``): 4 workers together took 1.73x one worker's PSS
spawned, 1.08x forked (the pool parent counted); warming only the imports, without numba's kernels, 1.30x.

The pool does what ``python -m workers`` does before its loop (settings, the model check with exit 2 and the
reason, niceness, handlers, plugins), then :func:`warm` (the handlers' modules, numba's kernels), ``gc.collect();
gc.freeze()`` (the objects that exist now are never touched by the collector again, so their pages stay shared)
and forks N children, each running :meth:`workers.worker.Worker.run` with ``parent_pid`` = the pool (a child stops
by itself when the pool is gone). The pool re-forks a child that dies (0.5 s doubling to 30 s, reset after 60 s
alive, as :class:`workers.supervisor.Supervisor`), forwards SIGTERM/SIGINT to its children, waits for them up to
``GEOLOC_WORKER_GRACE_S`` + :data:`STOP_MARGIN_S` and SIGKILLs the rest, and stops (children too) when its own
parent, the supervisor (``GEOLOC_SUPERVISOR_PID``), is gone.

**Before forking, the pool starts no thread and opens no database connection** (a forked thread is gone in the
child but its locks stay held; a forked SQLite connection must not be used by two processes): :func:`warm` only
imports and runs numba's compiled kernels on tiny arrays. Each child opens its own connection in ``Worker.run``.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import logging
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from contracts.logs import configure_logging
from contracts.settings import Settings, SettingsError, get_settings
from geoloc.localize.sbow_index import SbowIndex
from workers.context import device_probe, model_problems, needs_models
from workers.handlers import load_builtin_handlers, load_plugins
from workers.metrics import enable_metrics
from workers.supervisor import MAX_RESTART_DELAY_S, STARTUP_FAILURE_S
from workers.worker import Worker, install_signal_handlers

log = logging.getLogger("geoloc.pool")

STOP_MARGIN_S = 5.0
"""Seconds past the grace period a child gets to release its job and leave the workers table before SIGKILL."""


def warm() -> None:
    """Load what every worker uses, in this process, so that forked children share it.

    The handlers' modules (:func:`workers.handlers.load_builtin_handlers`) and numba's compiled SBoW kernels: a tiny
    :class:`SbowIndex` with one base and one recent document, queried once, loads both kernels' machine code from
    numba's cache. Starts no thread, opens no database.
    """
    load_builtin_handlers()
    index = SbowIndex(16)
    index.load(np.array([1]), np.array([2.0]), np.array([3]), np.array([0]), np.array([2.0]))
    index.add_words(2, np.array([3, 4]))
    index.top(np.array([3, 4, 5]), 2)


def fork_child(target: Callable[[], int]) -> int:
    """Fork a child that runs ``target`` and exits with its return value (1 on an exception); the child's pid."""
    pid = os.fork()
    if pid:
        return pid
    code = 1
    try:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        code = target()
    except BaseException:
        logging.getLogger("geoloc.pool").exception("child %d failed", os.getpid())
    finally:
        logging.shutdown()
        os._exit(code)


def freeze_warmed() -> None:
    """:func:`warm` this process, collect and freeze its heap: the objects that exist now stay untouched (shared)."""
    warm()
    gc.collect()
    gc.freeze()


@dataclass
class _Slot:
    pid: int | None = None
    started_at: float = 0.0
    restart_delay_s: float = 0.5
    restart_at: float | None = None
    starts: int = 0


class Pool:
    """Keeps ``count`` forked children running ``target(i)`` until SIGTERM/SIGINT or its parent is gone."""

    def __init__(
        self, count: int, target: Callable[[int], int], *, stop_timeout_s: float, parent_pid: int | None = None
    ) -> None:
        self.count = count
        self.target = target
        self.stop_timeout_s = stop_timeout_s
        self.parent_pid = parent_pid
        self.slots = [_Slot() for _ in range(count)]
        self._stopping = False

    def request_stop(self, *_: object) -> None:
        """Begin shutdown (signal-handler compatible)."""
        self._stopping = True

    def _parent_gone(self) -> bool:
        return self.parent_pid is not None and os.getppid() != self.parent_pid

    def _fork(self, index: int) -> None:
        slot = self.slots[index]
        slot.pid = fork_child(functools.partial(self.target, index))
        slot.started_at, slot.restart_at = time.monotonic(), None
        slot.starts += 1
        log.info("forked worker %d (pid %d)", index, slot.pid)

    def run(self) -> int:
        """Fork the children (after :func:`warm` and ``gc.freeze()``) and keep them running.

        Returns 0, or 1 when a child's first run failed within ``STARTUP_FAILURE_S`` (as the supervisor judges its
        own children: a setting or database that cannot work is not retried forever).
        """
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)
        freeze_warmed()
        for index in range(self.count):
            self._fork(index)
        try:
            while not self._stopping:
                if self._parent_gone():
                    log.warning("parent process gone; stopping the workers")
                    break
                time.sleep(0.2)
                if not self._reap():
                    return 1
        finally:
            self._stop_all()
        return 0

    def _reap(self) -> bool:
        """Note the children that exited and fork the ones due; False after a startup failure."""
        now = time.monotonic()
        for index, slot in enumerate(self.slots):
            if slot.pid is not None:
                done, status = os.waitpid(slot.pid, os.WNOHANG)
                if not done:
                    continue
                lived, code = now - slot.started_at, os.waitstatus_to_exitcode(status)
                slot.pid = None
                if slot.starts == 1 and lived < STARTUP_FAILURE_S and code > 0:
                    log.error("worker %d failed to start (exit code %s); stopping", index, code)
                    return False
                slot.restart_delay_s = 0.5 if lived > 60 else min(slot.restart_delay_s * 2, MAX_RESTART_DELAY_S)
                slot.restart_at = now + slot.restart_delay_s
                log.warning(
                    "worker %d exited (status %s) after %.1f s; forking another in %.1f s",
                    index,
                    code,
                    lived,
                    slot.restart_delay_s,
                )
            elif slot.restart_at is not None and now >= slot.restart_at:
                self._fork(index)
        return True

    def _stop_all(self) -> None:
        running = [slot.pid for slot in self.slots if slot.pid is not None]
        for pid in running:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)
        deadline = time.monotonic() + self.stop_timeout_s
        while running and time.monotonic() < deadline:
            running = [pid for pid in running if os.waitpid(pid, os.WNOHANG)[0] == 0]
            if running:
                time.sleep(0.05)
        for pid in running:
            log.warning("worker pid %d did not stop in time; killing it", pid)
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        log.info("all workers stopped")


def device_refused(settings: Settings) -> bool:
    """Whether ``GEOLOC_DEVICE=cuda`` cannot open a network on the GPU here (the reason printed on stderr).

    :func:`workers.context.device_probe`, which opens the segmentation network: in a process about to run jobs,
    never in the pool before it forks (CUDA does not survive a fork).
    """
    problems = device_probe() if needs_models(settings) else []
    if problems:
        print("error: the worker cannot run jobs:\n  " + "\n  ".join(problems), file=sys.stderr)
    return bool(problems)


def _run_worker(settings: Settings, pool_pid: int) -> int:
    """A forked child's work: one :class:`Worker` loop, stopping when the pool ``pool_pid`` is gone."""
    if device_refused(settings):
        return 2
    worker = Worker(settings)
    worker.parent_pid = pool_pid
    install_signal_handlers(worker)
    worker.run()
    return 0


def prepare(log_level: str | None) -> Settings | None:
    """What a worker process does before its loop; None (after printing the reason) when it must exit with 2.

    The settings, logging (``GEOLOC_LOG_FORMAT``), metrics (``GEOLOC_METRICS``), the model check (when the workers
    run the method's jobs), the niceness ``GEOLOC_WORKER_NICE``, the shipped handlers and ``GEOLOC_WORKER_PLUGINS``.
    Shared by ``python -m workers``.
    """
    try:
        settings = get_settings()
    except SettingsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    configure_logging(log_level or settings.log_level, settings.log_format, "worker")
    enable_metrics(settings)
    problems = model_problems() if needs_models(settings) else []
    if problems:
        print("error: the worker cannot run jobs:\n  " + "\n  ".join(problems), file=sys.stderr)
        return None
    if settings.worker_nice:
        os.nice(settings.worker_nice)
    load_builtin_handlers()
    load_plugins(settings.worker_plugins)
    return settings


def supervisor_pid() -> int | None:
    """The supervisor's pid from ``GEOLOC_SUPERVISOR_PID`` (None when not supervised)."""
    parent = os.environ.get("GEOLOC_SUPERVISOR_PID")
    return int(parent) if parent else None


def main(argv: list[str] | None = None) -> int:
    """Parse options, :func:`prepare` (exit 2 with the reason), run the pool until SIGTERM/SIGINT."""
    parser = argparse.ArgumentParser(prog="python -m workers.pool", description="Run N forked geoloc workers.")
    parser.add_argument("--workers", type=int, default=1, help="worker processes to fork (at least 1)")
    parser.add_argument("--log-level", default=None, help="default: GEOLOC_LOG_LEVEL")
    args = parser.parse_args(argv)
    settings = prepare(args.log_level)
    if settings is None:
        return 2
    pool_pid = os.getpid()
    pool = Pool(
        max(args.workers, 1),
        lambda _: _run_worker(settings, pool_pid),
        stop_timeout_s=settings.worker_grace_s + STOP_MARGIN_S,
        parent_pid=supervisor_pid(),
    )
    return pool.run()


if __name__ == "__main__":
    raise SystemExit(main())
