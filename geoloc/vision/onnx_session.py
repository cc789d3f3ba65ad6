"""The one onnxruntime session factory of the networks (segmentation, ALIKED): CPU, threads that do not spin."""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import onnxruntime as ort


@lru_cache(maxsize=8)
def cpu_session(path: str, threads: int) -> ort.InferenceSession:
    """The onnxruntime CPU session of the ONNX file at ``path`` with ``threads`` intra-op threads, cached per process.

    Idle threads sleep instead of spinning: with the pool's processes on every core, spinning threads burn
    the CPU another job needs.
    """
    # onnxruntime takes a while to import: only a process that runs a network pays for it.
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])
