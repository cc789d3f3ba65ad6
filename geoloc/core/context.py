"""What the method needs from its surroundings, passed in whole: threads and where the built models are.

The method never reads the settings; its caller builds one :class:`MethodContext` (the workers once per
process from the settings, :mod:`workers.context`; the command line likewise) and hands it to the stage
entries (:func:`geoloc.vision.evidence.analyze_photo`, :func:`geoloc.localize.reference.label_reference_photo`,
:func:`geoloc.localize.query.geolocate`) and the model factories
(:func:`geoloc.vision.segmentation.load_session`, :func:`geoloc.vision.aliked.load_runtime`). Answers do not
depend on the thread counts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from geoloc.core.parallel import JobThreads


@dataclass(frozen=True)
class MethodContext:
    """The method's surroundings.

    models_dir: the folder ``geoloc models build`` writes the ONNX networks, their metadata and the SBoW
    vocabularies into (:mod:`geoloc.vision.model_files`). threads: one job's threads for its independent
    parts (:class:`geoloc.core.parallel.JobThreads`). onnx_threads: onnxruntime intra-op threads of the
    networks (segmentation, ALIKED; they wait without spinning).
    """

    models_dir: Path
    threads: JobThreads = field(default_factory=JobThreads)
    onnx_threads: int = 1

    def __post_init__(self) -> None:
        """ValueError unless ``onnx_threads`` >= 1."""
        if self.onnx_threads < 1:
            raise ValueError(f"onnx_threads must be at least 1, got {self.onnx_threads}")
