"""Crash consistency on the embedded profile: SIGKILLs at random moments during mixed writes, several times over.

Each round writes (references, queries, deletes, extra maps; the workers label, answer and prune finished queries)
and SIGKILLs, at random moments, the API or a worker (the supervisor restarts it; ``integrity_check`` on the live
database) and then every process at once. With nothing running: ``integrity_check`` is ``ok``, the doctor's repairs
leave nothing for a second pass. After the last round the service runs until its workers have nothing left: every
job ends ``done``, ``failed`` with a reason, or ``cancelled`` (a deleted reference's), and ``geoloc doctor`` finds
nothing. The 200-kill version is ``benchmarks/bench_crashes.py`` (docs/measurements/faults.md).
"""

from __future__ import annotations

import json
import random
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from benchmarks.crash_faults import FAULT_ENV, MixedWrites, check_stopped, crash_round, final_jobs, pending_jobs
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    ONE_BUILDING,
    WRITE_KEY,
    geoloc_command,
    jpeg_bytes,
    running_service,
    service_env,
    upload_hall_map,
    wait_for,
)

pytestmark = pytest.mark.slow

KILLS = 5
SEED = 51


def _photo(seed: int) -> bytes:
    return jpeg_bytes(320, 240, seed=seed)


def test_random_kills_during_mixed_writes_leave_a_consistent_deployment(tmp_path: Path, built_models: Path) -> None:
    data_dir = tmp_path / "data"
    env = {**FAULT_ENV, "GEOLOC_MAX_QUEUED_JOBS": "4"}  # bounds the work left when the kills end
    rng = random.Random(SEED)
    rounds = []
    map_id = None
    started = time.monotonic()
    while sum(len(done.kills) for done in rounds) < KILLS:
        with running_service(data_dir, workers=1, models=built_models, **env) as service:
            if map_id is None:
                with service.client(WRITE_KEY) as client:
                    map_id = upload_hall_map(client)
            writes = MixedWrites(
                str(service.base_url), map_id, _photo, json.dumps(ONE_BUILDING).encode(), INSIDE_ONE_BUILDING,
                seed=rng.randrange(10**6), headers={"X-API-Key": WRITE_KEY},
            )  # fmt: skip

            def answers(url: str = str(service.base_url)) -> bool:
                try:
                    return httpx.get(f"{url}/healthz", timeout=1).status_code == 200
                except httpx.HTTPError:
                    return False

            done = crash_round(
                service.process.pid, data_dir, writes, rng, restarted=answers, window_s=(0.2, 1.2),
                partial_kills=min(2, KILLS - sum(len(done.kills) for done in rounds) - 1),
            )  # fmt: skip
            rounds.append(done)
        assert set(done.live_integrity) <= {"ok"}, done
        assert done.stopped.integrity == "ok", done
        assert done.stopped.left == [], done
        assert sum(writes.outcomes.values()) > 0, "the writes ran"
    kill_time = time.monotonic() - started

    with running_service(data_dir, workers=1, models=built_models, **env) as service:
        wait_for(lambda: pending_jobs(service.database) == 0, timeout=120, what="the workers to finish every job")
    drain_time = time.monotonic() - started - kill_time
    after = check_stopped(data_dir)
    assert (after.integrity, after.found, after.left) == ("ok", {}, []), after
    jobs = final_jobs(data_dir / "geoloc.sqlite3")
    assert jobs.unfinished == [] and jobs.without_reason == [], jobs
    assert jobs.statuses.get("done", 0) > 0, jobs

    doctor = subprocess.run(
        [*geoloc_command(), "doctor", "--json", "--grace-s", "0"],
        env=service_env(data_dir), capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert doctor.returncode == 0, doctor.stdout + doctor.stderr
    report = json.loads(doctor.stdout)
    assert report["clean"] and report["integrity"] == "ok" and report["findings"] == [], report
    kills = sum(len(r.kills) for r in rounds)
    print(f"{kills} kills in {len(rounds)} rounds, {kill_time:.0f} s, drain {drain_time:.0f} s; "
          f"found {[r.stopped.found for r in rounds]}; jobs {jobs.statuses}")  # fmt: skip
