"""Real PostgreSQL, Redis and Prometheus servers for the tests and benchmarks, on loopback in temp folders.

``PostgresServer`` runs a private cluster (``initdb`` + ``pg_ctl``, Debian's ``postgresql`` package) owned
by the ``postgres`` system user when the tests run as root (``initdb`` refuses root), with ``fsync`` off
(a test cluster: durability across a machine crash is not what is tested); every test service gets its
own database, copied from a migrated template. ``RedisServer`` runs ``redis-server`` without persistence;
every test service gets its own logical database number. Both stop when the test session ends.

Neither is mocked: the tests talk to the real servers over TCP. Where a binary is missing the fixtures
fail with the package to install (``.ci/run`` installs them).

The module lives in ``testbed/``, below both ``benchmarks/`` and ``tests/``, because both start these servers
(the tests' fixtures in ``tests/conftest.py``; ``benchmarks/bench_ingest.py`` and ``bench_soak.py``'s distributed
profile), and a benchmark never imports the tests (they sit above it: they import the benchmarks' pure parts).
A benchmark run as a script reaches ``testbed`` through the checkout that ``benchmarks/local_service.py`` puts
on ``sys.path``.
"""

from __future__ import annotations

import contextlib
import glob
import itertools
import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from db import connect, connection, migrate

