"""The one onnxruntime session factory of the networks (segmentation, ALIKED): CPU or CUDA, threads that do not spin.

The device is the caller's choice (:attr:`geoloc.core.context.MethodContext.device`, from ``GEOLOC_DEVICE``):

- ``cpu``: ``CPUExecutionProvider`` only, the session the method always had (the answers' reference);
- ``cuda``: ``CUDAExecutionProvider`` first, the CPU provider for the operators CUDA lacks; a
  :class:`DeviceUnavailableError` naming what is missing when onnxruntime has no CUDA provider (the CPU-only
  ``onnxruntime`` wheel is installed, not ``geoloc[gpu]``) or a session does not get it (no GPU, no driver,
  CUDA/cuDNN libraries missing: onnxruntime then silently falls back to the CPU, which we refuse);
- ``auto``: CUDA when the provider is there and a session gets it, else CPU without complaint; the first
  session of a process logs at info which device it runs on.

:func:`session_device` says which device a session actually runs on, :func:`used_device` which one this process's
networks got (a query answer's ``search.device``).
"""

from __future__ import annotations

import logging
from functools import lru_cache
from typing import TYPE_CHECKING

from geoloc.core.context import DEVICES, Device

if TYPE_CHECKING:
    import onnxruntime as ort

log = logging.getLogger(__name__)

CPU_PROVIDER = "CPUExecutionProvider"
CUDA_PROVIDER = "CUDAExecutionProvider"
GPU_HELP = (
    "install the GPU build of onnxruntime (pip uninstall onnxruntime && pip install 'geoloc[gpu]'), "
    "and run on a machine with an NVIDIA GPU, its driver and the CUDA/cuDNN libraries onnxruntime-gpu needs; "
    "or set GEOLOC_DEVICE=cpu (or auto)"
)
_logged: list[Device] = []
"""The device the first session of this process got (logged once)."""


class DeviceUnavailableError(RuntimeError):
    """``GEOLOC_DEVICE=cuda`` but onnxruntime cannot run on a GPU here; the message says what is missing."""


def available_providers() -> list[str]:
    """The execution providers of onnxruntime in this environment (``onnxruntime.get_available_providers()``)."""
    # onnxruntime takes a while to import: only a process that runs a network (or checks its device) pays for it.
    import onnxruntime as ort

    return list(ort.get_available_providers())


def device_problems(device: Device) -> list[str]:
    """Why ``device`` cannot be used here without opening a network: [] for ``cpu`` and ``auto``.

    For ``cuda``, the missing CUDA provider (the check a worker makes before it starts; a session that still
    falls back to the CPU, no GPU or no driver, raises :class:`DeviceUnavailableError` when it is opened).
    """
    if device not in DEVICES:
        return [f"unknown device {device!r}; expected one of {', '.join(DEVICES)}"]
    if device != "cuda" or CUDA_PROVIDER in available_providers():
        return []
    have = ", ".join(available_providers())
    return [f"GEOLOC_DEVICE=cuda but onnxruntime has no {CUDA_PROVIDER} (only {have}); {GPU_HELP}"]


def session_device(session: ort.InferenceSession) -> Device:
    """``cuda`` when the session runs on the CUDA provider, else ``cpu``."""
    return "cuda" if CUDA_PROVIDER in session.get_providers() else "cpu"


def used_device(requested: Device) -> Device:
    """The device this process's networks run on: the first session's; before any, ``requested`` (``auto``: cpu)."""
    if _logged:
        return _logged[0]
    return "cpu" if requested == "auto" else requested


def _options(threads: int) -> ort.SessionOptions:
    import onnxruntime as ort  # see available_providers

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return options


@lru_cache(maxsize=8)
def onnx_session(path: str, threads: int, device: Device = "cpu") -> ort.InferenceSession:
    """The onnxruntime session of the ONNX file at ``path`` on ``device``, cached per process.

    threads: intra-op threads (the CPU provider's; idle threads sleep instead of spinning: with the pool's
    processes on every core, spinning threads burn the CPU another job needs). ``cpu`` gives exactly the
    CPU-only session; ``cuda`` and ``auto`` as the module says.

    Raises
    ------
    DeviceUnavailableError
        ``device`` is ``cuda`` and onnxruntime lacks the CUDA provider or the session did not get it.
    ValueError
        ``device`` is not one of :data:`geoloc.core.context.DEVICES`.
    """
    import onnxruntime as ort  # see available_providers

    if device not in DEVICES:
        raise ValueError(f"unknown device {device!r}; expected one of {', '.join(DEVICES)}")
    if problems := device_problems(device):
        raise DeviceUnavailableError(problems[0])
    if device == "cpu" or CUDA_PROVIDER not in available_providers():
        session = ort.InferenceSession(path, _options(threads), providers=[CPU_PROVIDER])
    else:
        session = ort.InferenceSession(path, _options(threads), providers=[CUDA_PROVIDER, CPU_PROVIDER])
        if device == "cuda" and session_device(session) != "cuda":
            raise DeviceUnavailableError(
                f"GEOLOC_DEVICE=cuda but the onnxruntime session of {path} did not get the {CUDA_PROVIDER} "
                f"(it has {', '.join(session.get_providers())}: no usable GPU, driver or CUDA libraries); " + GPU_HELP
            )
    if not _logged:
        _logged.append(session_device(session))
        log.info("onnxruntime runs the networks on %s (GEOLOC_DEVICE=%s)", _logged[0], device)
    return session
