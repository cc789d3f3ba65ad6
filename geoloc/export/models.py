"""Exported models: build the networks' ONNX files in the models folder, outside git (needs torch).

``build_segmentation_model`` reads the published ESPNetv2 Cityscapes weights from the shared
folder (``GEOLOC_SHARED/models``), exports them to ONNX with a fixed input size into the models folder
(default: the settings', ``contracts.settings.models_dir()``) and writes a JSON beside it with the weights'
sha256; the export is redone when that hash (or the export recipe version) changes, or with ``force``.
Only this package imports torch (lazily, inside the exports); install it with the ``export`` extra.

``build_aliked_model`` does the same for the ALIKED local-feature network (``aliked-n16``,
``aliked-t16``, :mod:`geoloc.export.nets.aliked`). The files, their graphs and metadata are described in
:mod:`geoloc.vision.model_files`, the runtime's view of them, which this module uses for the paths and the
currency checks (so the runtime never imports the export).
"""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path
from typing import Any

from contracts import settings as config
from geoloc.vision.model_files import (
    ALIKED_EXPORT_VERSION,
    EXPORT_VERSION,
    OUTPUT_STRIDE,
    SEG_CLASSES,
    SEG_DEFAULT_SIZE,
    SEG_SCALE,
    SEG_WEIGHTS,
    AlikedModelFiles,
    aliked_files,
    aliked_is_current,
    check_size,
    is_current,
    segmentation_files,
    sha256_file,
)

OPSET = 17


def weights_path() -> Path:
    """The shared ESPNetv2 weights file (FileNotFoundError with a hint if absent)."""
    return config.shared_path("models", SEG_WEIGHTS)


