"""The Docker ``monitoring`` profile's files: Prometheus's scrape configuration and the Grafana dashboard.

The scrape configuration passes ``promtool check config``; every metric the dashboard queries is one the service
exports (named in ``service/observe.py``, ``service/metrics.py`` or ``workers/metrics.py``); the compose file
runs both in the ``monitoring`` profile with the files mounted.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[3]
SUFFIXES = re.compile(r"_(bucket|count|sum|total)$")


def _exported() -> set[str]:
    sources = ("service/observe.py", "service/metrics.py", "workers/metrics.py")
    return {name for path in sources for name in re.findall(r'"(geoloc_[a-z_]+)"', (ROOT / path).read_text())}


def test_every_metric_of_the_dashboard_is_exported() -> None:
    dashboard = json.loads((ROOT / "docker/grafana/dashboards/geoloc.json").read_text())
    exprs = [target["expr"] for panel in dashboard["panels"] for target in panel["targets"]]
    queried = {SUFFIXES.sub("", name) for expr in exprs for name in re.findall(r"\bgeoloc_[a-z_]+", expr)}
    exported = _exported()
    assert len(queried) >= 9 and queried <= exported, queried - exported
    assert {"geoloc_jobs", "geoloc_stage_duration_seconds", "geoloc_http_request_duration_seconds"} <= queried


def test_the_scrape_configuration_is_valid(tmp_path: Path) -> None:
    promtool = shutil.which("promtool")
    if promtool is None:
        pytest.fail("promtool not found: install Debian's `prometheus` package (.ci/run does)")
    key = tmp_path / "metrics-key"
    key.write_text("secret")
    config = tmp_path / "prometheus.yml"
    config.write_text((ROOT / "docker/prometheus.yml").read_text().replace("/prometheus/metrics-key", str(key)))
    checked = subprocess.run([promtool, "check", "config", str(config)], capture_output=True, text=True, check=False)
    assert checked.returncode == 0, checked.stdout + checked.stderr


def test_the_compose_file_runs_them_in_the_monitoring_profile() -> None:
    compose = yaml.safe_load((ROOT / "docker/compose.yaml").read_text())
    for name in ("prometheus", "grafana"):
        assert compose["services"][name]["profiles"] == ["monitoring"]
    mounts = [m for name in ("prometheus", "grafana") for m in compose["services"][name]["volumes"]]
    for mount in mounts:
        source = mount.split(":")[0]
        if source.startswith("./"):
            assert (ROOT / "docker" / source).exists(), mount
    for name in ("api", "worker", "api-a", "celery-worker"):
        assert "GEOLOC_METRICS_KEY" in compose["services"][name]["environment"], name
