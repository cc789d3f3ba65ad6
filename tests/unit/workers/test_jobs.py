"""The worker pool against a real database with real worker processes, in both profiles.

The built-in pool on SQLite; Celery workers on Redis and PostgreSQL, fed by the reconciler since these jobs
are enqueued straight into the table. Atomic claims, crash recovery after SIGKILL, retry limits, graceful
shutdown.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from db import Database, connect
from db import jobs as job_store
from tests.conftest import Profile
from tests.model_fixtures import link_models
from tests.service_fixtures import (
    REPO_ROOT,
    FailPayload,
    RecordPayload,
    SleepPayload,
    get_job_row,
    read_rows,
    running_workers,
    service_env,
    wait_for,
)

pytestmark = pytest.mark.slow


def new_database(profile: Profile, data_dir: Path) -> tuple[Database, dict[str, str]]:
    """A fresh database of the profile (open) and the settings its workers need."""
    target, env = profile.new_deployment(data_dir)
    return connect(target), env


def statuses(database: Path | str) -> dict[str, int]:
    rows = read_rows(database, "SELECT status, COUNT(*) AS n FROM jobs GROUP BY status")
    return {row["status"]: row["n"] for row in rows}


def test_two_competing_workers_never_run_a_job_twice(tmp_path: Path, built_models: Path, profile: Profile) -> None:
    data_dir = tmp_path / "data"
    db, env = new_database(profile, data_dir)
    log = tmp_path / "runs.log"
    n_jobs = 60
    for token in range(n_jobs):
        job_store.enqueue_job(db, "test_record", RecordPayload(token=token, log=str(log), seconds=0.01))
    db.close()
    with running_workers(data_dir, concurrency=2, models=built_models, **env) as workers:
        wait_for(
            lambda: statuses(workers.database).get("done", 0) == n_jobs,
            timeout=120,
            what=lambda: f"{n_jobs} jobs done\n{workers.log_tail()}",
        )
    lines = log.read_text().split("\n")[:-1]
    tokens = [int(line.split()[0]) for line in lines]
    assert sorted(tokens) == list(range(n_jobs)), "every job ran exactly once"
    pids = {line.split()[1] for line in lines}
    assert len(pids) == 2, "both workers took jobs"
    attempts = read_rows(workers.database, "SELECT DISTINCT attempts FROM jobs")
    assert [row["attempts"] for row in attempts] == [1]


def test_sigkilled_worker_loses_nothing(tmp_path: Path, built_models: Path, profile: Profile) -> None:
    data_dir = tmp_path / "data"
    db, env = new_database(profile, data_dir)
    log = tmp_path / "sleep.log"
    job_id = job_store.enqueue_job(db, "test_sleep", SleepPayload(seconds=3, log=str(log)), max_attempts=3)
    db.close()
    with running_workers(data_dir, concurrency=1, models=built_models, GEOLOC_JOB_LEASE_S="1.5", **env) as workers:
        wait_for(lambda: log.exists() and "start" in log.read_text(), timeout=60, what="the job to start")
        victim = int(log.read_text().split()[1])
        owner = get_job_row(workers.database, job_id)["lease_owner"]
        assert owner.split(":")[1] == str(victim)
        os.kill(victim, signal.SIGKILL)
        job = wait_for(
            lambda: (row := get_job_row(workers.database, job_id))["status"] == "done" and row,
            timeout=60,
            what=lambda: f"the job to complete after the crash\n{workers.log_tail()}",
        )
    assert job["attempts"] == 2
    assert job["lease_owner"] != owner
    events = log.read_text().split("\n")[:-1]
    assert [e.split()[0] for e in events] == ["start", "start", "end"]
    assert events[0].split()[1] == str(victim) and events[2].split()[1] != str(victim)


def test_retries_stop_at_the_limit_and_keep_the_error(tmp_path: Path, built_models: Path, profile: Profile) -> None:
    data_dir = tmp_path / "data"
    db, env = new_database(profile, data_dir)
    failing = job_store.enqueue_job(db, "test_fail", FailPayload(reason="disk on fire"), max_attempts=3)
    unknown = job_store.enqueue_job(db, "no_such_kind", FailPayload(), max_attempts=3)
    db.close()
    with running_workers(data_dir, concurrency=1, models=built_models, **env) as workers:
        wait_for(
            lambda: statuses(workers.database).get("failed", 0) == 2,
            timeout=60,
            what=lambda: f"failures\n{workers.log_tail()}",
        )
        time.sleep(0.5)  # nothing is retried past the limit
        job = get_job_row(workers.database, failing)
        other = get_job_row(workers.database, unknown)
    assert job["status"] == "failed" and job["attempts"] == 3
    assert "RuntimeError: deliberate failure: disk on fire" in job["error"]
    assert "Traceback" in job["error"] and "fail_handler" in job["error"]
    assert other["status"] == "failed" and other["attempts"] == 1, "an unknown kind is not retried"
    assert "no handler registered for job kind 'no_such_kind'" in other["error"]


def test_sigterm_releases_a_long_job_back_to_the_queue(tmp_path: Path, built_models: Path) -> None:
    """The built-in worker hands a job back after its grace period.

    A Celery worker instead lets running jobs finish on SIGTERM; one killed after that comes back through its
    lease, as in the SIGKILL test.
    """
    data_dir = tmp_path / "data"
    db, _ = new_database(Profile("embedded"), data_dir)
    log = tmp_path / "sleep.log"
    job_id = job_store.enqueue_job(db, "test_sleep", SleepPayload(seconds=60, log=str(log)))
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
