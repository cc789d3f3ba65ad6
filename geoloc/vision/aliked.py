"""ALIKED keypoints and descriptors at run time: onnxruntime for the dense network, numpy for the rest.

The network (:mod:`geoloc.export.nets.aliked`, exported by ``geoloc models build`` into
``cache_dir()/models``) gives a keypoint score map and four feature levels. Everything after it runs
here, vectorised over keypoints (no torch):

1. :func:`dense_maps`: the RGB image is padded to multiples of 32 (edge pixels replicated, split
   evenly between the sides), run through the ONNX graph, and the score map is cropped back.
2. :func:`detect_keypoints`: local maxima of the score map (radius-2 NMS with the reference's
   two-pass suppression, 2-pixel border dropped, optionally only inside an ``allowed`` mask), the
   ``max_keypoints`` strongest, each refined to sub-pixel by the soft-argmax (temperature 0.1) of its
   5x5 neighbourhood; its score is the score map read bilinearly there.
3. :func:`describe`: the sparse deformable descriptor head (SDDH). The descriptor map (the four
   levels upsampled bilinearly with aligned corners, concatenated, L2-normalised per pixel) is only
   evaluated at the integer pixels the head reads (:func:`descriptor_map_at`): the 3x3 patch at each
   truncated keypoint position, which predicts ``M`` = 16 sampling offsets (3x3 conv, SELU, 1x1 conv,
   clamped to +-max(H, W)/4), and the four corners of each offset sample (bilinear, zero outside the
   image). Samples go through a 1x1 conv and SELU, are aggregated by the (M, C, D) weights into one
   descriptor, L2-normalised.

Positions are (x, y) pixel centres of the input image (OpenCV's convention: pixel i spans
[i - 0.5, i + 0.5]). :func:`aliked_keypoints` does the three steps, optionally on an image pyramid;
``geoloc.vision.features`` wraps it into the project's :class:`~geoloc.vision.features.Features` (building mask,
working resolution).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from contracts.settings import default_threads
from geoloc.export.models import aliked_files

if TYPE_CHECKING:
    import onnxruntime as ort

PAD_MULTIPLE = 32
NMS_RADIUS = 2
SOFTARGMAX_TEMPERATURE = 0.1
_SELU_ALPHA = 1.6732632423543772
_SELU_SCALE = 1.0507009873554805


class AlikedNotBuiltError(FileNotFoundError):
    """The ALIKED export is missing; the message says how to build it."""


@dataclass(frozen=True)
class SddhWeights:
    """The descriptor head's weights (float32), shaped for matrix products.

    offset_w0: (2M, C * k * k) and offset_b0 (2M,): the k x k offset conv on a keypoint's patch (flattened
    channel-major, then row, then column). offset_w1 (2M, 2M), offset_b1 (2M,): the following 1x1 conv;
    its outputs are M x offsets then M y offsets. sample_w (C, C): the 1x1 conv on each sample.
    aggregate (M, C, D): per-sample aggregation weights.
    """

    offset_w0: np.ndarray
    offset_b0: np.ndarray
    offset_w1: np.ndarray
    offset_b1: np.ndarray
    sample_w: np.ndarray
    aggregate: np.ndarray
    kernel: int

    @property
    def n_samples(self) -> int:
        """M, the deformable samples per keypoint."""
        return int(self.aggregate.shape[0])

    @property
    def descriptor_dim(self) -> int:
        """D, the descriptor length."""
        return int(self.aggregate.shape[2])

    @classmethod
    def from_state(cls, state: dict[str, np.ndarray]) -> SddhWeights:
        """From the head's state dict arrays (keys as in the published weights, prefix ``desc_head.`` removed)."""
        w0 = np.asarray(state["offset_conv.0.weight"], np.float32)
        w1 = np.asarray(state["offset_conv.2.weight"], np.float32)
        return cls(
            offset_w0=w0.reshape(w0.shape[0], -1),
            offset_b0=np.asarray(state["offset_conv.0.bias"], np.float32),
            offset_w1=w1.reshape(w1.shape[0], -1),
            offset_b1=np.asarray(state["offset_conv.2.bias"], np.float32),
            sample_w=np.asarray(state["sf_conv.weight"], np.float32)[:, :, 0, 0],
            aggregate=np.asarray(state["agg_weights"], np.float32),
            kernel=int(w0.shape[-1]),
        )


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


def _default_threads() -> int:
    return default_threads()


@lru_cache(maxsize=4)
def _cached_runtime(onnx_path: str, head_path: str, config_name: str, threads: int) -> AlikedRuntime:
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")  # as the segmentation network
    session: ort.InferenceSession = ort.InferenceSession(onnx_path, options, providers=["CPUExecutionProvider"])
    with np.load(head_path, allow_pickle=False) as data:
        head = SddhWeights.from_state({k: data[k] for k in data.files})
    return AlikedRuntime(config_name, session, head)


