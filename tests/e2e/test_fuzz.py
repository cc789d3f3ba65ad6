"""An external fuzzer against a real server: Schemathesis with every check finds nothing.

``schemathesis run http://HOST:PORT/openapi.json --checks all`` (the repository's ``schemathesis.toml``
applies) against ``geoloc serve`` on loopback with one worker, once without API keys, once with keys
and a rate limit, and once with the keys of two tenants, on a database seeded with a map, a reference and a
query so that the operations on existing resources are reached too (their ids are offered to the fuzzer half
of the time). With tenants each tenant's key seeds its own rows and the fuzzer, with team-a's key, is offered
the ids of both: team-b's must answer the documented ``404``. A bounded number of examples per operation
keeps each run under a minute or two on 2 cores.
"""

from __future__ import annotations

import json
import re
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    ONE_BUILDING,
    REPO_ROOT,
    WRITE_KEY,
    jpeg_bytes,
    running_service,
)

pytestmark = pytest.mark.slow

MAX_EXAMPLES = 25
SEED = 1
RUN_TIMEOUT_S = 600


def _seed(client: httpx.Client) -> dict[str, int]:
    """A map, a reference and a query: ids the fuzzer can use on the operations that need one."""
    files = {"file": ("hall.geojson", json.dumps(ONE_BUILDING).encode())}
    map_id = client.post("/v1/maps", files=files, data={"wait_s": "120", "name": "fuzz"}).json()["id"]
    reference = client.post(
        f"/v1/maps/{map_id}/references",
        files={"image": ("r.jpg", jpeg_bytes(seed=11))},
        data=INSIDE_ONE_BUILDING,
    ).json()
    query = client.post(
        f"/v1/maps/{map_id}/queries",
        files={"image": ("q.jpg", jpeg_bytes(seed=12))},
        data={"use_exif_gps": "false", "wait_s": "0"},
    ).json()
    return {"map_id": map_id, "reference_id": reference["id"], "query_id": query["id"], "job_id": query["job_id"]}


def _config_with_seeds(path: Path, seeded: list[dict[str, int]]) -> Path:
    """The repository's ``schemathesis.toml`` plus dictionaries offering the seeded ids (of every seeding)."""
    lines = [(REPO_ROOT / "schemathesis.toml").read_text(), ""]
    ids = seeded[0]
    for name in ids:
        lines += [f"[dictionaries.seeded-{name}]", f"values = [{', '.join(str(s[name]) for s in seeded)}]", ""]
    lines.append("[parameters]")
    lines += [f'"path.{name}" = {{ dictionary = "seeded-{name}", probability = 0.5 }}' for name in ids]
    path.write_text("\n".join(lines) + "\n")
    return path


def _schemathesis(base_url: str, config: Path, headers: dict[str, str]) -> subprocess.CompletedProcess[str]:
    command = [
        str(Path(sys.executable).parent / "schemathesis"),
        "--config-file",
        str(config),
        "run",
        f"{base_url}/openapi.json",
        "--checks",
        "all",
        "--max-examples",
        str(MAX_EXAMPLES),
        "--seed",
        str(SEED),
        "--request-timeout",
        "60",
    ]
    for name, value in headers.items():
        command += ["--header", f"{name}: {value}"]
    return subprocess.run(
        command, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, cwd=config.parent, check=False
    )


TEAM_B_KEY = "fuzz-team-b"


@pytest.mark.parametrize(
    ("api_keys", "seed_keys", "overrides"),
    [
        (None, [None], {}),
        (f"{WRITE_KEY}:write,fuzz-reader:read", [WRITE_KEY], {"GEOLOC_RATE_LIMIT_PER_MIN": "3000"}),
        (
            f"{WRITE_KEY}:write@team-a,{TEAM_B_KEY}:read+write@team-b,fuzz-reader:read@team-a",
            [WRITE_KEY, TEAM_B_KEY],
            {"GEOLOC_RATE_LIMIT_PER_MIN": "3000"},
        ),
    ],
    ids=["without-api-keys", "with-api-keys", "with-tenants"],
)
def test_schemathesis_with_every_check_finds_nothing(
    tmp_path: Path, built_models: Path, api_keys: str | None, seed_keys: list[str | None], overrides: dict[str, Any]
) -> None:
    data_dir = tmp_path / "data"
    with running_service(data_dir, workers=1, models=built_models, api_keys=api_keys, **overrides) as service:
        seeded = []
        for key in seed_keys:  # with tenants: team-a's rows, then team-b's (ids the fuzzer's key may not see)
            with service.client(key) as client:
                seeded.append(_seed(client))
        run = _schemathesis(service.base_url or "", _config_with_seeds(tmp_path / "schemathesis.toml", seeded),
                            {"X-API-Key": WRITE_KEY} if api_keys else {})  # fmt: skip
        report = run.stdout[-6000:] + run.stderr[-2000:]
        assert run.returncode == 0, report
        counts = re.search(r"(\d+) generated, (\d+) passed", run.stdout)
        assert counts and int(counts[1]) >= 300 and counts[1] == counts[2], report
        assert httpx.get(f"{service.base_url}/healthz", timeout=5).status_code == 200, "the service is still up"
    conn = sqlite3.connect(str(data_dir / "geoloc.sqlite3"))
    try:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        conn.close()
