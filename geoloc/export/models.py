"""Exported models: build the networks' ONNX files in the cache, outside git.

``build_segmentation_model`` reads the published ESPNetv2 Cityscapes weights from the shared
folder (``GEOLOC_SHARED/models``), exports them to ONNX with a fixed input size into
``contracts.settings.cache_dir()/models/`` and writes a JSON beside it with the weights' sha256; the
export is redone when that hash (or the export recipe version) changes, or with ``force``.
Only this path imports torch (lazily, inside ``_export``); install it with the ``export`` extra.

The ONNX graph: input ``image`` (1, 3, H, W) float32 RGB in 0..255 (normalisation is inside the
graph); output ``logits`` (1, 20, H/2, W/2) float32 in Cityscapes trainId order (19 = void).

``build_aliked_model`` does the same for the ALIKED local-feature network (``aliked-n16``,
``aliked-t16``, :mod:`geoloc.export.nets.aliked`): ``<config>.onnx`` is the dense part (input ``image``
(1, 3, H, W) float32 RGB 0..255, H and W any multiples of 32; outputs ``score`` and ``level1..4``),
``<config>_head.npz`` the sparse descriptor head's weights as float32 arrays (the head runs in numpy,
:mod:`geoloc.vision.aliked`), and ``<config>.json`` the metadata with the weights' sha256.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from contracts import settings as config

SEG_WEIGHTS = "espnetv2_s_2.0_city_1024x512.pth"
SEG_SCALE = 2.0
SEG_CLASSES = 20
# Network input size (W, H) used by default; chosen by measuring accuracy against time on CamVid
# (table in geoloc/vision/segmentation.py). Multiples of 16.
SEG_DEFAULT_SIZE: tuple[int, int] = (768, 384)
OUTPUT_STRIDE = 2  # the graph returns logits at 1/2 of the input size
EXPORT_VERSION = 1  # bump when the export recipe changes, to force a rebuild
OPSET = 17
ALIKED_EXPORT_VERSION = 1  # bump when the ALIKED export recipe changes
ALIKED_CONFIG_NAMES = ("aliked-n16", "aliked-t16")


@dataclass(frozen=True)
class SegModelFiles:
    """Where a segmentation export lives: the ONNX file and its JSON metadata."""

    onnx: Path
    meta: Path


def parse_size(text: str) -> tuple[int, int]:
    """'768x384' -> (768, 384); both multiples of 16 and at least 64, else ValueError."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise ValueError(f"size must look like WxH (e.g. 768x384), got {text!r}") from exc
    check_size((w, h))
    return w, h


def check_size(size: tuple[int, int]) -> None:
    """Raise ValueError unless (W, H) are multiples of 16 and at least 64."""
    w, h = size
    if w % 16 or h % 16 or w < 64 or h < 64:
        raise ValueError(f"network size must be multiples of 16 and >= 64, got {w}x{h}")


def segmentation_files(size: tuple[int, int] | None = None) -> SegModelFiles:
    """Paths of the ONNX export for network input ``size`` = (W, H) (default ``SEG_DEFAULT_SIZE``)."""
    w, h = size or SEG_DEFAULT_SIZE
    stem = f"espnetv2_s{SEG_SCALE:g}_city_{w}x{h}"
    folder = config.cache_dir() / "models"
    return SegModelFiles(onnx=folder / f"{stem}.onnx", meta=folder / f"{stem}.json")


def weights_path() -> Path:
    """The shared ESPNetv2 weights file (FileNotFoundError with a hint if absent)."""
    return config.shared_path("models", SEG_WEIGHTS)


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_meta(files: SegModelFiles) -> dict[str, Any] | None:
    """The export's JSON metadata, or None if missing/unreadable."""
    try:
        meta = json.loads(files.meta.read_text())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) else None


def is_current(files: SegModelFiles, weights_sha256: str) -> bool:
    """True if the ONNX exists and was exported from these weights with this recipe."""
    meta = read_meta(files)
    return (
        files.onnx.exists()
        and meta is not None
        and meta.get("weights_sha256") == weights_sha256
        and meta.get("export_version") == EXPORT_VERSION
    )


