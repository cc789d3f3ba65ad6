"""The vision stage's fast paths give the plain paths' results bit for bit, on real photos.

Whole-image SIFT filtered by the building mask (:func:`geoloc.vision.features.sift_candidates`) against SIFT
run on the mask, and :func:`geoloc.vision.evidence.analyze_photo` with the image-only work beside the network
(two job threads) against one thread.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.core.context import MethodContext
from geoloc.core.parallel import JobThreads
from geoloc.photos.photo import load_photo
from geoloc.vision.evidence import PhotoEvidence, analyze_photo
from geoloc.vision.features import Features, extract_features, sift_candidates

FEATURE_ARRAYS = ("xy", "descriptors", "sizes", "angles", "responses")


def _photos() -> list[Path]:
    """Real street photos: one of Lund (1024 x 768) and two of Berlin (3264 x 2448)."""
    try:
        folders = [shared_path("data", "lund", "images"), shared_path("data", "berlin", "images")]
    except FileNotFoundError:
        pytest.skip("shared Lund/Berlin photos not available")
    return [sorted(folders[0].glob("*.jpg"))[0], *sorted(folders[1].glob("*.jpg"))[:2]]


def _rgb(path: Path) -> np.ndarray:
    """The photo as it is in the file (Berlin's are downscaled to the working size by the features)."""
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def _masks(rgb: np.ndarray) -> dict[str, np.ndarray | None]:
    """Masks of several shapes: an irregular one from the photo itself, a corner, none and an empty one."""
    gray = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), (0, 0), 9)
    h, w = gray.shape
    corner = np.zeros((h // 3, w // 3), np.uint8)  # another size than the photo: resized to it
    corner[: h // 9, : w // 9] = 1
    return {
        "bright": gray > np.median(gray),
        "corner": corner,
        "none": None,
        "empty": np.zeros((h, w), bool),
    }


def _assert_same(plain: Features, fast: Features) -> None:
    for name in FEATURE_ARRAYS:
        a, b = getattr(plain, name), getattr(fast, name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name
    assert (plain.image_shape, plain.scale, plain.method) == (fast.image_shape, fast.scale, fast.method)


@pytest.mark.parametrize("max_features", [1500, 300])
def test_whole_image_sift_on_the_mask_is_sift_with_the_mask(max_features: int) -> None:
    """OpenCV caps the strongest keypoints before it applies the mask: the candidates pick the same ones."""
    for path in _photos():
        rgb = _rgb(path)
        candidates = sift_candidates(rgb, max_features)
        for name, mask in _masks(rgb).items():
            plain = extract_features(rgb, mask, max_features)
            fast = extract_features(rgb, mask, max_features, candidates=candidates)
            _assert_same(plain, fast)
            assert (len(plain) > 0) == (name != "empty"), (path.name, name)


def test_candidates_of_other_parameters_are_refused() -> None:
    rgb = _rgb(_photos()[0])
    candidates = sift_candidates(rgb, 500)
    with pytest.raises(ValueError, match="SIFT candidates"):
        extract_features(rgb, None, 1500, candidates=candidates)
    with pytest.raises(ValueError, match="SIFT candidates"):
        extract_features(rgb[:-2], None, 500, candidates=candidates)
    with pytest.raises(ValueError, match="SIFT candidates"):
        extract_features(rgb, None, 500, method="aliked", candidates=candidates)


def _evidence_arrays(evidence: PhotoEvidence) -> list[np.ndarray]:
    model = evidence.image_model
    return [
        evidence.labels,
        evidence.analysis.segments,
        evidence.analysis.vanishing_points.rotation_upright_from_cam,
        evidence.column_distance_m,
        evidence.column_top_tan_elevation,
        model.orientation_deg,
        model.facade_present,
        *(getattr(evidence.features, name) for name in FEATURE_ARRAYS),
    ]


def test_analyze_photo_beside_the_network_is_analyze_photo_alone(built_models: Path) -> None:
    """Two job threads, the network on one (SIFT and line segments beside it): one thread's evidence bit for bit."""
    alone = MethodContext(built_models, JobThreads(1))
    beside = MethodContext(built_models, JobThreads(2), onnx_threads=1)
    for path in _photos()[1:2]:
        photo = load_photo(path)
        plain, fast = analyze_photo(photo, context=alone), analyze_photo(photo, context=beside)
        assert "image_only" in fast.timings_ms and "image_only" not in plain.timings_ms
        for a, b in zip(_evidence_arrays(plain), _evidence_arrays(fast), strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
