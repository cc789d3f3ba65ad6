"""Line segment detection (OpenCV LSD, or FLD from opencv-contrib when available).

Segments are returned as an ``(N, 4)`` float array ``x1, y1, x2, y2`` in pixels of the input
image (pixel centres at integer coordinates, as OpenCV reports them). OpenCV 5 returns LSD/FLD
lines as ``(N, 4)`` (OpenCV 4 as ``(N, 1, 4)``); both are handled.
"""

from __future__ import annotations

import numpy as np

DEFAULT_MIN_LENGTH_FRAC = 0.02
"""Default minimum segment length as a fraction of the image diagonal."""

DEFAULT_MAX_SIDE_PX = 1600
"""Images with a longer side than this are downscaled before detection (speed); segments are
scaled back to the input resolution."""


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) RGB(A) image (uint8 or float in [0, 1] / [0, 255]) -> (H, W) uint8 gray."""
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8:
        scale = 255.0 if img.size and float(np.nanmax(img)) <= 1.0 else 1.0
        img = np.clip(np.nan_to_num(img.astype(np.float32) * scale), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        return cv2.cvtColor(img[:, :, :3], cv2.COLOR_RGB2GRAY)
    raise ValueError(f"expected an (H, W) or (H, W, 3) image, got shape {img.shape}")


def segment_lengths_px(segments: np.ndarray) -> np.ndarray:
    """(N, 4) segments -> (N,) lengths in pixels."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    lengths: np.ndarray = np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1])
    return lengths


def sample_points_along(segments: np.ndarray, n_samples: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixels sampled evenly along segments.

    Parameters
    ----------
    segments
        (N, 4) ``x1, y1, x2, y2`` in pixels.
    n_samples
        Points per segment (S), at the centres of S equal parts.
    width, height
        Image size in pixels; points are clipped into it.

    Returns
    -------
    tuple[np.ndarray, np.ndarray]
        (N, S) integer x and y of the points.
    """
    t = (np.arange(n_samples) + 0.5) / n_samples
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    x = s[:, 0:1] + t[None, :] * (s[:, 2:3] - s[:, 0:1])
    y = s[:, 1:2] + t[None, :] * (s[:, 3:4] - s[:, 1:2])
    xi = np.clip(np.round(x).astype(int), 0, width - 1)
    yi = np.clip(np.round(y).astype(int), 0, height - 1)
    return xi, yi


def _raw_detect(gray: np.ndarray, method: str) -> np.ndarray:
    import cv2

    if method == "fld":
        # cv2.ximgproc is in opencv-contrib only: absent from the stubs of the headless wheel we depend on.
        fld = cv2.ximgproc.createFastLineDetector()  # type: ignore[attr-defined]
        lines = fld.detect(gray)
    else:
        lsd = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)
        lines = lsd.detect(gray)[0]
    if lines is None:
        return np.zeros((0, 4))
    return np.asarray(lines, dtype=float).reshape(-1, 4)


def detect_line_segments(
    image: np.ndarray,
    min_length_frac: float = DEFAULT_MIN_LENGTH_FRAC,
    min_length_px: float = 8.0,
    max_side_px: int | None = DEFAULT_MAX_SIDE_PX,
    method: str = "auto",
) -> np.ndarray:
    """Detect straight line segments in an image.

    image: (H, W) gray or (H, W, 3) RGB, any size.
    min_length_frac: drop segments shorter than this fraction of the image diagonal
        (but never keep segments shorter than ``min_length_px``).
    max_side_px: downscale larger images to this longer side before detection (None: never).
    method: ``"lsd"``, ``"fld"`` (needs opencv-contrib's ximgproc) or ``"auto"`` (LSD; it is the
        more precise of the two and always present in opencv-python-headless).
    Returns (N, 4) float64 ``x1, y1, x2, y2`` in input-image pixels, longest first.
    """
    import cv2

    gray = to_gray(image)
    h, w = gray.shape
    if h < 2 or w < 2:
        return np.zeros((0, 4))
    if method == "auto":
        method = "lsd"
    if method == "fld" and not hasattr(cv2, "ximgproc"):
        raise RuntimeError("FLD needs opencv-contrib (cv2.ximgproc); use method='lsd'")
    if method not in ("lsd", "fld"):
        raise ValueError(f"unknown line detector {method!r}")
    scale = 1.0
    if max_side_px is not None and max(h, w) > max_side_px:
        scale = max_side_px / max(h, w)
        gray = cv2.resize(gray, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    segments = _raw_detect(gray, method)
    if scale != 1.0 and len(segments):
        # Pixel centres: x_in = (x_small + 0.5) / scale - 0.5.
        segments = (segments + 0.5) / scale - 0.5
    min_len = max(min_length_px, min_length_frac * float(np.hypot(h, w)))
    lengths = segment_lengths_px(segments)
    keep = lengths >= min_len
    segments, lengths = segments[keep], lengths[keep]
    return segments[np.argsort(-lengths, kind="stable")]
