"""Crash faults on the embedded profile: SIGKILLs at random moments during mixed writes, and the checks after each.

Shared by the short e2e test (``tests/e2e/test_crash_consistency.py``, as ``benchmarks.crash_faults``) and the long
benchmark (``benchmarks/bench_crashes.py``, as its sibling ``crash_faults``), so it imports only project packages.

One round (:func:`crash_round`): :class:`MixedWrites` threads upload references (new photos and ones already sent),
ask queries, delete references, queries and extra maps, while the workers label, answer and prune (retention);
at random moments processes of ``geoloc serve`` are SIGKILLed: the API or a worker (the supervisor starts it again,
the writes go on and ``PRAGMA integrity_check`` runs on the live database), and last every process at once (power
loss). Then, with nothing running, :func:`check_stopped`: ``integrity_check``, ``geoloc doctor --repair`` (its
checks and repairs, :func:`db.doctor.examine`), and the doctor once more, which must find nothing. After the last
round :func:`final_jobs` reads how every job ended once the workers ran out of work.
"""

from __future__ import annotations

import json
import os
import random
import signal
import sqlite3
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from db import connect
from db.doctor import examine
from db.files import open_store

FINAL = ("done", "failed", "cancelled")
TARGETS = ("api", "worker", "all")
"""What a kill hits: the API process, one worker process, or every process of the service (power loss)."""
FAULT_ENV = {
    "GEOLOC_QUERY_RETENTION_S": "3",  # retention prunes answered queries during the run (checked every 1 s)
    "GEOLOC_RATE_LIMIT_PER_MIN": "0",
    "GEOLOC_JOB_LEASE_S": "2",
    "GEOLOC_JOB_RETRY_DELAY_S": "0.1",
}
"""Settings of the service under test: short leases and retention, no rate limit (the queue bound is set per run)."""


