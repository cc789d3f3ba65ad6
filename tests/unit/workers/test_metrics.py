"""The workers' metrics (:mod:`workers.metrics`): files per process, summed; dead processes' files removed."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

from contracts.settings import Settings
from workers.metrics import metrics_folder, process_identifier, remove_dead_files

RECORD = """
import sys
from contracts.settings import Settings
from workers.metrics import enable_metrics, observe_job, observe_stages
folder = enable_metrics(Settings.from_values(data_dir=sys.argv[1], metrics=sys.argv[2]))
observe_job("localize_query", "done", 0.3)
observe_stages("localize_query", {"segmentation": 120.0, "total": 400.0, "grid": 5.0})
print(folder)
"""


def _record(data_dir: Path, metrics: str = "true") -> Path:
    """Record a job and its stages in a process of its own (``GEOLOC_METRICS=metrics``); the folder it used."""
    done = subprocess.run(
        [sys.executable, "-c", RECORD, str(data_dir), metrics], capture_output=True, text=True, check=True
    )
    return Path(done.stdout.strip())


def test_processes_write_their_own_files_which_add_up(tmp_path: Path) -> None:
    from prometheus_client import CollectorRegistry, generate_latest, multiprocess

    folder = _record(tmp_path)
    assert folder == metrics_folder(Settings.from_values(data_dir=tmp_path))
    assert not folder.is_relative_to(tmp_path)  # off the data disk: a full one would kill the process (SIGBUS)
    _record(tmp_path)
    files = sorted(p.name for p in folder.iterdir())
    assert len(files) == 2 and all(name.startswith("histogram_") for name in files), files
    registry = CollectorRegistry()
    multiprocess.MultiProcessCollector(registry, path=str(folder))
    text = generate_latest(registry).decode()
    assert 'geoloc_job_duration_seconds_count{kind="localize_query",outcome="done"} 2.0' in text
    assert 'geoloc_stage_duration_seconds_count{kind="localize_query",stage="segmentation"} 2.0' in text
    assert 'stage="total"' not in text and 'stage="grid"' not in text  # only the named stages


def test_metrics_off_records_nothing(tmp_path: Path) -> None:
    assert _record(tmp_path, "false") == Path("None")
    assert not metrics_folder(Settings.from_values(data_dir=tmp_path)).exists()


def test_the_files_of_dead_processes_of_this_host_are_removed(tmp_path: Path) -> None:
    folder = _record(tmp_path)  # its process has exited
    live = folder / f"counter_{process_identifier()}.db"  # this process: alive
    other_host = folder / "histogram_otherhost-1.db"
    live.write_bytes(b"")
    other_host.write_bytes(b"")
    assert remove_dead_files(folder) == 1
    assert sorted(p.name for p in folder.iterdir()) == sorted([live.name, other_host.name])
    assert socket.gethostname().replace("_", "-") in live.name
