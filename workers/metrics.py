"""Prometheus metrics shared by every process of a machine: prometheus-client in multiprocess mode.

Every API and worker process of a machine writes its counters and histograms into one folder
(``GEOLOC_METRICS_DIR``, by default one in the system's temporary directory: :func:`metrics_folder`), one
memory-mapped file per process and metric type, named ``<type>_<host>-<pid>.db`` (the host too, so that
containers sharing a volume, whose pids repeat, never write the same file); the API's ``GET /metrics`` adds
them up (:mod:`service.metrics`). :func:`enable_metrics` switches a process on (``GEOLOC_METRICS``, default
on); until then, and with metrics off, the recording functions here do nothing. A supervisor (``geoloc serve``,
``geoloc worker``) removes the files of its host's dead processes when it starts (:func:`remove_dead_files`): a
counter then restarts from zero, which Prometheus's ``rate()`` reads as a reset.

What the workers record (seconds):

- ``geoloc_job_duration_seconds{kind, outcome}``: each job run, from claim to outcome (``done``, ``retry``,
  ``failed``, ``released``); its ``_count`` counts the jobs run;
- ``geoloc_stage_duration_seconds{kind, stage}``: the method's stages in a job, from the timings its answer
  carries (``segmentation``, ``features``, ``facades``, ``retrieval``, ``transfer``, ``anchors``, ``localize``,
  ``fuse``, ``labeling``) and the sequence job's ``placement``.
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
import socket
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from contracts.settings import Settings

MULTIPROC_ENV: Final = "PROMETHEUS_MULTIPROC_DIR"
DURATION_BUCKETS_S: Final = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 300.0)
"""Histogram buckets (s) of jobs and stages: a stage takes milliseconds, a map's parse minutes."""
STAGES: Final = frozenset(
    {"segmentation", "features", "facades", "retrieval", "transfer", "anchors", "localize", "fuse", "labeling"}
)
"""The timing keys of an answer recorded as stages (the others are parts of these, or the total)."""
_FILE_NAME: Final = re.compile(r"(?:counter|histogram|summary|gauge_[a-z]+)_(?P<host>[^_]+)-(?P<pid>\d+)\.db")
"""A metric file's name: its type (a gauge's with its mode), host and pid."""

_state: dict[str, Any] = {}
"""This process's instruments once :func:`enable_metrics` ran (``"job"``, ``"stage"``, ``"folder"``)."""


def metrics_folder(settings: Settings) -> Path:
    """Where this machine's processes write their metrics: ``GEOLOC_METRICS_DIR``, else one of the temp folder.

    The default is named after ``GEOLOC_DATA_DIR`` in the system's temporary directory, so every process of one
    data folder finds the same one.

    Not in the data folder by default: the files are memory-mapped and grow sparse, and a write into a page the
    file system has no block for kills the process with SIGBUS. On a full data disk that was the API itself
    (``tests/e2e/test_durability.py``: a map upload reset the connection instead of answering ``507``).
    """
    if settings.metrics_dir is not None:
        return settings.metrics_dir
    tag = hashlib.sha256(str(settings.data_dir).encode()).hexdigest()[:12]
    return Path(tempfile.gettempdir()) / f"geoloc-metrics-{tag}"


def process_identifier() -> str:
    """The name of this process in the metric files: ``<host>-<pid>`` (a ``_`` of the host as ``-``)."""
    return f"{socket.gethostname().replace('_', '-')}-{os.getpid()}"


def enable_metrics(settings: Settings) -> Path | None:
    """Switch this process's metrics on in the machine's folder (created); None when ``GEOLOC_METRICS`` is off.

    Idempotent; safe before or after ``prometheus_client`` is imported (its value class is set here), and in a
    process forked from one that enabled them (the file names follow the pid).
    """
    if not settings.metrics:
        return None
    folder = metrics_folder(settings)
    if _state.get("folder") == folder:
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    os.environ[MULTIPROC_ENV] = str(folder)
    from prometheus_client import Histogram, values

    values.ValueClass = values.MultiProcessValue(process_identifier)  # type: ignore[no-untyped-call]
    _state.clear()
    _state["folder"] = folder
    _state["job"] = Histogram(
        "geoloc_job_duration_seconds",
        "Job runs by kind and outcome (done, retry, failed, released), from claim to outcome (s)",
        ["kind", "outcome"],
        buckets=DURATION_BUCKETS_S,
        registry=None,
    )
    _state["stage"] = Histogram(
        "geoloc_stage_duration_seconds",
        "The method's stages in a job, by job kind and stage (s)",
        ["kind", "stage"],
        buckets=DURATION_BUCKETS_S,
        registry=None,
    )
    return folder


def enabled_folder() -> Path | None:
    """The folder this process writes its metrics to, once :func:`enable_metrics` switched it on; else None."""
    folder: Path | None = _state.get("folder")
    return folder


def observe_job(kind: str, outcome: str, seconds: float) -> None:
    """Record one job run of ``kind`` that ended in ``outcome`` after ``seconds``."""
    if "job" in _state:
        _state["job"].labels(kind, outcome).observe(seconds)


def observe_stages(kind: str, timings_ms: Mapping[str, float]) -> None:
    """Record the stages of a job's answer (its ``timings_ms``, milliseconds) that are in :data:`STAGES`."""
    if "stage" not in _state:
        return
    for stage, ms in timings_ms.items():
        if stage in STAGES:
            _state["stage"].labels(kind, stage).observe(ms / 1e3)


def observe_stage(kind: str, stage: str, seconds: float) -> None:
    """Record one stage of a job of ``kind`` that took ``seconds`` (``placement``: a sequence's joint placement)."""
    if "stage" in _state:
        _state["stage"].labels(kind, stage).observe(seconds)


def remove_dead_files(folder: Path) -> int:
    """Remove the metric files of this host's processes that no longer run; returns how many.

    Files of other hosts (containers sharing the folder) are left: only their own supervisors know them.
    """
    host = socket.gethostname().replace("_", "-")
    removed = 0
    for path in glob.glob(os.path.join(folder, "*.db")):
        match = _FILE_NAME.fullmatch(os.path.basename(path))
        if match is None or match["host"] != host or _alive(int(match["pid"])):
            continue
        try:
            os.remove(path)
            removed += 1
        except FileNotFoundError:  # another supervisor removed it first
            pass
    return removed


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True