def _children(pid: int) -> list[int]:
    try:
        return [int(child) for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _cmdline(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    except OSError:
        return []


def service_pids(supervisor_pid: int) -> dict[str, list[int]]:
    """The processes of ``geoloc serve``: ``api`` (``python -m service``) and ``worker`` (``python -m workers``)."""
    found: dict[str, list[int]] = {"api": [], "worker": []}
    for child in _children(supervisor_pid):
        argv = _cmdline(child)
        if "service" in argv:
            found["api"].append(child)
        elif "workers" in argv or "workers.pool" in argv:
            found["worker"].append(child)
    return found


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except OSError:
        return True


def kill(supervisor_pid: int, target: str, rng: random.Random) -> list[int]:
    """SIGKILL ``target`` (:data:`TARGETS`) of the service; returns the pids killed once they are gone.

    ``all`` kills the supervisor first (nothing is restarted), then its children in a random order.
    """
    children = service_pids(supervisor_pid)
    if target == "all":
        rest = children["api"] + children["worker"] + [pid for pid in _children(supervisor_pid) if pid not in children]
        victims = [supervisor_pid, *rng.sample(rest, len(rest))]
    else:
        victims = rng.sample(children[target], 1) if children[target] else []
    for pid in victims:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            continue
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not all(_gone(pid) for pid in victims):
        time.sleep(0.01)
    return victims


class MixedWrites:
    """Threads that write to the service until stopped: references, queries, deletes, extra maps.

    ``photo(seed)`` makes a photo; ``map_file`` is a small GeoJSON map (uploaded again under new names and deleted);
    ``form``: the reference's position fields. Every outcome is counted as ``"op status"`` or ``"op ErrorName"``
    (the API dies under them: connection errors are expected).
    """

    def __init__(
        self,
        base_url: str,
        map_id: int,
        photo: Callable[[int], bytes],
        map_file: bytes,
        form: dict[str, str],
        *,
        seed: int,
        headers: dict[str, str] | None = None,
        threads: int = 2,
        pause_s: float = 0.05,
    ) -> None:
        self.base_url, self.map_id, self.photo, self.map_file, self.form = base_url, map_id, photo, map_file, form
        self.headers = headers or {}
        self.rng = random.Random(seed)
        self.seed = seed
        self.threads = threads
        self.pause_s = pause_s
        self.outcomes: Counter[str] = Counter()
        self.references: list[int] = []
        self.queries: list[int] = []
        self.maps: list[int] = []
        self.sent = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._running: list[threading.Thread] = []

    def start(self) -> None:
        """Start the writer threads."""
        self._stop.clear()
        self._running = [threading.Thread(target=self._write, args=(n,), daemon=True) for n in range(self.threads)]
        for thread in self._running:
            thread.start()

    def stop(self) -> None:
        """Stop the writers and wait for their requests to end."""
        self._stop.set()
        for thread in self._running:
            thread.join(timeout=60)

    def _pick(self, ids: list[int]) -> int | None:
        with self._lock:
            return ids.pop(self.rng.randrange(len(ids))) if ids else None

    def _write(self, number: int) -> None:
        rng = random.Random(self.seed * 1000 + number + self.sent)
        with httpx.Client(base_url=self.base_url, headers=self.headers, timeout=30) as client:
            while not self._stop.is_set():
                op = rng.choices(("reference", "query", "delete_reference", "delete_query", "map"), (5, 2, 2, 1, 1))[0]
                try:
                    status = self._one(client, op, rng)
                except httpx.HTTPError as exc:
                    status = type(exc).__name__
                    time.sleep(0.2)  # the API is down: it comes back in a second
                with self._lock:
                    self.outcomes[f"{op} {status}"] += 1
                time.sleep(rng.uniform(0, 2 * self.pause_s))

    def _one(self, client: httpx.Client, op: str, rng: random.Random) -> int | str:
        if op in ("reference", "query"):
            with self._lock:
                self.sent += 1
                seed = rng.randrange(self.sent) if op == "reference" and rng.random() < 0.2 else self.sent
            files = {"image": ("p.jpg", self.photo(seed))}
            if op == "reference":
                response = client.post(f"/v1/maps/{self.map_id}/references", files=files, data=self.form)
            else:
                response = client.post(f"/v1/maps/{self.map_id}/queries", files=files, data={"wait_s": "0"})
            if response.status_code == 202:
                with self._lock:
                    (self.references if op == "reference" else self.queries).append(int(response.json()["id"]))
            return response.status_code
        if op == "map":
            if self.maps and rng.random() < 0.5:
                map_id = self._pick(self.maps)
                return client.delete(f"/v1/maps/{map_id}").status_code if map_id else "none"
            with self._lock:
                self.sent += 1
                name = f"extra {self.seed}-{self.sent}"
            content = self.map_file.replace(b'"Hall"', json.dumps(name).encode())
            response = client.post("/v1/maps", files={"file": ("m.geojson", content)}, data={"name": name})
            if response.status_code in (201, 202):
                with self._lock:
                    self.maps.append(int(response.json()["id"]))
            return response.status_code
        ids = self.references if op == "delete_reference" else self.queries
        row = self._pick(ids)
        if row is None:
            return "none"
        path = f"/v1/references/{row}" if op == "delete_reference" else f"/v1/queries/{row}"
        return client.delete(path).status_code


def integrity(database: Path) -> str:
    """``PRAGMA integrity_check``'s first line (``ok``) on a plain connection of its own."""
    conn = sqlite3.connect(str(database), timeout=30)
    try:
        return str(conn.execute("PRAGMA integrity_check").fetchone()[0])
    finally:
        conn.close()


@dataclass
class StoppedCheck:
    """What the checks found with nothing running: integrity, the doctor's findings, repairs, and what was left."""

    integrity: str
    found: dict[str, int]
    repaired: int
    left: list[str]

    def to_json(self) -> dict[str, Any]:
        """As a JSON object."""
        return {"integrity": self.integrity, "found": self.found, "repaired": self.repaired, "left": self.left}


def check_stopped(data_dir: Path, lease_s: float = 2.0) -> StoppedCheck:
    """With the service stopped: ``integrity_check``, the doctor with ``--repair``, and the doctor again.

    Every file is judged (grace 0); ``left`` lists what the second pass still found (it must be nothing).
    """
    ok = integrity(data_dir / "geoloc.sqlite3")
    db = connect(data_dir / "geoloc.sqlite3")
    try:
        store = open_store(data_dir)
        repaired = examine(db, store, repair=True, grace_s=0, lease_s=lease_s)
        again = examine(db, store, grace_s=0, lease_s=lease_s)
    finally:
        db.close()
    found = {check: count for check, count in repaired.counts().items() if count}
    left = [f"{f.check}: {f.subject}: {f.problem}" for f in again.findings + repaired.problems]
    return StoppedCheck(ok, found, len(repaired.findings) - len(repaired.problems), left)


@dataclass
class RoundResult:
    """One round: the kills (targets, in order), live integrity checks after a partial kill, the stopped check."""

    kills: list[str]
    live_integrity: list[str]
    stopped: StoppedCheck

    def to_json(self) -> dict[str, Any]:
        """As a JSON object."""
        return {"kills": self.kills, "live_integrity": self.live_integrity, "stopped": self.stopped.to_json()}


def crash_round(
    supervisor_pid: int,
    data_dir: Path,
    writes: MixedWrites,
    rng: random.Random,
    *,
    partial_kills: int,
    restarted: Callable[[], bool],
    window_s: tuple[float, float] = (0.3, 2.5),
) -> RoundResult:
    """Write; ``partial_kills`` times kill the API or a worker (at random) after a random time; then kill everything.

    Each wait is drawn from ``window_s`` (s). ``restarted()``: whether the service answers again after a partial kill
    (the supervisor restarts the killed process); the live database's ``integrity_check`` is read then. The round
    ends with :func:`check_stopped`.
    """
    kills: list[str] = []
    live: list[str] = []
    writes.start()
    try:
        for _ in range(partial_kills):
            time.sleep(rng.uniform(*window_s))
            target = rng.choice(TARGETS[:2])
            kill(supervisor_pid, target, rng)
            kills.append(target)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not restarted():
                time.sleep(0.1)
            live.append(integrity(data_dir / "geoloc.sqlite3"))
        time.sleep(rng.uniform(*window_s))
        kill(supervisor_pid, "all", rng)
        kills.append("all")
    finally:
        writes.stop()
    return RoundResult(kills, live, check_stopped(data_dir))


@dataclass
class JobOutcomes:
    """How the jobs ended: counts by status, and the failed ones' reasons (first line) by count."""

    statuses: dict[str, int] = field(default_factory=dict)
    reasons: dict[str, int] = field(default_factory=dict)
    without_reason: list[int] = field(default_factory=list)
    unfinished: list[int] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """As a JSON object."""
        return {
            "statuses": self.statuses,
            "failed_reasons": self.reasons,
            "failed_without_reason": self.without_reason,
            "unfinished": self.unfinished,
        }


def final_jobs(database: Path) -> JobOutcomes:
    """Every job's end: final (``done``, ``failed`` with a reason, ``cancelled``) or listed as unfinished."""
    conn = sqlite3.connect(str(database), timeout=30)
    try:
        rows = conn.execute("SELECT id, status, error FROM jobs ORDER BY id").fetchall()
    finally:
        conn.close()
    outcome = JobOutcomes(dict(Counter(status for _, status, _ in rows)))
    reasons: Counter[str] = Counter()
    for job_id, status, error in rows:
        if status not in FINAL:
            outcome.unfinished.append(job_id)
        elif status == "failed" and not (error or "").strip():
            outcome.without_reason.append(job_id)
        elif status == "failed":
            reasons[_reason(error)] += 1
    outcome.reasons = dict(reasons.most_common())
    return outcome


def _reason(error: str) -> str:
    """A failure's reason without its ids, to count alike ones together."""
    lines = error.strip().splitlines()
    line = lines[-1] if "worker lost" in lines[-1] else lines[0]  # a lost worker's note is added last
    words = ("W" if word.count(":") == 2 else "N" if word.strip(":,()").isdigit() else word for word in line.split())
    return " ".join(words)[:120]  # W: a worker id (host:pid:random)


def pending_jobs(database: Path) -> int:
    """Jobs still ``queued`` or ``running``."""
    conn = sqlite3.connect(str(database), timeout=30)
    try:
        return int(conn.execute("SELECT COUNT(*) FROM jobs WHERE status IN ('queued', 'running')").fetchone()[0])
    finally:
        conn.close()