def build_segmentation_model(force: bool = False, size: tuple[int, int] | None = None) -> Path:
    """Export ESPNetv2 (s=2.0, Cityscapes) to ONNX in the cache unless an up-to-date export exists.

    Parameters
    ----------
    force
        Re-export even if the cached file matches the weights.
    size
        Network input (W, H), multiples of 16; default ``SEG_DEFAULT_SIZE``.

    Returns
    -------
    Path
        The ONNX file.
    """
    size = size or SEG_DEFAULT_SIZE
    check_size(size)
    files = segmentation_files(size)
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


@dataclass(frozen=True)
class AlikedModelFiles:
    """Where an ALIKED export lives: the dense ONNX graph, the descriptor head's weights, the metadata."""

    onnx: Path
    head: Path
    meta: Path


def aliked_files(config_name: str) -> AlikedModelFiles:
    """Paths of the ALIKED export of ``config_name`` ("aliked-n16" or "aliked-t16") in the cache."""
    if config_name not in ALIKED_CONFIG_NAMES:
        raise ValueError(f"unknown ALIKED config {config_name!r}; known: {', '.join(ALIKED_CONFIG_NAMES)}")
    folder = config.cache_dir() / "models"
    stem = folder / config_name
    return AlikedModelFiles(stem.with_suffix(".onnx"), folder / f"{config_name}_head.npz", stem.with_suffix(".json"))


def aliked_weights_path(config_name: str) -> Path:
    """The shared ALIKED weights of a config (FileNotFoundError with a hint if absent)."""
    return config.shared_path("models", f"{config_name}.pth")


def aliked_is_current(files: AlikedModelFiles, weights_sha256: str) -> bool:
    """True if the ALIKED export exists and was made from these weights with this recipe."""
    try:
        meta = json.loads(files.meta.read_text())
    except (OSError, ValueError):
        return False
    return (
        files.onnx.exists()
        and files.head.exists()
        and meta.get("weights_sha256") == weights_sha256
        and meta.get("export_version") == ALIKED_EXPORT_VERSION
    )


def build_aliked_model(config_name: str = "aliked-n16", force: bool = False) -> AlikedModelFiles:
    """Export ALIKED ``config_name`` to the cache (ONNX dense graph + head weights) unless up to date.

    Parameters
    ----------
    config_name
        "aliked-n16" (128-D descriptors) or "aliked-t16" (64-D).
    force
        Re-export even if the cached files match the weights.

    Returns
    -------
    AlikedModelFiles
        The exported files.
    """
    files = aliked_files(config_name)
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

def model_problems(size: tuple[int, int] | None = None) -> list[str]:
    """What is wrong with the built models the workers need; empty when all are present and current.

    Checked: the segmentation ONNX for network input ``size`` (default ``SEG_DEFAULT_SIZE``) exists;
    its JSON metadata exists and records this export recipe (``EXPORT_VERSION``) and, when the shared
    weights are present, their sha256 (a mismatch means the weights changed since the export); the
    SBoW vocabulary exists and opens. ``geoloc serve``, ``geoloc worker`` and the worker processes
    refuse to start on any of these, and ``/readyz`` lists them.

    Returns
    -------
    list[str]
        One sentence per problem, each saying how to fix it.
    """
    import numpy as np

    from geoloc.localize.retrieval import vocabulary_path

    fix = "run `geoloc models build` (needs the export extra: pip install -e '.[export]')"
    files = segmentation_files(size)
    problems = []
    meta = read_meta(files)
    if not files.onnx.exists():
        problems.append(f"segmentation model not found at {files.onnx}; {fix}")
    elif meta is None or meta.get("export_version") != EXPORT_VERSION:
        problems.append(f"segmentation model {files.onnx} is stale (export recipe changed); {fix} --force")
    else:
        try:
            weights = weights_path()
        except FileNotFoundError:
            weights = None  # nothing to compare with: the recorded export stands
        if weights is not None and meta.get("weights_sha256") != sha256_file(weights):
            problems.append(
                f"segmentation model {files.onnx} is stale: it was exported from other weights than {weights}; "
                f"{fix} --force"
            )
    vocabulary = vocabulary_path()
    try:
        with np.load(vocabulary, allow_pickle=False) as npz:
            npz.files  # noqa: B018 - reads the archive's directory: a truncated file fails here
    except FileNotFoundError:
        problems.append(f"SBoW vocabulary not found at {vocabulary}; {fix}")
    except (OSError, ValueError) as exc:
        problems.append(f"SBoW vocabulary {vocabulary} is unreadable ({exc}); delete it and {fix}")
    return problems
