"""ALIKED keypoints and descriptors at run time: onnxruntime for the dense network, numpy for the rest.

The network (:mod:`geoloc.export.nets.aliked`, exported by ``geoloc models build`` into the models folder,
:mod:`geoloc.vision.model_files`) gives a keypoint score map and four feature levels. Everything after it runs
here, vectorised over keypoints (no torch):

1. :func:`dense_maps`: the RGB image is padded to multiples of 32 (edge pixels replicated, split
   evenly between the sides), run through the ONNX graph, and the score map is cropped back.
2. :func:`detect_keypoints`: local maxima of the score map (radius-2 NMS with the reference's
   two-pass suppression, 2-pixel border dropped, optionally only inside an ``allowed`` mask), the
   ``max_keypoints`` strongest, each refined to sub-pixel by the soft-argmax (temperature 0.1) of its
   5x5 neighbourhood; its score is the score map read bilinearly there.
3. :func:`geoloc.vision.aliked_head.describe`: the sparse deformable descriptor head (SDDH), in its own
   module.

Positions are (x, y) pixel centres of the input image (OpenCV's convention: pixel i spans
[i - 0.5, i + 0.5]). :func:`aliked_keypoints` does the three steps, optionally on an image pyramid;
``geoloc.vision.features`` wraps it into the project's :class:`~geoloc.vision.features.Features` (building mask,
working resolution).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import cv2
import numpy as np

from geoloc.core.context import Device, MethodContext
from geoloc.vision.aliked_head import DenseMaps, SddhWeights, describe
from geoloc.vision.model_files import aliked_files
from geoloc.vision.onnx_session import onnx_session

PAD_MULTIPLE = 32
NMS_RADIUS = 2
SOFTARGMAX_TEMPERATURE = 0.1


class AlikedNotBuiltError(FileNotFoundError):
    """The ALIKED export is missing; the message says how to build it."""


@dataclass
class AlikedRuntime:
    """A loaded ALIKED export: the onnxruntime session of the dense graph and the head's weights."""

    config_name: str
    session: Any
    head: SddhWeights

    @property
    def descriptor_dim(self) -> int:
        """D, the descriptor length (128 for n16, 64 for t16)."""
        return self.head.descriptor_dim


@lru_cache(maxsize=4)
def _cached_runtime(onnx_path: str, head_path: str, config_name: str, threads: int, device: Device) -> AlikedRuntime:
    session = onnx_session(onnx_path, threads, device)
    with np.load(head_path, allow_pickle=False) as data:
        head = SddhWeights.from_state({k: data[k] for k in data.files})
    return AlikedRuntime(config_name, session, head)


def load_runtime(context: MethodContext, config_name: str = "aliked-n16") -> AlikedRuntime:
    """Return the ALIKED runtime of ``config_name`` ("aliked-n16" or "aliked-t16"), cached per process.

    Parameters
    ----------
    context
        Where the built models are (``models_dir``), the onnxruntime intra-op threads (``onnx_threads``) and the
        device the network runs on (``device``; a ``cuda`` one that is not here raises
        :class:`geoloc.vision.onnx_session.DeviceUnavailableError`).
    config_name
        Which export.

    Raises
    ------
    AlikedNotBuiltError
        The export is not in the models folder.
    """
    files = aliked_files(context.models_dir, config_name)
    if not (files.onnx.exists() and files.head.exists()):
        raise AlikedNotBuiltError(
            f"ALIKED model {config_name} not found at {files.onnx}; build it once with `geoloc models build` "
            "(needs the export extra: pip install -e '.[export]')"
        )
    return _cached_runtime(str(files.onnx), str(files.head), config_name, context.onnx_threads, context.device)


# ----------------------------------------------------------------------------------------------
# Dense maps