def build_segmentation_model(
    force: bool = False, size: tuple[int, int] | None = None, models_dir: Path | None = None
) -> Path:
    """Export ESPNetv2 (s=2.0, Cityscapes) to ONNX in the cache unless an up-to-date export exists.

    Parameters
    ----------
    force
        Re-export even if the cached file matches the weights.
    size
        Network input (W, H), multiples of 16; default ``SEG_DEFAULT_SIZE``.
    models_dir
        Where to write; default the settings' models folder.

    Returns
    -------
    Path
        The ONNX file.
    """
    size = size or SEG_DEFAULT_SIZE
    check_size(size)
    files = segmentation_files(models_dir or config.models_dir(), size)
    weights = weights_path()
    sha = sha256_file(weights)
    if not force and is_current(files, sha):
        return files.onnx
    files.onnx.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    tmp = files.onnx.with_suffix(f".tmp{os.getpid()}.onnx")
    try:
        versions = _export(weights, tmp, size)
        os.replace(tmp, files.onnx)
    finally:
        tmp.unlink(missing_ok=True)
    meta = {
        "weights": SEG_WEIGHTS,
        "weights_sha256": sha,
        "scale": SEG_SCALE,
        "input": {"name": "image", "shape": [1, 3, size[1], size[0]], "format": "RGB float 0..255"},
        "output": {
            "name": "logits",
            "shape": [1, SEG_CLASSES, size[1] // 2, size[0] // 2],
            "classes": "cityscapes trainId 0..18, 19 void",
        },
        "output_stride": OUTPUT_STRIDE,
        "export_version": EXPORT_VERSION,
        "opset": OPSET,
        "export_seconds": round(time.perf_counter() - t0, 2),
        **versions,
    }
    files.meta.write_text(json.dumps(meta, indent=2) + "\n")
    return files.onnx


def _export(weights: Path, out: Path, size: tuple[int, int]) -> dict[str, str]:
    """Load the weights strictly, trace at ``size`` and write ONNX to ``out``; returns versions."""
    try:
        import torch

        # The networks import torch, a heavy optional dependency (the export extra): only when exporting.
        from geoloc.export.nets.espnetv2 import NormalizedSegmenter, load_espnetv2
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise RuntimeError("exporting the segmentation model needs torch: pip install -e '.[export]'") from exc
    net = load_espnetv2(weights, s=SEG_SCALE, classes=SEG_CLASSES)
    net.set_static_ops(True)
    net.full_resolution = False
    model = NormalizedSegmenter(net).eval()
    # Shapes are Python ints on purpose: the graph has a fixed input size.
    _trace_to_onnx(model, torch.zeros(1, 3, size[1], size[0]), out, ["logits"])
    return {"torch": torch.__version__}


def _trace_to_onnx(
    model: Any, dummy: Any, out: Path, outputs: list[str], dynamic_axes: dict[str, dict[int, str]] | None = None
) -> None:
    """Trace ``model`` on ``dummy`` (input ``image``) with the legacy exporter and write ONNX to ``out``."""
    import torch

    with torch.no_grad(), warnings.catch_warnings():
        # torch.jit re-exports TracerWarning (from torch.jit._trace) without listing it in __all__.
        warnings.simplefilter("ignore", torch.jit.TracerWarning)  # type: ignore[attr-defined]
        warnings.simplefilter("ignore", DeprecationWarning)  # the legacy exporter is what we want
        torch.onnx.export(
            model,
            (dummy,),
            str(out),
            input_names=["image"],
            output_names=outputs,
            dynamic_axes=dynamic_axes,
            opset_version=OPSET,
            dynamo=False,
            do_constant_folding=True,
        )


# ----------------------------------------------------------------------------------------------
# ALIKED


def aliked_weights_path(config_name: str) -> Path:
    """The shared ALIKED weights of a config (FileNotFoundError with a hint if absent)."""
    return config.shared_path("models", f"{config_name}.pth")


def build_aliked_model(
    config_name: str = "aliked-n16", force: bool = False, models_dir: Path | None = None
) -> AlikedModelFiles:
    """Export ALIKED ``config_name`` to the cache (ONNX dense graph + head weights) unless up to date.

    Parameters
    ----------
    config_name
        "aliked-n16" (128-D descriptors) or "aliked-t16" (64-D).
    force
        Re-export even if the cached files match the weights.
    models_dir
        Where to write; default the settings' models folder.

    Returns
    -------
    AlikedModelFiles
        The exported files.
    """
    files = aliked_files(models_dir or config.models_dir(), config_name)
    weights = aliked_weights_path(config_name)
    sha = sha256_file(weights)
    if not force and aliked_is_current(files, sha):
        return files
    files.onnx.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    tmp_onnx = files.onnx.with_suffix(f".tmp{os.getpid()}.onnx")
    tmp_head = files.head.with_suffix(f".tmp{os.getpid()}.npz")
    try:
        versions, info = _export_aliked(weights, config_name, tmp_onnx, tmp_head)
        os.replace(tmp_onnx, files.onnx)
        os.replace(tmp_head, files.head)
    finally:
        tmp_onnx.unlink(missing_ok=True)
        tmp_head.unlink(missing_ok=True)
    meta = {
        "config": config_name,
        "weights": weights.name,
        "weights_sha256": sha,
        **info,
        "input": {"name": "image", "shape": [1, 3, "H", "W"], "format": "RGB float 0..255, H and W multiples of 32"},
        "outputs": ["score", "level1", "level2", "level3", "level4"],
        "export_version": ALIKED_EXPORT_VERSION,
        "opset": OPSET,
        "export_seconds": round(time.perf_counter() - t0, 2),
        **versions,
    }
    files.meta.write_text(json.dumps(meta, indent=2) + "\n")
    return files


def _export_aliked(
    weights: Path, config_name: str, onnx_out: Path, head_out: Path
) -> tuple[dict[str, str], dict[str, int]]:
    """Load the weights strictly, export the dense graph (dynamic H, W) and save the head's weights."""
    try:
        import numpy as np
        import torch

        # The networks import torch, a heavy optional dependency (the export extra): only when exporting.
        from geoloc.export.nets.aliked import AlikedDense, load_aliked
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise RuntimeError("exporting ALIKED needs torch: pip install -e '.[export]'") from exc
    net = load_aliked(weights, config_name)
    model = AlikedDense(net).eval()
    outputs = ["score", "level1", "level2", "level3", "level4"]
    dynamic = {"image": {2: "height", 3: "width"}, **{name: {2: f"{name}_h", 3: f"{name}_w"} for name in outputs}}
    _trace_to_onnx(model, torch.zeros(1, 3, 64, 96), onnx_out, outputs, dynamic)
    head = {name: p.detach().numpy().astype(np.float32) for name, p in net.desc_head.state_dict().items()}
    with head_out.open("wb") as fh:
        np.savez(fh, **head)
    cfg = net.config
    info = {"descriptor_dim": cfg.dim, "sddh_kernel": cfg.kernel, "sddh_samples": cfg.n_samples}
    return {"torch": torch.__version__}, info
