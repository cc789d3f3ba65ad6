"""The worker pool against a real database file with real worker processes.

Atomic claims, crash recovery after SIGKILL, retry limits, graceful shutdown.
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

from .model_fixtures import link_models
from .service_fixtures import (
    REPO_ROOT,
    get_job_row,
    read_rows,
    running_workers,
    service_env,
    wait_for,
)

pytestmark = pytest.mark.slow


def new_database(data_dir: Path):
    data_dir.mkdir(parents=True, exist_ok=True)
    db = connect(data_dir / "geoloc.sqlite3")
    migrate(db)
    return db


def statuses(db_path: Path) -> dict[str, int]:
    rows = read_rows(db_path, "SELECT status, COUNT(*) AS n FROM jobs GROUP BY status")
    return {row["status"]: row["n"] for row in rows}


def test_two_competing_workers_never_run_a_job_twice(tmp_path: Path, built_models: Path) -> None:
    data_dir = tmp_path / "data"
    db = new_database(data_dir)
    log = tmp_path / "runs.log"
    n_jobs = 60
    for token in range(n_jobs):
        job_store.enqueue_job(db, "test_record", {"token": token, "log": str(log), "seconds": 0.01})
    db.close()
    with running_workers(data_dir, concurrency=2, models=built_models) as workers:
        wait_for(
            lambda: statuses(workers.db_path).get("done", 0) == n_jobs,
            timeout=120,
            what=lambda: f"{n_jobs} jobs done\n{workers.log_tail()}",
        )
    lines = log.read_text().split("\n")[:-1]
    tokens = [int(line.split()[0]) for line in lines]
    assert sorted(tokens) == list(range(n_jobs)), "every job ran exactly once"
    pids = {line.split()[1] for line in lines}
    assert len(pids) == 2, "both workers took jobs"
    attempts = read_rows(data_dir / "geoloc.sqlite3", "SELECT DISTINCT attempts FROM jobs")
    assert [row["attempts"] for row in attempts] == [1]


def test_sigkilled_worker_loses_nothing(tmp_path: Path, built_models: Path) -> None:
    data_dir = tmp_path / "data"
    db = new_database(data_dir)
    log = tmp_path / "sleep.log"
    job_id = job_store.enqueue_job(db, "test_sleep", {"seconds": 3, "log": str(log)}, max_attempts=3)
    db.close()
    with running_workers(data_dir, concurrency=1, models=built_models, GEOLOC_JOB_LEASE_S="1.5") as workers:
        wait_for(lambda: log.exists() and "start" in log.read_text(), timeout=60, what="the job to start")
        victim = int(log.read_text().split()[1])
        owner = get_job_row(workers.db_path, job_id)["lease_owner"]
        assert owner.split(":")[1] == str(victim)
        os.kill(victim, signal.SIGKILL)
        job = wait_for(
            lambda: (row := get_job_row(workers.db_path, job_id))["status"] == "done" and row,
            timeout=60,
            what=lambda: f"the job to complete after the crash\n{workers.log_tail()}",
        )
    assert job["attempts"] == 2
    assert job["lease_owner"] != owner
    events = log.read_text().split("\n")[:-1]
    assert [e.split()[0] for e in events] == ["start", "start", "end"]
    assert events[0].split()[1] == str(victim) and events[2].split()[1] != str(victim)


def test_retries_stop_at_the_limit_and_keep_the_error(tmp_path: Path, built_models: Path) -> None:
    data_dir = tmp_path / "data"
    db = new_database(data_dir)
    failing = job_store.enqueue_job(db, "test_fail", {"reason": "disk on fire"}, max_attempts=3)
    unknown = job_store.enqueue_job(db, "no_such_kind", {}, max_attempts=3)
    db.close()
    with running_workers(data_dir, concurrency=1, models=built_models) as workers:
        wait_for(
            lambda: statuses(workers.db_path).get("failed", 0) == 2,
            timeout=60,
            what=lambda: f"failures\n{workers.log_tail()}",
        )
        time.sleep(0.5)  # nothing is retried past the limit
        job = get_job_row(workers.db_path, failing)
        other = get_job_row(workers.db_path, unknown)
    assert job["status"] == "failed" and job["attempts"] == 3
    assert "RuntimeError: deliberate failure: disk on fire" in job["error"]
    assert "Traceback" in job["error"] and "fail_handler" in job["error"]
    assert other["status"] == "failed" and other["attempts"] == 1, "an unknown kind is not retried"
    assert "no handler registered for job kind 'no_such_kind'" in other["error"]


def test_sigterm_releases_a_long_job_back_to_the_queue(tmp_path: Path, built_models: Path) -> None:
    data_dir = tmp_path / "data"
    db = new_database(data_dir)
    log = tmp_path / "sleep.log"
    job_id = job_store.enqueue_job(db, "test_sleep", {"seconds": 60, "log": str(log)})
    db.close()
    link_models(data_dir, built_models)
    env = service_env(data_dir, GEOLOC_WORKER_GRACE_S="0.5")
    process = subprocess.Popen([sys.executable, "-m", "workers"], cwd=REPO_ROOT, env=env)
    try:
        wait_for(lambda: log.exists() and "start" in log.read_text(), timeout=60, what="the job to start")
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=20) == 0
    finally:
        if process.poll() is None:
            process.kill()
    job = get_job_row(data_dir / "geoloc.sqlite3", job_id)
    assert job["status"] == "queued" and job["attempts"] == 0
    worker = read_rows(data_dir / "geoloc.sqlite3", "SELECT * FROM workers")[0]
    assert worker["stopped_at"] is not None
