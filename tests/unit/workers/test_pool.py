"""The forking pool's own logic (:class:`workers.pool.Pool`) with stand-in children, in a fresh process each.

A child failing at once stops the pool (exit 1, as the supervisor judges its children); a child that exits
later is forked again; SIGTERM stops the pool and its children. The real workers under ``geoloc serve``:
``tests/e2e/test_worker_pool.py``.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.service_fixtures import REPO_ROOT, wait_for

pytestmark = pytest.mark.slow  # each pool process imports and warms the handlers (seconds)

SCRIPT = """
import os, signal, sys, time
from pathlib import Path
from workers.pool import Pool
log, mode = Path(sys.argv[1]), sys.argv[2]
def child(index):
    with log.open("a") as f:
        f.write(f"{index} {os.getpid()}\\n")
    if mode == "fail":
        return 3
    if mode == "stubborn":
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    time.sleep(0.3 if mode == "short" else 600)
    return 0
raise SystemExit(Pool(2, child, stop_timeout_s=1.0).run())
"""


def _starts(log: Path) -> list[tuple[int, int]]:
    lines = log.read_text().split() if log.exists() else []
    return [(int(lines[i]), int(lines[i + 1])) for i in range(0, len(lines), 2)]


def _pool(log: Path, mode: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", SCRIPT, str(log), mode], cwd=REPO_ROOT)


def test_a_child_failing_at_once_stops_the_pool(tmp_path: Path) -> None:
    pool = _pool(tmp_path / "starts.log", "fail")
    assert pool.wait(timeout=60) == 1
    assert len(_starts(tmp_path / "starts.log")) in (1, 2)  # no second round


def test_exited_children_are_forked_again_and_sigterm_stops_all(tmp_path: Path) -> None:
    log = tmp_path / "starts.log"
    pool = _pool(log, "short")
    try:
        starts = wait_for(lambda: len(s := _starts(log)) >= 6 and s, timeout=60, what="children forked again")
        assert {index for index, _ in starts} == {0, 1} and len({pid for _, pid in starts}) == len(starts)
        pool.send_signal(signal.SIGTERM)
        started = time.monotonic()
        assert pool.wait(timeout=20) == 0 and time.monotonic() - started < 5.0
    finally:
        if pool.poll() is None:
            pool.kill()
            pool.wait()


@pytest.mark.parametrize("mode", ["long", "stubborn"])  # the stand-ins: SIGTERM's default action; SIGTERM ignored
def test_sigterm_reaches_the_children_and_stragglers_are_killed_after_the_timeout(tmp_path: Path, mode: str) -> None:
    log = tmp_path / "starts.log"
    pool = _pool(log, mode)
    try:
        starts = wait_for(lambda: len(s := _starts(log)) == 2 and s, timeout=60, what="two children")
        time.sleep(0.2)  # the stubborn ones have ignored SIGTERM by now
        started = time.monotonic()
        pool.send_signal(signal.SIGTERM)
        assert pool.wait(timeout=20) == 0
        took = time.monotonic() - started
        assert (took >= 1.0) if mode == "stubborn" else (took < 1.0), took
        assert not any(Path(f"/proc/{pid}").exists() for _, pid in starts)  # reaped by the pool
    finally:
        if pool.poll() is None:
            pool.kill()
            pool.wait()
