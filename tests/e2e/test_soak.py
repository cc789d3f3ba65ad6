"""``benchmarks/bench_soak.py`` run briefly on the embedded profile: its report's structure and its verdict.

Twenty seconds of load at a fixed rate (no saturation phase) with a 20 s retention, so that the run's own
retention check sees pruned queries; the memory and fd checks are not asserted to pass (twenty seconds is
warm-up), only that the report's checks are the verdict of its samples and the exit code follows them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.soak_checks import verdict
from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_a_brief_soak_reports_samples_jobs_retention_and_its_verdict(tmp_path: Path, built_models: Path) -> None:
    world = tmp_path / "world"
    generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), world, WorldOptions(n_references=6, n_queries=4))
    out = tmp_path / "soak.json"
    argv = [sys.executable, str(REPO / "benchmarks" / "bench_soak.py"), "--duration-s", "20", "--rate", "0.3",
            "--retention-s", "20", "--sample-s", "2", "--world", str(world), "--out", str(out)]  # fmt: skip
    env = {**os.environ, "GEOLOC_DATA_DIR": str(built_models.parent.parent), "PYTHONPATH": str(REPO)}
    run = subprocess.run(argv, check=False, env=env, capture_output=True, text=True, timeout=600)
    assert out.exists(), run.stdout[-3000:] + run.stderr[-3000:]
    report = json.loads(out.read_text())

    assert report["profile"] == "embedded" and report["rate_qps"] == 0.3 and report["saturation_qps"] is None
    assert report["errors"] == {}, report["error_samples"]
    jobs = report["jobs"]
    assert jobs["accepted"] > 0 and jobs["done"] == jobs["accepted"] and jobs["unfinished"] == 0
    assert report["retention"]["older_than_retention"] > 0
    assert report["retention"]["pruned"] == report["retention"]["older_than_retention"]
    for op in ("POST /v1/maps/{id}/queries", "POST /v1/maps/{id}/references", "POST /v1/maps", "DELETE /v1/maps/{id}"):
        assert report["requests"].get(op, 0) > 0, op
    samples = report["samples"]
    assert len(samples) >= 10 and samples[-1]["t_s"] >= 20
    for row in samples:
        roles = {name.split()[0] for name in row["processes"]}
        assert {"supervisor", "api", "worker"} <= roles
        assert all(p["rss_mb"] > 20 and p["fds"] > 0 for p in row["processes"].values())
        assert row["db_bytes"] > 0 and row["store_bytes"] > 0 and row["queued"] >= 0
    assert len([name for name in samples[-1]["processes"] if name.startswith("worker")]) == 2
    assert report["checks"] == dict(verdict(report))
    assert run.returncode == (0 if all(report["checks"].values()) else 1)