POSTGRES_USER = "postgres"
"""System user that owns the test cluster when the tests run as root."""
REDIS_DATABASES = 4096
"""Logical databases of the test Redis (one per test service)."""


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _wait_port(port: int, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return
        time.sleep(0.05)
    raise TimeoutError(f"{what} did not listen on 127.0.0.1:{port} within {timeout_s:.0f} s")


def postgres_bin(name: str) -> str:
    """Path of a PostgreSQL server program (``initdb``, ``pg_ctl``): on PATH or under /usr/lib/postgresql."""
    found = shutil.which(name) or next(iter(sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"), reverse=True)), None)
    if found is None:
        raise RuntimeError(f"{name} not found: install Debian's `postgresql` package (.ci/run does)")
    return found


class PostgresServer:
    """A private PostgreSQL cluster on 127.0.0.1 (a free port), in a temp folder."""

    def __init__(self) -> None:
        self.root = Path(tempfile.mkdtemp(prefix="geoloc-pg-"))
        self.port = _free_port()
        self.data = self.root / "data"
        self.log = self.root / "server.log"
        self._as_user: list[str] = []
        if os.geteuid() == 0:
            user = pwd.getpwnam(POSTGRES_USER)
            os.chown(self.root, user.pw_uid, user.pw_gid)
            self._as_user = ["runuser", "-u", POSTGRES_USER, "--"]
        self._names = itertools.count(1)
        self.template = "geoloc_template"
        self.options = ""

    def _run(self, *argv: str) -> None:
        subprocess.run([*self._as_user, *argv], check=True, capture_output=True, timeout=120)

    def start(self) -> PostgresServer:
        """initdb, start, and create the migrated template database."""
        self._run(postgres_bin("initdb"), "-D", str(self.data), "-U", "geoloc", "--auth=trust", "-E", "UTF8")
        options = (
            f"-p {self.port} -c listen_addresses=127.0.0.1 -k {self.root} -c fsync=off -c synchronous_commit=off"
            " -c full_page_writes=off -c max_connections=300 -c shared_buffers=64MB"
        )
        self.options = options
        self.resume()
        self._admin(f"CREATE DATABASE {self.template}")
        db = connect(self.url(self.template))
        try:
            migrate(db)
        finally:
            db.close()
        self._drop_pool(self.template)
        return self

    def halt(self) -> None:
        """Stop the server (fast shutdown: sessions are ended) and keep its data; :meth:`resume` starts it again."""
        self._run(postgres_bin("pg_ctl"), "-D", str(self.data), "-m", "fast", "-w", "stop")

    def resume(self) -> None:
        """Start the (initialised) cluster and wait until it accepts connections."""
        pg_ctl = postgres_bin("pg_ctl")
        self._run(pg_ctl, "-D", str(self.data), "-l", str(self.log), "-o", self.options, "-w", "start")
        _wait_port(self.port, 30, "PostgreSQL")

    def url(self, database: str) -> str:
        """``postgresql://`` URL of one database of this cluster."""
        return f"postgresql://geoloc@127.0.0.1:{self.port}/{database}"

    def _admin(self, sql: str) -> None:
        import psycopg

        with psycopg.connect(self.url("postgres"), autocommit=True) as conn:
            conn.execute(sql)

    def _drop_pool(self, database: str) -> None:
        """Close this process's pooled connections to ``database`` (a template must have none)."""
        pool = connection._pools.pop(self.url(database), None)
        if pool is not None:
            for conn in pool.idle:
                conn.close()

    def new_database(self) -> str:
        """A fresh, migrated database; returns its URL."""
        name = f"geoloc_{os.getpid()}_{next(self._names)}"
        self._admin(f"CREATE DATABASE {name} TEMPLATE {self.template}")
        return self.url(name)

    def new_empty_database(self) -> str:
        """A fresh database with no tables (for migration tests); returns its URL."""
        name = f"geoloc_{os.getpid()}_{next(self._names)}"
        self._admin(f"CREATE DATABASE {name} TEMPLATE template0")
        return self.url(name)

    def stop(self) -> None:
        """Stop the cluster (fast shutdown) and remove its folder."""
        with contextlib.suppress(Exception):
            self._run(postgres_bin("pg_ctl"), "-D", str(self.data), "-m", "immediate", "-w", "stop")
        shutil.rmtree(self.root, ignore_errors=True)


class RedisServer:
    """``redis-server`` on 127.0.0.1 (a free port), no persistence; :meth:`restart` loses every message."""

    def __init__(self) -> None:
        binary = shutil.which("redis-server")
        if binary is None:
            raise RuntimeError("redis-server not found: install Debian's `redis-server` package (.ci/run does)")
        self.binary = binary
        self.root = Path(tempfile.mkdtemp(prefix="geoloc-redis-"))
        self.port = _free_port()
        self.process: subprocess.Popen[bytes] | None = None
        self._numbers = itertools.count(1)

    def start(self) -> RedisServer:
        """Start the server and wait until it listens."""
        log = (self.root / "server.log").open("ab")
        self.process = subprocess.Popen(
            [
                self.binary,
                "--port", str(self.port),
                "--bind", "127.0.0.1",
                "--save", "",
                "--appendonly", "no",
                "--databases", str(REDIS_DATABASES),
                "--dir", str(self.root),
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        log.close()
        _wait_port(self.port, 30, "redis-server")
        return self

    def new_url(self) -> str:
        """A ``redis://`` URL of a logical database no other test service uses."""
        return f"redis://127.0.0.1:{self.port}/{next(self._numbers) % REDIS_DATABASES}"

    def stop(self) -> None:
        """Stop the server (SIGKILL: nothing is persisted anyway)."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait()
        self.process = None

    def restart(self, down_s: float = 0.0) -> None:
        """Kill the server, stay down ``down_s`` seconds, start it again empty on the same port."""
        self.stop()
        time.sleep(down_s)
        self.start()

    def close(self) -> None:
        """Stop the server and remove its folder."""
        self.stop()
        shutil.rmtree(self.root, ignore_errors=True)


class PrometheusServer:
    """A Prometheus server (Debian's ``prometheus``) on 127.0.0.1 scraping ``targets`` every ``interval_s``.

    For the metrics' end-to-end test (``tests/e2e/test_metrics.py``): the service's ``/metrics`` read by a
    real scraper and queried through Prometheus's own HTTP API (:meth:`query`). ``bearer``: the metrics key
    (``GEOLOC_METRICS_KEY``) sent as ``Authorization: Bearer``.
    """

    def __init__(self, targets: list[str], *, interval_s: float = 1.0, bearer: str | None = None) -> None:
        binary = shutil.which("prometheus")
        if binary is None:
            raise RuntimeError("prometheus not found: install Debian's `prometheus` package (.ci/run does)")
        self.binary = binary
        self.root = Path(tempfile.mkdtemp(prefix="geoloc-prometheus-"))
        self.port = _free_port()
        self.process: subprocess.Popen[bytes] | None = None
        auth = f"\n    authorization:\n      credentials: {bearer}" if bearer else ""
        quoted = ", ".join(f"'{t}'" for t in targets)
        (self.root / "prometheus.yml").write_text(
            f"global:\n  scrape_interval: {interval_s:g}s\n  scrape_timeout: {interval_s:g}s\n"
            f"scrape_configs:\n  - job_name: geoloc{auth}\n    static_configs:\n      - targets: [{quoted}]\n"
        )

    @property
    def url(self) -> str:
        """The server's base URL."""
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> PrometheusServer:
        """Start the server and wait until it listens."""
        log = (self.root / "server.log").open("ab")
        self.process = subprocess.Popen(
            [
                self.binary,
                f"--config.file={self.root / 'prometheus.yml'}",
                f"--storage.tsdb.path={self.root / 'data'}",
                f"--web.listen-address=127.0.0.1:{self.port}",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        log.close()
        _wait_port(self.port, 60, "prometheus")
        return self

    def query(self, promql: str) -> list[dict[str, object]]:
        """An instant query's result vector (``[{"metric": {...}, "value": [time, "value"]}, ...]``)."""
        import json
        import urllib.parse
        import urllib.request

        url = f"{self.url}/api/v1/query?" + urllib.parse.urlencode({"query": promql})
        with urllib.request.urlopen(url, timeout=10) as response:
            body = json.loads(response.read())
        if body.get("status") != "success":
            raise RuntimeError(f"prometheus query {promql!r} failed: {body}")
        result: list[dict[str, object]] = body["data"]["result"]
        return result

    def targets(self) -> list[dict[str, object]]:
        """The scrape targets as Prometheus sees them (``health``, ``lastError``, ``scrapeUrl``, ...)."""
        import json
        import urllib.request

        with urllib.request.urlopen(f"{self.url}/api/v1/targets", timeout=10) as response:
            active: list[dict[str, object]] = json.loads(response.read())["data"]["activeTargets"]
        return active

    def log_tail(self, lines: int = 30) -> str:
        """The end of the server's own log."""
        path = self.root / "server.log"
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:]) if path.exists() else ""

    def stop(self) -> None:
        """Stop the server and remove its folder."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process = None
        shutil.rmtree(self.root, ignore_errors=True)
