"""The method's context built from the settings: once per process in the workers, and for the command line.

:func:`method_context` is the one place that turns the settings into a :class:`~geoloc.core.context.MethodContext`
(the models folder ``DATA_DIR/cache/models``, ``GEOLOC_JOB_THREADS`` job threads, ``GEOLOC_SEG_THREADS``
onnxruntime threads, else the job threads, the networks' device ``GEOLOC_DEVICE``); :func:`worker_context` also
limits numpy's BLAS and OpenCV to ``GEOLOC_WORKER_THREADS`` threads in a worker process (the pool's processes are
the parallelism; measured on the shared 2-core machine at load average 5: one descriptor product of matching, 1,400
x 1,200 RootSIFT, took 7.5 ms with one BLAS thread and 13.9 ms with two). :func:`model_problems` checks the built
models against the settings' folders and that the device ``GEOLOC_DEVICE`` names can be used here (``cuda`` without
onnxruntime's CUDA provider is refused like a missing model: a worker does not start, ``/readyz`` says why).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

from contracts.jobs import LOAD_MAP
from contracts.settings import Settings, default_threads, get_settings, models_dir, shared_dir
from geoloc.core.context import Device, MethodContext
from geoloc.core.parallel import JobThreads
from geoloc.vision import model_files, onnx_session

_limited: dict[int, int] = {}
"""The BLAS/OpenCV thread count set in each process (by process id)."""


@lru_cache(maxsize=8)
def _context(
    models: Path, job_threads: int, onnx_threads: int, device: Device, segmentation_size: tuple[int, int] | None
) -> MethodContext:
    """One context (and so one job thread pool) per distinct setting."""
    return MethodContext(models, JobThreads(job_threads), onnx_threads, device, segmentation_size)


def segmentation_size(settings: Settings | None = None) -> tuple[int, int] | None:
    """``GEOLOC_SEGMENTATION_SIZE`` as (W, H), None when unset (the method's default); ValueError if not a size."""
    text = (settings or get_settings()).segmentation_size
    return None if text is None else model_files.parse_size(text)


def method_context() -> MethodContext:
    """The method's context from the current settings (the same object while they stay the same)."""
    settings = get_settings()
    return _context(models_dir(), settings.job_threads, default_threads(), settings.device, segmentation_size(settings))


def limit_threads(threads: int | None = None) -> None:
    """Run numpy's BLAS and OpenCV with ``threads`` threads (default ``GEOLOC_WORKER_THREADS``) in this process."""
    # OpenCV and threadpoolctl only where the method runs: the API imports this module for model_problems.
    import cv2
    from threadpoolctl import threadpool_limits

    count = threads or get_settings().worker_threads
    threadpool_limits(limits=count, user_api="blas")
    cv2.setNumThreads(count)
    _limited[os.getpid()] = count


def worker_context() -> MethodContext:
    """:func:`method_context` in a worker process: the first call there limits its BLAS and OpenCV threads."""
    if os.getpid() not in _limited:
        limit_threads()
    return method_context()


def model_problems(size: tuple[int, int] | None = None) -> list[str]:
    """What stops the workers: missing or stale models, a device that is not here; [] when they can run.

    :func:`geoloc.vision.model_files.model_problems` for the settings' models folder, segmentation network size
    (``size``, else ``GEOLOC_SEGMENTATION_SIZE``, else the method's) and shared weights, and
    :func:`geoloc.vision.onnx_session.device_problems` for ``GEOLOC_DEVICE`` (checked without opening a network).
    """
    try:
        size = size or segmentation_size()
    except ValueError as exc:
        return [f"GEOLOC_SEGMENTATION_SIZE: {exc}"]
    problems = model_files.model_problems(models_dir(), shared_dir() / "models", size)
    return problems + onnx_session.device_problems(get_settings().device)


def device_probe() -> list[str]:
    """With ``GEOLOC_DEVICE=cuda``, open the segmentation network on it: why it cannot run there, else [].

    What :func:`model_problems` cannot see without a session: the CUDA provider is installed but a session does
    not get it (no GPU, no driver). Only in a process that runs jobs itself (``python -m workers``): the session
    stays cached for its jobs; a parent that forks workers (Celery's prefork) must not open CUDA before the fork.
    """
    if get_settings().device != "cuda":
        return []
    # The segmentation module pulls OpenCV: only a worker about to run jobs probes.
    from geoloc.vision.segmentation import load_session

    try:
        load_session(method_context())
    except onnx_session.DeviceUnavailableError as exc:
        return [str(exc)]
    return []


MODEL_FREE_KINDS = (LOAD_MAP,)
"""Job kinds whose handlers need no built models (a map's parse)."""


def runs_method_jobs(kinds: Sequence[str]) -> bool:
    """Whether a worker claiming ``kinds`` (empty: every kind) runs the method's jobs (queries, references).

    A worker that claims only model-free kinds (``serve --workers 0``'s map parser) does not.
    """
    return not kinds or any(kind not in MODEL_FREE_KINDS for kind in kinds)


def needs_models(settings: Settings) -> bool:
    """Whether this process's workers run the method's jobs: all do, but those that claim only model-free kinds."""
    return runs_method_jobs(settings.worker_kinds)
