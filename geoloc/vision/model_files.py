"""The built models as the runtime sees them: where their files are, what their metadata says, whether current.

``geoloc models build`` (:mod:`geoloc.export`, PyTorch) writes into one models folder (the caller's
``MethodContext.models_dir``; the settings put it at ``DATA_DIR/cache/models``):

- the segmentation network (ESPNetv2 s=2.0, Cityscapes): ``espnetv2_s2_city_<W>x<H>.onnx`` and its
  ``.json`` metadata (the weights' sha256, :data:`EXPORT_VERSION`). Graph: input ``image`` (1, 3, H, W)
  float32 RGB 0..255; output ``logits`` (1, 20, H/2, W/2) float32 in Cityscapes trainId order (19 = void).
- ALIKED (``aliked-n16``, ``aliked-t16``): ``<config>.onnx`` (the dense part: input ``image`` (1, 3, H, W)
  float32 RGB 0..255, H and W multiples of 32; outputs ``score`` and ``level1..4``), ``<config>_head.npz``
  (the descriptor head's float32 weights, run in numpy by :mod:`geoloc.vision.aliked`) and ``<config>.json``.
- the SBoW vocabularies: ``sbow_vocabulary_<feature type>_<words>.npz`` (:mod:`geoloc.localize.retrieval`).

This module only reads; the export imports it (the same names, so models built before stay current) and
the runtime never imports the export.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.vision.feature_types import canonical_method

SEG_WEIGHTS = "espnetv2_s_2.0_city_1024x512.pth"
"""The published ESPNetv2 Cityscapes weights' file name (in the shared folder's ``models``)."""
SEG_SCALE = 2.0
SEG_CLASSES = 20
# Network input size (W, H) used by default; chosen by measuring accuracy against time on CamVid
# (table in geoloc/vision/segmentation.py). Multiples of 16.
SEG_DEFAULT_SIZE: tuple[int, int] = (768, 384)
OUTPUT_STRIDE = 2  # the graph returns logits at 1/2 of the input size
EXPORT_VERSION = 1  # bump when the export recipe changes, to force a rebuild
ALIKED_EXPORT_VERSION = 1  # bump when the ALIKED export recipe changes
ALIKED_CONFIG_NAMES = ("aliked-n16", "aliked-t16")
DEFAULT_WORDS = 4096
"""Words of the default SBoW vocabulary."""
BUILD_HINT = "run `geoloc models build` (needs the export extra: pip install -e '.[export]')"


@dataclass(frozen=True)
class SegModelFiles:
    """Where a segmentation export lives: the ONNX file and its JSON metadata."""

    onnx: Path
    meta: Path


@dataclass(frozen=True)
class AlikedModelFiles:
    """Where an ALIKED export lives: the dense ONNX graph, the descriptor head's weights, the metadata."""

    onnx: Path
    head: Path
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


def segmentation_files(models_dir: Path, size: tuple[int, int] | None = None) -> SegModelFiles:
    """Paths of the ONNX export for network input ``size`` = (W, H) (default ``SEG_DEFAULT_SIZE``)."""
    w, h = size or SEG_DEFAULT_SIZE
    stem = f"espnetv2_s{SEG_SCALE:g}_city_{w}x{h}"
    return SegModelFiles(onnx=models_dir / f"{stem}.onnx", meta=models_dir / f"{stem}.json")


def aliked_files(models_dir: Path, config_name: str) -> AlikedModelFiles:
    """Paths of the ALIKED export of ``config_name`` ("aliked-n16" or "aliked-t16"); ValueError for others."""
    if config_name not in ALIKED_CONFIG_NAMES:
        raise ValueError(f"unknown ALIKED config {config_name!r}; known: {', '.join(ALIKED_CONFIG_NAMES)}")
    stem = models_dir / config_name
    return AlikedModelFiles(
        stem.with_suffix(".onnx"), models_dir / f"{config_name}_head.npz", stem.with_suffix(".json")
    )


def vocabulary_path(models_dir: Path, n_words: int = DEFAULT_WORDS, method: str | None = None) -> Path:
    """Where the default SBoW vocabulary of feature type ``method`` (None: the default type) with ``n_words`` is."""
    return models_dir / f"sbow_vocabulary_{canonical_method(method)}_{n_words}.npz"


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_meta(files: SegModelFiles | AlikedModelFiles) -> dict[str, Any] | None:
    """An export's JSON metadata, or None if missing/unreadable."""
    try:
        meta = json.loads(files.meta.read_text())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) else None


def is_current(files: SegModelFiles, weights_sha256: str) -> bool:
    """True if the segmentation ONNX exists and was exported from these weights with this recipe."""
    meta = read_meta(files)
    return (
        files.onnx.exists()
        and meta is not None
        and meta.get("weights_sha256") == weights_sha256
        and meta.get("export_version") == EXPORT_VERSION
    )


def aliked_is_current(files: AlikedModelFiles, weights_sha256: str) -> bool:
    """True if the ALIKED export exists and was made from these weights with this recipe."""
    meta = read_meta(files)
    return (
        files.onnx.exists()
        and files.head.exists()
        and meta is not None
        and meta.get("weights_sha256") == weights_sha256
        and meta.get("export_version") == ALIKED_EXPORT_VERSION
    )


def model_problems(models_dir: Path, weights_dir: Path | None = None, size: tuple[int, int] | None = None) -> list[str]:
    """What is wrong with the built models the workers need; empty when all are present and current.

    Checked: the segmentation ONNX for network input ``size`` (default ``SEG_DEFAULT_SIZE``) in
    ``models_dir`` exists; its JSON metadata exists and records this export recipe (``EXPORT_VERSION``) and,
    when the weights are in ``weights_dir`` (the shared folder's ``models``), their sha256 (a mismatch means
    the weights changed since the export); the default SBoW vocabulary exists and opens. ``geoloc serve``,
    ``geoloc worker`` and the worker processes refuse to start on any of these, and ``/readyz`` lists them.

    Returns
    -------
    list[str]
        One sentence per problem, each saying how to fix it.
    """
    files = segmentation_files(models_dir, size)
    problems = []
    meta = read_meta(files)
    if not files.onnx.exists():
        problems.append(f"segmentation model not found at {files.onnx}; {BUILD_HINT}")
    elif meta is None or meta.get("export_version") != EXPORT_VERSION:
        problems.append(f"segmentation model {files.onnx} is stale (export recipe changed); {BUILD_HINT} --force")
    else:
        weights = None if weights_dir is None else weights_dir / SEG_WEIGHTS
        if weights is not None and not weights.exists():
            weights = None  # nothing to compare with: the recorded export stands
        if weights is not None and meta.get("weights_sha256") != sha256_file(weights):
            problems.append(
                f"segmentation model {files.onnx} is stale: it was exported from other weights than {weights}; "
                f"{BUILD_HINT} --force"
            )
    vocabulary = vocabulary_path(models_dir)
    try:
        with np.load(vocabulary, allow_pickle=False) as npz:
            npz.files  # noqa: B018 - reads the archive's directory: a truncated file fails here
    except FileNotFoundError:
        problems.append(f"SBoW vocabulary not found at {vocabulary}; {BUILD_HINT}")
    except (OSError, ValueError) as exc:
        problems.append(f"SBoW vocabulary {vocabulary} is unreadable ({exc}); delete it and {BUILD_HINT}")
    return problems