def padding_for(size_hw: tuple[int, int], multiple: int = PAD_MULTIPLE) -> tuple[tuple[int, int], tuple[int, int]]:
    """((top, bottom), (left, right)) padding that brings (H, W) to multiples of ``multiple`` (at least 2x)."""
    out = []
    for n in size_hw:
        target = max(2 * multiple, -(-n // multiple) * multiple)
        extra = target - n
        out.append((extra // 2, extra - extra // 2))
    return out[0], out[1]


def dense_maps(runtime: AlikedRuntime, image_rgb: np.ndarray) -> DenseMaps:
    """Run the dense network on an (h, w, 3) uint8 RGB image (see :class:`DenseMaps`)."""
    img = np.asarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) RGB image, got shape {img.shape}")
    h, w = img.shape[:2]
    (top, bottom), (left, right) = padding_for((h, w))
    padded = np.pad(img, ((top, bottom), (left, right), (0, 0)), mode="edge")
    x = np.ascontiguousarray(padded.transpose(2, 0, 1)[None], dtype=np.float32)
    outputs = runtime.session.run(None, {"image": x})
    score = np.ascontiguousarray(outputs[0][0, 0, top : top + h, left : left + w])
    levels = [np.ascontiguousarray(o[0].transpose(1, 2, 0)) for o in outputs[1:]]
    return DenseMaps(score, levels, top, left, (padded.shape[0], padded.shape[1]))


# ----------------------------------------------------------------------------------------------
# Keypoints


def _max_filter(x: np.ndarray, radius: int) -> np.ndarray:
    """Maximum over the (2r+1)^2 window (outside the map ignored), like max pooling with stride 1."""
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(x, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)


def local_maxima(score: np.ndarray, radius: int = NMS_RADIUS) -> np.ndarray:
    """(h, w) scores kept at local maxima (0 elsewhere); a maximum next to a stronger one's window is dropped.

    The reference's "simple NMS": maxima of the window, then twice: pixels outside every kept maximum's
    window that are maxima among the remaining pixels are kept too.
    """
    s = np.ascontiguousarray(score, dtype=np.float32)
    is_max = s == _max_filter(s, radius)
    for _ in range(2):
        suppressed = _max_filter(is_max.astype(np.float32), radius) > 0
        rest = np.where(suppressed, np.float32(0), s)
        is_max |= (rest == _max_filter(rest, radius)) & ~suppressed
    return np.where(is_max, s, np.float32(0))


def bilinear(maps: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(N, C) bilinear samples of (H, W, C) ``maps`` at (N, 2) pixel positions; corners outside count 0."""
    h, w = maps.shape[:2]
    x, y = xy[:, 0].astype(np.float64), xy[:, 1].astype(np.float64)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    ax, ay = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
    flat = maps.reshape(h * w, -1)
    out = np.zeros((len(xy), flat.shape[1]), np.float32)
    for dy, dx, weight in ((0, 0, (1 - ax) * (1 - ay)), (0, 1, ax * (1 - ay)), (1, 0, (1 - ax) * ay), (1, 1, ax * ay)):
        cx, cy = x0 + dx, y0 + dy
        inside = (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)
        out += flat[np.where(inside, cy * w + cx, 0)] * (weight * inside)[:, None]
    return out


def detect_keypoints(
    score: np.ndarray,
    max_keypoints: int,
    allowed: np.ndarray | None = None,
    *,
    min_score: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints of an (h, w) score map: (N, 2) float32 sub-pixel (x, y) and (N,) float32 scores.

    allowed: optional (h, w) bool mask where keypoints may lie (tested at the local maximum's pixel).
    min_score: local maxima must score above this. Returns the ``max_keypoints`` strongest local maxima
    (by the score at the maximum; ties by position), refined by the 5x5 soft-argmax, ordered by their
    refined score, strongest first.
    """
    r = NMS_RADIUS
    h, w = score.shape
    nms = local_maxima(score, r)
    nms[:r], nms[h - r :], nms[:, :r], nms[:, w - r :] = 0, 0, 0, 0
    if allowed is not None:
        nms[~np.asarray(allowed, bool)] = 0
    flat = np.flatnonzero(nms > max(min_score, 0.0))
    if len(flat) == 0 or max_keypoints <= 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    values = nms.reshape(-1)[flat]
    if len(flat) > max_keypoints:
        keep = np.argpartition(-values, max_keypoints - 1)[:max_keypoints]
        flat, values = flat[keep], values[keep]
    order = np.lexsort((flat, -values))
    flat = flat[order]
    rows, cols = flat // w, flat % w
    d = np.arange(-r, r + 1)
    dy, dx = np.repeat(d, 2 * r + 1), np.tile(d, 2 * r + 1)  # the 5x5 window, row-major
    window = score[rows[:, None] + dy[None, :], cols[:, None] + dx[None, :]].astype(np.float32)
    weights = np.exp((window - window.max(axis=1, keepdims=True)) / np.float32(SOFTARGMAX_TEMPERATURE))
    weights /= weights.sum(axis=1, keepdims=True)
    xy = np.stack([cols + weights @ dx.astype(np.float32), rows + weights @ dy.astype(np.float32)], axis=1)
    xy = xy.astype(np.float32)
    refined = bilinear(score[:, :, None], xy)[:, 0]
    order = np.argsort(-refined, kind="stable")
    return xy[order], refined[order]


@dataclass
class Keypoints:
    """ALIKED keypoints of one image, strongest first.

    Returns (N, 2) float32 positions (x, y) in its pixels, (N,) float32 scores, (N, D) float32 unit
    descriptors and (N,) float32 the pyramid scale each was detected at (1 = full size).
    """

    xy: np.ndarray
    scores: np.ndarray
    descriptors: np.ndarray
    scales: np.ndarray

    def __len__(self) -> int:
        """Number of keypoints."""
        return len(self.xy)


def aliked_keypoints(
    image_rgb: np.ndarray,
    max_keypoints: int,
    allowed: np.ndarray | None = None,
    *,
    runtime: AlikedRuntime,
    min_score: float = 0.0,
    scales: tuple[float, ...] = (1.0,),
) -> Keypoints:
    """ALIKED on one (h, w, 3) uint8 RGB image, optionally over an image pyramid.

    allowed: optional (h, w) bool mask where keypoints may lie. runtime: from :func:`load_runtime`.
    scales: the image is run at each of these factors of its size (``cv2.INTER_AREA``; the mask nearest);
    levels below 32 px are skipped. ALIKED is single-scale: a facade seen 3x larger in one photo than in another has few
    matches at one scale, so a pyramid extends the scale range matching covers. Keypoints of all levels
    compete by score for the ``max_keypoints`` places (:func:`detect_keypoints` per level; only the kept
    ones are described); positions are returned in the input image's pixels.
    """
    img = np.asarray(image_rgb)
    h, w = img.shape[:2]
    levels = []
    for scale in scales:
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        if min(size) < PAD_MULTIPLE:
            continue
        if size == (w, h):
            img_s, allowed_s = img, allowed
        else:
            img_s = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
            allowed_s = None
            if allowed is not None:
                allowed_s = cv2.resize(np.asarray(allowed, np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
        maps = dense_maps(runtime, img_s)
        xy, scores = detect_keypoints(maps.score, max_keypoints, allowed_s, min_score=min_score)
        levels.append((maps, xy, scores, size[0] / w, size[1] / h))
    if not levels:
        return Keypoints(
            np.zeros((0, 2), np.float32),
            np.zeros(0, np.float32),
            np.zeros((0, runtime.descriptor_dim), np.float32),
            np.zeros(0, np.float32),
        )
    level_of = np.concatenate([np.full(len(lv[1]), i) for i, lv in enumerate(levels)])
    all_scores = np.concatenate([lv[2] for lv in levels])
    keep = np.sort(np.argsort(-all_scores, kind="stable")[:max_keypoints])
    out_xy, out_scores, out_desc, out_scale = [], [], [], []
    start = 0
    for i, (maps, xy, scores, sx, sy) in enumerate(levels):
        mine = keep[level_of[keep] == i] - start
        start += len(xy)
        out_desc.append(describe(maps, runtime.head, xy[mine]))
        out_xy.append(np.column_stack([(xy[mine, 0] + 0.5) / sx - 0.5, (xy[mine, 1] + 0.5) / sy - 0.5]))
        out_scores.append(scores[mine])
        out_scale.append(np.full(len(mine), sx, np.float32))
    scores_all = np.concatenate(out_scores)
    order = np.argsort(-scores_all, kind="stable")
    return Keypoints(
        np.concatenate(out_xy).astype(np.float32)[order],
        scores_all[order],
        np.concatenate(out_desc)[order],
        np.concatenate(out_scale)[order],
    )
