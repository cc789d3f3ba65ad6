"""The service as the benchmarks run it: ``geoloc serve`` on loopback, started fresh and stopped.

:class:`LocalService` starts ``geoloc serve --workers N`` from a source folder (this checkout by default; a
benchmark may start an exported older commit beside it) on a free port, with a fresh data folder that links
the built models in, and returns once ``/readyz`` answers 200 (database, broker, models and a live worker).
The ``/proc`` helpers read its processes' CPU time and memory. Importing this module puts this checkout first
on ``sys.path``, so a benchmark measures this checkout's code whatever the environment has installed.
"""

from __future__ import annotations

import os
import platform
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO_ROOT))

from client import ApiError, Client, RetryPolicy, ServiceUnreachableError, calls  # noqa: E402
from contracts.settings import cache_dir  # noqa: E402
from workers.context import model_problems  # noqa: E402

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def exit_on_sigterm() -> None:
    """Make SIGTERM end this process with ``SystemExit`` (status 143), so that ``finally`` blocks run.

    The services run in their own sessions and outlive a plain SIGTERM of the benchmark that started them; with
    this, its ``finally`` stops them. Only from the main thread, and only where SIGTERM has its default action.
    """
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, lambda signum, _frame: sys.exit(128 + signum))


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def run_figures() -> dict[str, str]:
    """What a benchmark's JSON says of its run: the machine (cores, load average at the start) and the command."""
    return {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start",
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
    }


def parent_pid(pid: int) -> int | None:
    """The parent of process ``pid`` (``/proc/PID/stat``), None when it has gone."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None


def descendants(pid: int) -> list[int]:
    """Every descendant process of ``pid``."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (ppid := parent_pid(int(entry.name))) is not None:
            parents.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        found = parents.get(todo.pop(), [])
        out += found
        todo += found
    return out


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def status_mb(pid: int, key: str) -> float:
    """A memory figure of ``/proc/PID/status`` (``VmHWM``: peak resident, ``VmRSS``: now) in MB; NaN if absent."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


IDLE_CPU_S = 0.1
"""Worker CPU seconds in :data:`IDLE_WINDOW_S` below which :meth:`LocalService.wait_until_idle` counts them idle."""
IDLE_WINDOW_S = 2.0


def prepare_data_dir(data_dir: Path, *, fresh: bool = True) -> None:
    """Empty ``data_dir`` and link the built models in (when ``fresh``, or when they are not linked there yet)."""
    if fresh or not (data_dir / "cache" / "models").exists():
        shutil.rmtree(data_dir, ignore_errors=True)
        (data_dir / "cache").mkdir(parents=True)
        (data_dir / "cache" / "models").symlink_to(cache_dir() / "models", target_is_directory=True)


def start_geoloc(
    argv: list[str], data_dir: Path, env: dict[str, str] | None, source: Path, log_path: Path, *, append: bool
) -> subprocess.Popen[bytes]:
    """``geoloc ARGV`` run from ``source`` on ``data_dir``, in its own session, output to ``log_path``; no API keys."""
    environment = {**os.environ, "GEOLOC_DATA_DIR": str(data_dir), "PYTHONPATH": str(source), **(env or {})}
    environment.pop("GEOLOC_API_KEYS", None)
    exit_on_sigterm()
    with log_path.open("ab" if append else "wb") as log:
        return subprocess.Popen(
            [sys.executable, "-c", "from cli.main import app; app()", *argv],
            cwd=source,
            env=environment,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


class Supervised:
    """A ``geoloc`` supervisor process (``process``) and the processes under it."""

    process: subprocess.Popen[bytes]

    def pids(self, role: bytes) -> list[int]:
        """Its processes running module ``role`` or one in it: ``b"workers"`` (built-in or Celery), ``b"service"``."""
        found = []
        for pid in descendants(self.process.pid):
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if any(part == role or part.startswith(role + b".") for part in cmdline):
                found.append(pid)
        return found

    def worker_roles(self) -> dict[str, list[int]]:
        """Its worker processes by role: ``pool`` and ``worker``.

        ``pool``: a parent of other worker processes, which runs no jobs itself (the forking pool,
        :mod:`workers.pool`, or a Celery worker's main process); ``worker``: the processes that run jobs (the
        pool's children, spawned ``python -m workers`` processes, Celery's pool processes).
        """
        workers = self.pids(b"workers")
        parents = {parent_pid(pid) for pid in workers}  # a pool's workers are its own children
        pools = [pid for pid in workers if pid in parents]
        return {"pool": pools, "worker": [pid for pid in workers if pid not in pools]}

    def stop(self) -> None:
        """SIGTERM the supervisor (it stops its children), then SIGKILL the group if it lingers."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()