def load_runtime(config_name: str = "aliked-n16", threads: int | None = None) -> AlikedRuntime:
    """Return the ALIKED runtime of ``config_name`` ("aliked-n16" or "aliked-t16"), cached per process.

    Parameters
    ----------
    config_name
        Which export.
    threads
        onnxruntime intra-op threads; default ``$GEOLOC_SEG_THREADS`` or min(4, cpu count).

    Raises
    ------
    AlikedNotBuiltError
        The export is not in the cache.
    """
    files = aliked_files(config_name)
    if not (files.onnx.exists() and files.head.exists()):
        raise AlikedNotBuiltError(
            f"ALIKED model {config_name} not found at {files.onnx}; build it once with `geoloc models build` "
            "(needs the export extra: pip install -e '.[export]')"
        )
    return _cached_runtime(str(files.onnx), str(files.head), config_name, threads or _default_threads())


def export_metadata(config_name: str) -> dict[str, Any] | None:
    """Return the export's JSON metadata (weights sha256, versions), or None if missing."""
    try:
        return dict(json.loads(aliked_files(config_name).meta.read_text()))
    except (OSError, ValueError):
        return None


# ----------------------------------------------------------------------------------------------
# Dense maps


@dataclass
class DenseMaps:
    """The network's output for one image.

    score: (h, w) float32 keypoint scores in (0, 1) at the image's size. levels: the four feature levels of
    the *padded* image, channels last, (H/s, W/s, C/4) for s = 1, 2, 8, 32 (pixel-major, so gathering a
    pixel's channels reads contiguous memory). pad_top, pad_left: the padding before the image's first
    row and column; padded_shape: (H, W).
    """

    score: np.ndarray
    levels: list[np.ndarray]
    pad_top: int
    pad_left: int
    padded_shape: tuple[int, int]

    @property
    def shape(self) -> tuple[int, int]:
        """(h, w) of the image."""
        return int(self.score.shape[0]), int(self.score.shape[1])


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


# ----------------------------------------------------------------------------------------------
# Descriptors


def _selu(x: np.ndarray) -> np.ndarray:
    return np.float32(_SELU_SCALE) * np.where(x > 0, x, np.float32(_SELU_ALPHA) * np.expm1(np.minimum(x, 0)))


