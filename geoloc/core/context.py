"""What the method needs from its surroundings, passed in whole: threads, the device and where the built models are.

The method never reads the settings; its caller builds one :class:`MethodContext` (the workers once per
process from the settings, :mod:`workers.context`; the command line likewise) and hands it to the stage
entries (:func:`geoloc.vision.evidence.analyze_photo`, :func:`geoloc.localize.reference.label_reference_photo`,
:func:`geoloc.localize.query.geolocate`) and the model factories
(:func:`geoloc.vision.segmentation.load_session`, :func:`geoloc.vision.aliked.load_runtime`). Answers do not
depend on the thread counts, nor on the device beyond floating-point rounding (a GPU's kernels sum in another
order); they do depend on the segmentation network's size.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from geoloc.core.parallel import JobThreads

Device = Literal["auto", "cpu", "cuda"]
"""Where the networks run (``GEOLOC_DEVICE``; :mod:`geoloc.vision.onnx_session` picks the providers)."""
DEVICES: tuple[Device, ...] = ("auto", "cpu", "cuda")


@dataclass(frozen=True)
class MethodContext:
    """The method's surroundings.

    models_dir: the folder ``geoloc models build`` writes the ONNX networks, their metadata and the SBoW
    vocabularies into (:mod:`geoloc.vision.model_files`). threads: one job's threads for its independent
    parts (:class:`geoloc.core.parallel.JobThreads`). onnx_threads: onnxruntime intra-op threads of the
    networks (segmentation, ALIKED; they wait without spinning). device: where the networks run, ``cpu``,
    ``cuda`` or ``auto`` (CUDA when onnxruntime can use a GPU here, else CPU; :mod:`geoloc.vision.onnx_session`).
    segmentation_size: the segmentation network's input (W, H), None for the method's default
    (:data:`geoloc.vision.model_files.SEG_DEFAULT_SIZE`); answers depend on it.
    """

    models_dir: Path
    threads: JobThreads = field(default_factory=JobThreads)
    onnx_threads: int = 1
    device: Device = "cpu"
    segmentation_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        """ValueError unless ``onnx_threads`` >= 1 and ``device`` is one of :data:`DEVICES`."""
        if self.onnx_threads < 1:
            raise ValueError(f"onnx_threads must be at least 1, got {self.onnx_threads}")
        if self.device not in DEVICES:
            raise ValueError(f"device must be one of {', '.join(DEVICES)}, got {self.device!r}")