class LocalWorkers(Supervised):
    """``geoloc worker --concurrency N`` on ``data_dir`` (see :func:`prepare_data_dir`); started, not waited for.

    The workers alone, beside API processes started with ``workers=0`` (whose ``/readyz`` waits for a worker's
    heartbeat). env and source as for :class:`LocalService`; the log goes to ``log_path`` (default ``worker.log``
    beside ``data_dir``).
    """

    def __init__(
        self,
        data_dir: Path,
        *,
        concurrency: int,
        env: dict[str, str] | None = None,
        source: Path = REPO_ROOT,
        log_path: Path | None = None,
    ) -> None:
        if problems := model_problems():
            raise SystemExit("the built models are not usable: " + " ".join(problems))
        self.data_dir = data_dir
        self.log_path = log_path or data_dir.parent / "worker.log"
        argv = f"worker --concurrency {concurrency} --log-level warning".split()
        self.process = start_geoloc(argv, data_dir, env, source, self.log_path, append=False)


class LocalService(Supervised):
    """``geoloc serve --workers N`` on a fresh data folder ``data_dir``, ready when constructed.

    env: extra environment (e.g. the distributed profile's URLs); API keys are removed, so it needs none.
    fresh: False starts it on what ``data_dir`` already holds (a restart after a crash), else the folder is emptied.
    source: the source folder to run (default this checkout). The log goes to ``log_path`` (default
    ``serve.log`` beside ``data_dir``).
    """

    def __init__(
        self,
        data_dir: Path,
        *,
        workers: int,
        env: dict[str, str] | None = None,
        source: Path = REPO_ROOT,
        log_path: Path | None = None,
        ready_timeout_s: float = 180.0,
        name: str = "geoloc serve",
        fresh: bool = True,
    ) -> None:
        if problems := model_problems():
            raise SystemExit("the built models are not usable: " + " ".join(problems))
        prepare_data_dir(data_dir, fresh=fresh)
        self.name = name
        self.data_dir = data_dir
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path or data_dir.parent / "serve.log"
        serve = f"serve --host 127.0.0.1 --port {self.port} --workers {workers} --log-level warning".split()
        self.process = start_geoloc(serve, data_dir, env, source, self.log_path, append=not fresh)
        self.client = Client(self.url, timeout_s=600.0)
        deadline = time.monotonic() + ready_timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                self.client.close()
                raise SystemExit(f"{name} exited ({self.process.returncode}); see {self.log_path}")
            try:
                self.client.call(calls.ready(), retry=RetryPolicy(retries=0))
                return
            except (ApiError, ServiceUnreachableError):
                pass  # not ready (503) or not listening yet
            time.sleep(0.5)
        self.stop()
        raise SystemExit(f"{name} did not become ready in {ready_timeout_s:.0f} s; see {self.log_path}")

    @property
    def database_path(self) -> Path:
        """The embedded profile's SQLite file."""
        return self.data_dir / "geoloc.sqlite3"

    def worker_cpu_s(self) -> float:
        """CPU seconds its worker processes have used (user and system, :func:`cpu_seconds`)."""
        return sum(cpu_seconds(pid) for pid in self.pids(b"workers"))

    def wait_until_idle(self, timeout_s: float = 600.0) -> float:
        """Wait until its workers' CPU time stops growing: the jobs queued so far (and those they queued) ended.

        Returns the ``perf_counter`` time the quiet window began, when the work ended. Idle: less than
        :data:`IDLE_CPU_S` of worker CPU in :data:`IDLE_WINDOW_S` (idle polling costs about 0.02).
        """
        deadline = time.monotonic() + timeout_s
        before, since = self.worker_cpu_s(), time.perf_counter()
        while time.monotonic() < deadline:
            time.sleep(IDLE_WINDOW_S)
            now = self.worker_cpu_s()
            if now - before < IDLE_CPU_S:
                return since
            before, since = now, time.perf_counter()
        raise SystemExit(f"the workers were still busy after {timeout_s:.0f} s")

    def stop(self) -> None:
        """Close its client, then stop it (:meth:`Supervised.stop`)."""
        self.client.close()
        super().stop()
