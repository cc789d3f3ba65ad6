"""Fail fast on missing or stale models, or a GPU that is not there.

Without built (or with stale) models, or with ``GEOLOC_DEVICE=cuda`` where onnxruntime has no CUDA provider,
``geoloc serve`` and ``geoloc worker`` refuse to start with the reason and exit code 2, ``/readyz`` says why
the service is not ready, and a model that disappears while the service runs fails each job at once (no
retries) with that reason.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from geoloc.vision.onnx_session import CUDA_PROVIDER, available_providers
from tests.conftest import Profile
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    ONE_BUILDING,
    REPO_ROOT,
    WRITE_KEY,
    geoloc_command,
    get_job_row,
    jpeg_bytes,
    read_rows,
    running_service,
    service_env,
    wait_for,
)

pytestmark = pytest.mark.slow  # real server processes (tests/e2e/ is the slow suite)


def _run(args: list[str], data_dir: Path, **overrides: str) -> subprocess.CompletedProcess[str]:
    env = service_env(data_dir, **overrides)
    return subprocess.run(
        [*geoloc_command(), *args], cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120, check=False
    )


@pytest.mark.parametrize("args", [["serve", "--port", "1", "--workers", "1"], ["worker"]], ids=["serve", "worker"])
def test_no_models_no_start(tmp_path: Path, args: list[str]) -> None:
    result = _run(args, tmp_path / "data")
    assert result.returncode == 2, result.stderr
    assert "segmentation model not found" in result.stderr and "SBoW vocabulary not found" in result.stderr
    assert "geoloc models build" in result.stderr


def test_stale_models_no_start(tmp_path: Path, built_models: Path) -> None:
    models = tmp_path / "data" / "cache" / "models"
    shutil.copytree(built_models, models)
    meta_path = next(models.glob("espnetv2*.json"))
    meta = json.loads(meta_path.read_text())
    meta["weights_sha256"] = "0" * 64  # exported from other weights than the shared ones
    meta_path.write_text(json.dumps(meta))
    result = _run(["worker"], tmp_path / "data")
    assert result.returncode == 2 and "is stale" in result.stderr and "--force" in result.stderr, result.stderr


@pytest.mark.parametrize("args", [["serve", "--port", "1", "--workers", "1"], ["worker"]], ids=["serve", "worker"])
def test_cuda_without_a_gpu_no_start(tmp_path: Path, built_models: Path, args: list[str]) -> None:
    if CUDA_PROVIDER in available_providers():
        pytest.skip("this machine has onnxruntime's CUDA provider")
    shutil.copytree(built_models, tmp_path / "data" / "cache" / "models")
    result = _run(args, tmp_path / "data", GEOLOC_DEVICE="cuda")
    assert result.returncode == 2, result.stderr
    assert f"GEOLOC_DEVICE=cuda but onnxruntime has no {CUDA_PROVIDER}" in result.stderr, result.stderr
    assert "pip install 'geoloc[gpu]'" in result.stderr and "Traceback" not in result.stderr


def test_api_alone_starts_and_readyz_says_why(tmp_path: Path, profile: Profile) -> None:
    env = profile.new_env()
    with running_service(tmp_path / "data", workers=0, **env) as service, service.client(None) as client:
        # `serve --workers 0` still runs one worker, that takes only load_map jobs: once it has registered, /readyz
        # must still count no worker, since none would answer a query.
        sql = "SELECT kinds FROM workers WHERE stopped_at IS NULL"
        registered = wait_for(lambda: read_rows(service.database, sql), timeout=60, what=service.log_tail)
        assert [row["kinds"] for row in registered] == ["load_map"]
        ready = client.get("/readyz")
    assert ready.status_code == 503
    details = ready.json()["error"]["details"]
    assert details["profile"] == profile.name and details["database"] == "ok"
    assert details["broker"] == ("ok" if profile.distributed else None)
    problems = details["problems"]
    assert any("segmentation model not found" in p for p in problems), problems
    assert details["live_workers"] == 0, details
    assert any("no worker that takes queries has a heartbeat" in p for p in problems), problems


def test_a_model_gone_at_run_time_fails_the_job_at_once(tmp_path: Path, built_models: Path, profile: Profile) -> None:
    data_dir = tmp_path / "data"
    shutil.copytree(built_models, data_dir / "cache" / "models")  # a copy: this test deletes from it
    env = profile.new_env()
    with running_service(data_dir, workers=1, **env) as service, service.client(WRITE_KEY) as client:
        wait_for(lambda: client.get("/readyz").status_code == 200, timeout=60, what="the worker to start")
        next((data_dir / "cache" / "models").glob("*.onnx")).unlink()
        files = {"file": ("hall.geojson", json.dumps(ONE_BUILDING).encode())}
        map_id = client.post("/v1/maps", files=files, data={"wait_s": "120", "name": "hall"}).json()["id"]
        accepted = client.post(
            f"/v1/maps/{map_id}/references", files={"image": ("r.jpg", jpeg_bytes(seed=1))}, data=INSIDE_ONE_BUILDING
        ).json()
        job = wait_for(
            lambda: (row := get_job_row(service.database, accepted["job_id"]))["status"] in ("failed", "done") and row,
            timeout=120,
            what="the labelling job to end",
        )
        assert job["status"] == "failed" and job["attempts"] == 1, "a missing model is not retried"
        assert "segmentation model not found" in job["error"] and "geoloc models build" in job["error"]
        reference = client.get(f"/v1/references/{accepted['id']}").json()
        assert reference["status"] == "failed" and "segmentation model not found" in reference["error"]
        ready = wait_for(lambda: (r := client.get("/readyz")).status_code == 503 and r, timeout=30, what="not ready")
        assert any("segmentation model not found" in p for p in ready.json()["error"]["details"]["problems"])
