"""Local features on building pixels (the paper's SBoW uses building only): RootSIFT or ALIKED.

Two feature types (``method``), with the same output contract (:class:`Features`: positions in input
pixels, unit-norm descriptors, strongest first, only on the building mask):

- ``"rootsift"``: OpenCV SIFT keypoints with RootSIFT descriptors (128-D, non-negative).
- ``"aliked-n16"`` (alias ``"aliked"``) and ``"aliked-t16"``: the learned ALIKED keypoints and
  descriptors (128-D and 64-D, signed; :mod:`geoloc.vision.aliked`, exported by ``geoloc models build``).
  ALIKED keypoints have no scale or orientation: ``sizes`` is the 5x5 detection window (in input
  pixels) and ``angles`` is 0 (the descriptors are not rotation invariant; photos are upright).

:data:`~geoloc.vision.feature_types.DEFAULT_METHOD` is the one setting that chooses the feature type
everywhere (extraction in the pipeline, the SBoW vocabulary: ``geoloc models build --features <type>``
builds a type's vocabulary).
Descriptors of both types are unit vectors, so :func:`geoloc.localize.transfer.match_features` (dot products,
Lowe's ratio 0.8, one-to-one) serves both; features of different types must never be matched or
indexed together (``Features.method`` says which type a set is).

Measured (``benchmarks/bench_features.py``; simulated Helsinki world seed 1, 60 references, 30
queries, 640 x 480, network building masks, 1500 keypoints; the pipeline's matching and RANSAC; Lund:
29 real 1024 x 768 photos along a street; times on the shared 2-core box at load 5-11)::

                                                   RootSIFT   ALIKED-n16  ALIKED-t16  n16, pyramid 1,1/2,1/4
    best co-visible reference, >= 12 / >= 30
      correct inliers (18 queries)                0.39/0.28   0.28/0.22   0.33/0.22   0.39/0.22
    verified inliers that are correct             0.41        0.70        0.56        0.72
    unrelated references passing RANSAC (of 450)  24 %        0.4 %       3.6 %       0.2 %
      their most inliers                          38          14          35          15
    reference with most inliers is right          7 of 26     9 of 13     8 of 17     8 of 12
    SBoW top 20 / re-ranked top 4                 0.76/0.67   0.81/0.48   0.76/0.43   0.81/0.48
    Lund adjacent pairs, median verified inliers  84          183         168         188
    Lund pairs >= 8 apart passing RANSAC          5 %         8 %         11 %        10 %
    ms per 640 x 480 / 1024 x 768 image           114/314     636/1977    439/1295    899/2789

ALIKED's inliers are far more often right and unrelated references (repeated facade textures) almost
never pass verification; on real photos it finds twice the inliers. It does not cover more simulated
queries: it is single-scale, and beyond a ~2.5x scale change between two photos of a facade it finds
nothing (the pyramid, ``aliked_scales``, recovers RootSIFT's coverage at 1.4x its time), and it costs
4-6x RootSIFT's extraction time (at lower load: network 0.13 s + descriptor head 0.12-0.16 s per
640 x 480 image). Mutual nearest neighbours add nothing to the ratio test with one-to-one matching;
looser ratios (0.9, 0.95) find more inliers for both types but let most unrelated references pass.
RootSIFT stays the default.

Pipeline (:func:`extract_features`):

1. The image is downscaled (``cv2.INTER_AREA``) so its longer side is at most ``max_side`` pixels
   (default 1024: phone photos of 4032 x 3024 become 1024 x 768; smaller images are kept as they are).
   Features of every image are thus computed at a comparable working resolution, and SIFT stays fast.
2. The building mask is resized to the working size (nearest) and dilated by ``dilate_px`` working
   pixels (default 4): segmentation tends to undershoot building outlines, and keypoints on a
   building's silhouette (roof line against the sky, corners) are among the most distinctive ones.
   Keypoints are detected only where this dilated mask is set. OpenCV applies a mask after SIFT's
   ``nfeatures`` cap, so SIFT can also run on the whole image before the mask exists
   (:func:`sift_candidates`, beside the segmentation network) and the mask then picks the same keypoints
   and descriptors bit for bit (``extract_features(..., candidates=...)``).
3. RootSIFT: OpenCV SIFT keeps the ``max_features`` strongest keypoints; each descriptor is made
   RootSIFT (L1-normalised, element-wise square root: unit L2 norm, so Euclidean distance between
   RootSIFT descriptors is the Hellinger distance between the SIFT histograms, and dot products are
   similarities). ALIKED: the ``max_features`` strongest local maxima of the score map whose pixel
   is on the mask (:func:`geoloc.vision.aliked.detect_keypoints`), described by the network's head.
4. Keypoints are sorted by response (strongest first; ties by position), and their positions are
   returned in the *input* image's pixel coordinates (pixel centres at integer + 0.5 convention of
   OpenCV: ``x_in = (x_work + 0.5) / scale - 0.5``).

The result is deterministic for a given image, mask and parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from geoloc.core.context import MethodContext
from geoloc.vision.aliked import aliked_keypoints, load_runtime
from geoloc.vision.feature_types import DESCRIPTOR_DIMS, canonical_method

DEFAULT_MAX_SIDE = 1024
DEFAULT_MAX_FEATURES = 1500
DESCRIPTOR_DIM = 128  # RootSIFT and ALIKED-n16; ALIKED-t16 has 64

ALIKED_WINDOW_PX = 5  # ALIKED's detection window (NMS and soft-argmax), reported as the keypoint size
DEFAULT_ALIKED_SCALES: tuple[float, ...] = (1.0,)


@dataclass
class Features:
    """Local features of one image.

    xy: (N, 2) float32 keypoint positions (x, y) in pixels of the input image.
    descriptors: (N, D) float32 unit-L2-norm descriptors (RootSIFT: D = 128, non-negative; ALIKED-n16:
    128, ALIKED-t16: 64).
    sizes: (N,) float32 keypoint diameters in input-image pixels. angles: (N,) float32 orientations (deg).
    responses: (N,) float32 detector responses (strongest first).
    image_shape: (H, W) of the input image. scale: working size / input size (<= 1); coordinates
    multiplied by ``scale`` are in working pixels, where pixel thresholds (RANSAC) are meant.
    method: the feature type (:mod:`geoloc.vision.feature_types`); descriptors of different types must not be matched.
    """

    xy: np.ndarray
    descriptors: np.ndarray
    sizes: np.ndarray
    angles: np.ndarray
    responses: np.ndarray
    image_shape: tuple[int, int]
    scale: float = 1.0
    method: str = "rootsift"

    def __post_init__(self) -> None:
        """Coerce the arrays to their dtypes and shapes; ValueError if their lengths differ."""
        self.xy = np.asarray(self.xy, dtype=np.float32).reshape(-1, 2)
        desc = np.asarray(self.descriptors, dtype=np.float32)
        if desc.ndim != 2:
            desc = desc.reshape(len(self.xy), -1) if desc.size else np.zeros((0, DESCRIPTOR_DIM), np.float32)
        self.descriptors = desc
        self.method = canonical_method(str(self.method))
        self.sizes = np.asarray(self.sizes, dtype=np.float32).reshape(-1)
        self.angles = np.asarray(self.angles, dtype=np.float32).reshape(-1)
        self.responses = np.asarray(self.responses, dtype=np.float32).reshape(-1)
        self.image_shape = (int(self.image_shape[0]), int(self.image_shape[1]))
        n = len(self.xy)
        if not (len(self.descriptors) == len(self.sizes) == len(self.angles) == len(self.responses) == n):
            raise ValueError("xy, descriptors, sizes, angles and responses must have the same length")

    def __len__(self) -> int:
        """Number of keypoints."""
        return len(self.xy)

    @property
    def descriptor_dim(self) -> int:
        """D, the length of one descriptor."""
        return int(self.descriptors.shape[1])

    @classmethod
    def empty(
        cls, image_shape: tuple[int, int], scale: float = 1.0, method: str = "rootsift", descriptor_dim: int = 128
    ) -> Features:
        """No keypoints (e.g. an image without building pixels)."""
        z = np.zeros(0, np.float32)
        return cls(np.zeros((0, 2)), np.zeros((0, descriptor_dim)), z, z, z, image_shape, scale, method)

    def subset(self, index: np.ndarray) -> Features:
        """The keypoints selected by ``index`` (bool mask or integer indices)."""
        return Features(
            self.xy[index],
            self.descriptors[index],
            self.sizes[index],
            self.angles[index],
            self.responses[index],
            self.image_shape,
            self.scale,
            self.method,
        )

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays for storage (descriptors as float16: unit vectors, components in [-1, 1])."""
        return {
            "xy": self.xy,
            "descriptors": self.descriptors.astype(np.float16),
            "sizes": self.sizes,
            "angles": self.angles,
            "responses": self.responses,
            "image_shape": np.asarray(self.image_shape, np.int64),
            "scale": np.asarray(self.scale, np.float64),
            "method": np.asarray(self.method),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> Features:
        """Inverse of :meth:`to_arrays` (accepts an ``np.load`` result).

        Arrays stored without ``method`` are RootSIFT, the only type before it existed.
        """
        return cls(
            arrays["xy"],
            np.asarray(arrays["descriptors"], np.float32),
            arrays["sizes"],
            arrays["angles"],
            arrays["responses"],
            tuple(np.asarray(arrays["image_shape"]).tolist()),
            float(arrays["scale"]),
            str(arrays["method"]) if "method" in arrays else "rootsift",
        )

    def save(self, path: str | Path) -> None:
        """Write to ``path`` (.npz, compressed)."""
        # allow_pickle is numpy's default, named so that the arrays are not matched against it (mypy).
        np.savez_compressed(path, allow_pickle=True, **self.to_arrays())

    @classmethod
    def load(cls, path: str | Path) -> Features:
        """Features saved by :meth:`save`."""
        with np.load(path) as data:
            return cls.from_arrays(dict(data))


def working_scale(image_shape: tuple[int, int], max_side: int = DEFAULT_MAX_SIDE) -> float:
    """Scale factor (<= 1) that brings an image of ``image_shape`` (H, W) to a longer side of at most ``max_side``."""
    return min(1.0, float(max_side) / float(max(image_shape[:2])))


def root_sift(descriptors: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """(N, 128) SIFT -> RootSIFT: L1-normalise each row, then element-wise square root (rows get unit L2 norm)."""
    d = np.maximum(np.asarray(descriptors, dtype=np.float32), 0.0)
    d /= np.maximum(d.sum(axis=1, keepdims=True), eps)
    return np.sqrt(d, out=d)


def _to_u8(image: np.ndarray) -> np.ndarray:
    """uint8 copy of an image given as uint8, or float in [0, 1] or [0, 255]; an alpha channel is dropped."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        scale = 255.0 if img.dtype.kind == "f" and img.max(initial=0) <= 1.0 else 1.0
        img = np.clip(img.astype(np.float32) * scale, 0, 255).astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    return np.ascontiguousarray(img)


def _to_gray_u8(image_rgb: np.ndarray) -> np.ndarray:
    img = _to_u8(image_rgb)
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


def _to_rgb_u8(image_rgb: np.ndarray) -> np.ndarray:
    img = _to_u8(image_rgb)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB) if img.ndim == 2 else img


def detection_mask(building_mask: np.ndarray, size_wh: tuple[int, int], dilate_px: int) -> np.ndarray:
    """(h, w) uint8 mask (0/255) where keypoints may be detected: the building mask at working size, dilated."""
    mask: np.ndarray = (np.asarray(building_mask) > 0).astype(np.uint8)
    if (mask.shape[1], mask.shape[0]) != size_wh:
        mask = cv2.resize(mask, size_wh, interpolation=cv2.INTER_NEAREST)
    if dilate_px > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilate_px + 1, 2 * dilate_px + 1))
        mask = cv2.dilate(mask, kernel)
    return mask * np.uint8(255)


@dataclass(frozen=True)
class SiftCandidates:
    """SIFT on a whole image before any mask: what :func:`extract_features` keeps the masked keypoints of.

    OpenCV's SIFT detects on the whole image, keeps its ``nfeatures`` strongest keypoints and only then drops
    those off the mask (``KeyPointsFilter::runByPixelsMask`` after ``retainBest``); descriptors are computed per
    keypoint. So these candidates, filtered by a mask, are exactly what SIFT finds with that mask, and they can
    be computed before the mask exists (beside the segmentation network).

    xy_work: (N, 2) float32 positions in working pixels; sift: (N, 128) float32 plain SIFT descriptors (RootSIFT
    is made after the mask); sizes, angles, responses: (N,) float32 in working pixels / degrees.
    image_shape: (H, W) of the input image; size_wh: the working size (w, h); parameters: (max_features,
    max_side, contrast_threshold, edge_threshold) they were computed with.
    """

    xy_work: np.ndarray
    sift: np.ndarray
    sizes: np.ndarray
    angles: np.ndarray
    responses: np.ndarray
    image_shape: tuple[int, int]
    size_wh: tuple[int, int]
    parameters: tuple[int, int, float, float]


def _working_image(image_rgb: np.ndarray, method: str, max_side: int) -> tuple[np.ndarray, float, float, float]:
    """The image at working size (gray for RootSIFT, RGB for ALIKED), its scale and exact per-axis factors."""
    image = _to_gray_u8(image_rgb) if method == "rootsift" else _to_rgb_u8(image_rgb)
    h, w = image.shape[:2]
    scale = working_scale((h, w), max_side)
    size_wh = (max(1, round(w * scale)), max(1, round(h * scale)))
    if size_wh == (w, h):
        return image, scale, 1.0, 1.0
    # Exact per-axis factors (rounding of the working size).
    return cv2.resize(image, size_wh, interpolation=cv2.INTER_AREA), scale, size_wh[0] / w, size_wh[1] / h


@dataclass(frozen=True)
class SiftThresholds:
    """OpenCV SIFT's detector thresholds (RootSIFT only): ``contrastThreshold`` and ``edgeThreshold``."""

    contrast: float = 0.02
    edge: float = 10.0


def _sift_parameters(
    max_features: int, max_side: int, contrast_threshold: float, edge_threshold: float
) -> tuple[int, int, float, float]:
    """What :class:`SiftCandidates` records of its parameters, to refuse them for features of other ones."""
    return int(max_features), int(max_side), float(contrast_threshold), float(edge_threshold)


def sift_candidates(
    image_rgb: np.ndarray,
    max_features: int = DEFAULT_MAX_FEATURES,
    *,
    max_side: int = DEFAULT_MAX_SIDE,
    sift: SiftThresholds = SiftThresholds(),
) -> SiftCandidates:
    """SIFT on the whole working-size image (:class:`SiftCandidates`); parameters as :func:`extract_features`.

    It costs the masked SIFT's time plus the descriptors of the keypoints off the building (about 13 % more CPU
    on 640 x 480 street photos): worth it only where it runs beside something else (the network).
    """
    contrast_threshold, edge_threshold = sift.contrast, sift.edge
    gray, _, _, _ = _working_image(image_rgb, "rootsift", max_side)
    found = _sift(gray, None, max_features, contrast_threshold, edge_threshold)
    if found is None:
        z = np.zeros(0, np.float32)
        found = np.zeros((0, 2), np.float32), np.zeros((0, DESCRIPTOR_DIM), np.float32), z, z, z
    image_shape = (int(np.shape(image_rgb)[0]), int(np.shape(image_rgb)[1]))
    parameters = _sift_parameters(max_features, max_side, contrast_threshold, edge_threshold)
    xy_work, descriptors, sizes, angles, responses = found
    size_wh = (gray.shape[1], gray.shape[0])
    return SiftCandidates(xy_work, descriptors, sizes, angles, responses, image_shape, size_wh, parameters)


def extract_features(
    image_rgb: np.ndarray,
    building_mask: np.ndarray | None,
    max_features: int = DEFAULT_MAX_FEATURES,
    *,
    method: str | None = None,
    max_side: int = DEFAULT_MAX_SIDE,
    dilate_px: int = 4,
    sift: SiftThresholds = SiftThresholds(),
    aliked_scales: tuple[float, ...] = DEFAULT_ALIKED_SCALES,
    context: MethodContext | None = None,
    candidates: SiftCandidates | None = None,
) -> Features:
    """Local features on the building pixels of an image (module docstring).

    image_rgb: (H, W, 3) uint8 RGB (or (H, W) gray). building_mask: (H, W) bool/int, non-zero on building
    pixels (any size: it is resized to the image); None means the whole image.
    max_features: keep at most this many keypoints (the strongest).
    method: "rootsift", "aliked-n16" (alias "aliked") or "aliked-t16"; None is the default.
    max_side: working resolution (longer side, pixels); dilate_px: mask dilation in working pixels.
    sift: OpenCV SIFT's detector thresholds (:class:`SiftThresholds`; RootSIFT only).
    aliked_scales: ALIKED's image pyramid, as factors of the working size (ALIKED only; see
    :func:`geoloc.vision.aliked.aliked_keypoints`).
    context: where the built models are and the networks' threads (ALIKED only: RootSIFT needs no model).
    candidates: :func:`sift_candidates` of this image with these parameters (RootSIFT only): the mask picks from
    them instead of running SIFT again; the result is the same bit for bit.
    Returns :class:`Features` with positions in input-image pixels, strongest first.
    Raises :class:`geoloc.vision.aliked.AlikedNotBuiltError` when ALIKED is asked for and not exported, and
    ValueError when it is asked for (on a non-empty mask) without a ``context``, or when ``candidates`` were
    computed with other parameters, on another image size or for ALIKED.
    """
    method = canonical_method(method)
    contrast_threshold, edge_threshold = sift.contrast, sift.edge
    h, w = np.shape(image_rgb)[:2]
    if candidates is not None:
        parameters = _sift_parameters(max_features, max_side, contrast_threshold, edge_threshold)
        if method != "rootsift" or candidates.parameters != parameters or candidates.image_shape != (h, w):
            raise ValueError("SIFT candidates of another image size, other parameters or for another feature type")
        scale = working_scale((h, w), max_side)
        size_wh = candidates.size_wh
        sx, sy = size_wh[0] / w, size_wh[1] / h
    else:
        image, scale, sx, sy = _working_image(image_rgb, method, max_side)
        size_wh = (image.shape[1], image.shape[0])
    if building_mask is None:
        mask = np.full((size_wh[1], size_wh[0]), 255, np.uint8)
    else:
        mask = detection_mask(building_mask, size_wh, dilate_px)
    dim = DESCRIPTOR_DIMS[method]
    if not mask.any() or max_features <= 0:
        return Features.empty((h, w), scale, method, dim)
    if candidates is not None:
        found = _on_mask(candidates, mask)
    elif method == "rootsift":
        found = _sift(image, mask, max_features, contrast_threshold, edge_threshold)
    else:
        found = _aliked(image, mask, max_features, method, aliked_scales, context)
    if found is None:
        return Features.empty((h, w), scale, method, dim)
    pts, desc, sizes, angles, responses = found
    if method == "rootsift":
        desc = root_sift(desc)
    # Strongest first; ties broken by position, so the order does not depend on the detector's internal order.
    order = np.lexsort((pts[:, 0], pts[:, 1], -responses))[: int(max_features)]
    xy = np.empty_like(pts[order])
    xy[:, 0] = (pts[order, 0] + 0.5) / sx - 0.5
    xy[:, 1] = (pts[order, 1] + 0.5) / sy - 0.5
    return Features(xy, desc[order], sizes[order] / scale, angles[order], responses[order], (h, w), scale, method)


_Found = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _sift(
    gray: np.ndarray, mask: np.ndarray | None, max_features: int, contrast_threshold: float, edge_threshold: float
) -> _Found | None:
    """SIFT on a working-size gray image inside ``mask`` (None: all of it): positions, SIFT, sizes, angles, scores."""
    sift = cv2.SIFT.create(
        nfeatures=int(max_features), contrastThreshold=contrast_threshold, edgeThreshold=edge_threshold
    )
    keypoints, desc = sift.detectAndCompute(gray, mask)
    if desc is None or len(keypoints) == 0:
        return None
    pts = np.array([k.pt for k in keypoints], np.float32).reshape(-1, 2)
    sizes = np.array([k.size for k in keypoints], np.float32)
    angles = np.array([k.angle for k in keypoints], np.float32)
    responses = np.array([k.response for k in keypoints], np.float32)
    return pts, np.asarray(desc, np.float32), sizes, angles, responses


def _on_mask(candidates: SiftCandidates, mask: np.ndarray) -> _Found | None:
    """The candidates whose pixel is set in ``mask``, as OpenCV's ``runByPixelsMask`` picks them.

    OpenCV reads ``mask[int(y + 0.5f), int(x + 0.5f)]`` in float32 (truncation; positions are positive).
    """
    xy = candidates.xy_work
    half = np.float32(0.5)
    cols = np.clip((xy[:, 0] + half).astype(np.int64), 0, mask.shape[1] - 1)
    rows = np.clip((xy[:, 1] + half).astype(np.int64), 0, mask.shape[0] - 1)
    keep = mask[rows, cols] != 0
    if not keep.any():
        return None
    c = candidates
    return c.xy_work[keep], c.sift[keep], c.sizes[keep], c.angles[keep], c.responses[keep]


def _aliked(
    rgb: np.ndarray,
    mask: np.ndarray,
    max_features: int,
    method: str,
    scales: tuple[float, ...],
    context: MethodContext | None,
) -> _Found | None:
    """ALIKED on a working-size RGB image, keypoints on ``mask``: positions, descriptors, sizes, angles, scores."""
    if context is None:
        raise ValueError(f"{method} features need a MethodContext (the built models' folder)")
    runtime = load_runtime(context, method)
    found = aliked_keypoints(rgb, int(max_features), mask > 0, runtime=runtime, scales=scales)
    if len(found) == 0:
        return None
    sizes = np.float32(ALIKED_WINDOW_PX) / found.scales
    return found.xy, found.descriptors, sizes, np.zeros(len(found), np.float32), found.scores
