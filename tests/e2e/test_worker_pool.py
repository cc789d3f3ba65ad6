"""The forking worker pool (``GEOLOC_WORKER_START=fork``, :mod:`workers.pool`) under ``geoloc serve``, for real.

Two forked workers register and run jobs; a SIGKILLed one loses no job (its lease expires and the other takes it)
and the pool forks a replacement; SIGTERM to the service stops everything within the grace period, handing the
running job back; the pool's parent gone, the pool and its workers stop; the pool itself SIGKILLed, its workers
stop.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from db import connect, migrate
from db import jobs as job_store
from tests.service_fixtures import (
    REPO_ROOT,
    SleepPayload,
    get_job_row,
    read_rows,
    running_service,
    service_env,
    wait_for,
)

pytestmark = pytest.mark.slow


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie nobody reaped does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def _children(pid: int) -> list[int]:
    """The live processes whose parent is ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid and fields[0] not in ("Z", "X"):
                found.append(int(entry.name))
    return sorted(found)


def _cmdline(pid: int) -> list[bytes]:
    return Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")


def _live_workers(database: Path) -> list[int]:
    return sorted(r["pid"] for r in read_rows(database, "SELECT pid FROM workers WHERE stopped_at IS NULL"))


def test_the_pool_forks_registered_workers_replaces_a_killed_one_and_stops_in_grace(
    tmp_path: Path, built_models: Path
) -> None:
    data_dir = tmp_path / "data"
    log = tmp_path / "sleep.log"
    with running_service(data_dir, workers=2, models=built_models, GEOLOC_WORKER_START="fork") as service:
        database = Path(service.database)
        pools = [p for p in _children(service.process.pid) if b"workers.pool" in _cmdline(p)]
        assert len(pools) == 1, [_cmdline(p) for p in _children(service.process.pid)]
        pool = pools[0]
        forked = wait_for(lambda: len(_children(pool)) == 2 and _children(pool), timeout=60, what="two workers")
        wait_for(lambda: _live_workers(database) == forked, timeout=60, what=service.log_tail)
        # The children carry the pool's command line: what LocalService.pids(b"workers") looks for.
        assert all(b"workers.pool" in _cmdline(pid) for pid in forked)

        db = connect(database)
        migrate(db)
        victim_job = job_store.enqueue_job(db, "test_sleep", SleepPayload(seconds=3, log=str(log)))
        job = wait_for(lambda: get_job_row(database, victim_job)["lease_owner"], timeout=30, what="a worker to claim")
        victim = int(job.split(":")[1])
        assert victim in forked
        os.kill(victim, signal.SIGKILL)
        done = wait_for(
            lambda: (row := get_job_row(database, victim_job))["status"] == "done" and row,
            timeout=60,
            what=lambda: f"the job to be taken again\n{service.log_tail()}",
        )
        assert done["attempts"] == 2 and int(done["lease_owner"].split(":")[1]) != victim
        again = wait_for(lambda: len(kids := _children(pool)) == 2 and victim not in kids and kids, timeout=30,
                         what="the pool to fork a replacement")  # fmt: skip
        wait_for(lambda: set(again) <= set(_live_workers(database)), timeout=30, what="the replacement to register")

        long_job = job_store.enqueue_job(db, "test_sleep", SleepPayload(seconds=60, log=str(log)))
        db.close()
        wait_for(lambda: get_job_row(database, long_job)["status"] == "running", timeout=30, what="the long job")
        started = time.monotonic()
        assert service.stop(timeout=40) == 0
        stopped_s = time.monotonic() - started
    assert stopped_s < 2 + 5 + 3, f"grace 2 s + margin 5 s; took {stopped_s:.1f} s"
    assert not any(_alive(pid) for pid in [pool, *again])
    assert get_job_row(database, long_job)["status"] == "queued"  # handed back, not lost
    assert _live_workers(database) == [victim]  # the SIGKILLed one never said goodbye; the others did


WRAPPER = """
import os, subprocess, sys, time
env = {**os.environ, "GEOLOC_SUPERVISOR_PID": str(os.getpid())}
pool = subprocess.Popen([sys.executable, "-m", "workers.pool", "--workers", "2"], env=env)
print(pool.pid, flush=True)
time.sleep(600)
"""


@pytest.mark.parametrize("killed", ["the pool's parent", "the pool"])
def test_workers_stop_when_the_pool_or_its_parent_is_gone(tmp_path: Path, built_models: Path, killed: str) -> None:
    from tests.model_fixtures import link_models  # as service_fixtures: the models only where workers run

    data_dir = tmp_path / "data"
    data_dir.mkdir()
    link_models(data_dir, built_models)
    database = data_dir / "geoloc.sqlite3"
    db = connect(database)
    migrate(db)
    db.close()
    wrapper = subprocess.Popen(
        [sys.executable, "-c", WRAPPER], cwd=REPO_ROOT, env=service_env(data_dir), stdout=subprocess.PIPE, text=True
    )
    try:
        assert wrapper.stdout is not None
        pool = int(wrapper.stdout.readline())
        forked = wait_for(lambda: len(_children(pool)) == 2 and _children(pool), timeout=60, what="two workers")
        wait_for(lambda: _live_workers(database) == forked, timeout=60, what="the workers to register")
        os.kill(wrapper.pid if killed == "the pool's parent" else pool, signal.SIGKILL)
        wait_for(lambda: not any(_alive(p) for p in [pool, *forked]), timeout=20, what=f"all to stop ({killed})")
        wait_for(lambda: _live_workers(database) == [], timeout=5, what="the workers to leave the table")
    finally:
        for pid in (wrapper.pid, pool):
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        wrapper.wait()
