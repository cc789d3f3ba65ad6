"""ALIKED's sparse deformable descriptor head (SDDH) in numpy, on the dense network's maps.

The descriptor map (the four feature levels upsampled bilinearly with aligned corners, concatenated,
L2-normalised per pixel) is only evaluated at the integer pixels the head reads (:func:`descriptor_map_at`):
the 3x3 patch at each truncated keypoint position, which predicts ``M`` = 16 sampling offsets (3x3 conv,
SELU, 1x1 conv, clamped to +-max(H, W)/4), and the four corners of each offset sample (bilinear, zero
outside the image). Samples go through a 1x1 conv and SELU, are aggregated by the (M, C, D) weights into
one descriptor, L2-normalised (:func:`describe`). The network and the keypoints: :mod:`geoloc.vision.aliked`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_SELU_ALPHA = 1.6732632423543772
_SELU_SCALE = 1.0507009873554805


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