def _upsample_taps(n_out: int, n_in: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Taps of bilinear upsampling with aligned corners from ``n_in`` to ``n_out`` samples along one axis.

    Returns, for every output index, its two source indices and the weight of the second.
    """
    src = np.arange(n_out, dtype=np.float32) * np.float32((n_in - 1) / max(n_out - 1, 1))
    lo = np.minimum(np.floor(src).astype(np.int64), n_in - 1)
    return lo, np.minimum(lo + 1, n_in - 1), (src - lo).astype(np.float32)


def descriptor_map_at(maps: DenseMaps, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(K, D) unit descriptors of the dense descriptor map at integer image pixels (rows, cols), inside the image.

    Level 1 is read directly; levels 2-4 are upsampled (bilinear, aligned corners, separable taps) at
    just these pixels; the concatenation is L2-normalised.
    """
    prow = np.asarray(rows, np.int64) + maps.pad_top
    pcol = np.asarray(cols, np.int64) + maps.pad_left
    big_h, big_w = maps.padded_shape
    quarter = maps.levels[0].shape[2]
    out = np.empty((len(prow), 4 * quarter), np.float32)
    for i, level in enumerate(maps.levels):
        h, w = level.shape[:2]
        flat = level.reshape(h * w, quarter)
        part = out[:, i * quarter : (i + 1) * quarter]
        if (h, w) == (big_h, big_w):
            part[:] = flat[prow * w + pcol]
            continue
        y0, y1, wy = (a[prow] for a in _upsample_taps(big_h, h))
        x0, x1, wx = (a[pcol] for a in _upsample_taps(big_w, w))
        wx, wy = wx[:, None], wy[:, None]
        top = flat[y0 * w + x0] * (1 - wx) + flat[y0 * w + x1] * wx
        bottom = flat[y1 * w + x0] * (1 - wx) + flat[y1 * w + x1] * wx
        part[:] = top * (1 - wy) + bottom * wy
    out /= np.maximum(np.sqrt(np.einsum("ij,ij->i", out, out)), np.float32(1e-12))[:, None]
    return out


def describe(maps: DenseMaps, head: SddhWeights, xy: np.ndarray) -> np.ndarray:
    """(N, D) float32 unit descriptors of keypoints at (N, 2) pixel positions (SDDH, module docstring)."""
    n = len(xy)
    if n == 0:
        return np.zeros((0, head.descriptor_dim), np.float32)
    h, w = maps.shape
    k, m = head.kernel, head.n_samples
    xy = np.asarray(xy, np.float32)
    base = np.floor(xy).astype(np.int64)  # the reference truncates (positions are >= 0)

    # Integer pixels the head reads: each keypoint's k x k patch and the 4 corners of its M samples.
    d = np.arange(k) - k // 2
    patch_rows = base[:, 1, None, None] + d[None, :, None]  # (N, k, 1)
    patch_cols = base[:, 0, None, None] + d[None, None, :]  # (N, 1, k)
    patch_rows, patch_cols = np.broadcast_arrays(patch_rows, patch_cols)

    # Offsets need the patches first.
    pr, pc = patch_rows.reshape(-1), patch_cols.reshape(-1)
    inside = (pr >= 0) & (pr < h) & (pc >= 0) & (pc < w)
    values = np.zeros((len(pr), head.offset_w0.shape[1] // (k * k)), np.float32)
    values[inside] = descriptor_map_at(maps, pr[inside], pc[inside])
    patches = values.reshape(n, k * k, -1).transpose(0, 2, 1).reshape(n, -1)  # channel-major, then row, col
    hidden = _selu(patches @ head.offset_w0.T + head.offset_b0)
    offsets = hidden @ head.offset_w1.T + head.offset_b1
    limit = np.float32(max(h, w) / 4.0)
    offsets = np.clip(offsets, -limit, limit)
    positions = xy[:, None, :] + np.stack([offsets[:, :m], offsets[:, m:]], axis=2)  # (N, M, 2)

    # Bilinear samples of the descriptor map (zero outside the image), evaluated once per distinct pixel.
    p = positions.reshape(-1, 2).astype(np.float64)
    x0, y0 = np.floor(p[:, 0]).astype(np.int64), np.floor(p[:, 1]).astype(np.int64)
    ax, ay = (p[:, 0] - x0).astype(np.float32), (p[:, 1] - y0).astype(np.float32)
    corner_x = np.stack([x0, x0 + 1, x0, x0 + 1], axis=1)
    corner_y = np.stack([y0, y0, y0 + 1, y0 + 1], axis=1)
    corner_w = np.stack([(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay], axis=1)
    valid = (corner_x >= 0) & (corner_x < w) & (corner_y >= 0) & (corner_y < h)
    pixels, slot = np.unique(corner_y[valid] * w + corner_x[valid], return_inverse=True)
    table = np.zeros((len(pixels) + 1, head.sample_w.shape[1]), np.float32)  # last row: outside (zero)
    table[:-1] = descriptor_map_at(maps, pixels // w, pixels % w)
    corner_slot = np.full(valid.shape, len(pixels), np.int64)
    corner_slot[valid] = slot.reshape(-1)
    samples = table[corner_slot[:, 0]] * corner_w[:, 0, None]
    for j in range(1, 4):
        samples += table[corner_slot[:, j]] * corner_w[:, j, None]
    samples = _selu(samples.reshape(n, m, -1) @ head.sample_w.T)  # (N, M, C)
    descriptors: np.ndarray = samples.reshape(n, -1) @ head.aggregate.reshape(-1, head.descriptor_dim)  # sum (m, c)
    descriptors /= np.maximum(np.linalg.norm(descriptors, axis=1, keepdims=True), np.float32(1e-12))
    return descriptors.astype(np.float32)


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
    runtime: AlikedRuntime | None = None,
    min_score: float = 0.0,
    scales: tuple[float, ...] = (1.0,),
) -> Keypoints:
    """ALIKED on one (h, w, 3) uint8 RGB image, optionally over an image pyramid.

    allowed: optional (h, w) bool mask where keypoints may lie. runtime: default ``load_runtime()`` (n16).
    scales: the image is run at each of these factors of its size (``cv2.INTER_AREA``; the mask nearest);
    levels below 32 px are skipped. ALIKED is single-scale: a facade seen 3x larger in one photo than in another has few
    matches at one scale, so a pyramid extends the scale range matching covers. Keypoints of all levels
    compete by score for the ``max_keypoints`` places (:func:`detect_keypoints` per level; only the kept
    ones are described); positions are returned in the input image's pixels.
    """
    runtime = runtime or load_runtime()
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
        return Keypoints(np.zeros((0, 2), np.float32), np.zeros(0, np.float32),
                         np.zeros((0, runtime.descriptor_dim), np.float32), np.zeros(0, np.float32))
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
