"""The image side of one photo: segmentation, facades, facade distances, the image model and local features.

:func:`analyze_photo` is the vision stage's entry: a :class:`geoloc.photos.Photo` in, a :class:`PhotoEvidence`
out, used by the reference labelling and the query stage alike. :func:`image_model_with_identity` bins
per-column building identities into the photo's image model (the identity-aware likelihood).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from geoloc.core import labels as classes
from geoloc.core.camera import Intrinsics
from geoloc.core.context import MethodContext
from geoloc.photos.photo import Photo
from geoloc.vision.facades import ImageAnalysis, analyze_image
from geoloc.vision.features import Features, SiftCandidates, extract_features, sift_candidates
from geoloc.vision.ground import facade_base_distances, facade_top_elevations
from geoloc.vision.image_model import ImageModel, image_model_from_columns
from geoloc.vision.lines import detect_line_segments
from geoloc.vision.segmentation import load_session, segment


class ColumnIdentity(Protocol):
    """Per-column building identities (e.g. :class:`geoloc.localize.identity.IdentityMap`).

    column_prob: (M, W) probability of each of ``building_ids`` (M,) per image column.
    """

    column_prob: np.ndarray
    building_ids: np.ndarray


@dataclass
class PhotoEvidence:
    """What the image analysis found in one photo.

    labels: (H, W) class codes; analysis: lines, vanishing points and facade decomposition;
    column_distance_m: (W,) facade distance from the base line (NaN unknown, :mod:`geoloc.vision.ground`);
    image_model: the per-bin facade evidence with those distances; features: local features on
    building pixels; timings_ms per stage.
    """

    labels: np.ndarray
    analysis: ImageAnalysis
    column_distance_m: np.ndarray
    column_top_tan_elevation: np.ndarray
    image_model: ImageModel
    features: Features
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def building_mask(self) -> np.ndarray:
        """(H, W) bool: pixels labelled building."""
        mask: np.ndarray = self.labels == classes.BUILDING
        return mask


def analyze_photo(photo: Photo, labels: np.ndarray | None = None, *, context: MethodContext) -> PhotoEvidence:
    """Segmentation (unless ``labels`` are given, e.g. ground truth), facades and features of a photo.

    context: the segmentation network's folder and threads, and the job threads. When the network leaves one of
    the job's threads free (``onnx_threads`` < job threads), what needs only the image (SIFT on the whole image,
    :func:`~geoloc.vision.features.sift_candidates`, and the line segments) runs beside the network, and the
    building mask then picks its keypoints: the same features bit for bit, at the cost of the off-building
    descriptors' CPU (about 3 % of the stage's). Otherwise (the network uses every job thread: measured on 2
    cores, 0.97x the wall for 1.03x the CPU; or labels given) SIFT runs on the mask, beside the facade analysis.
    """
    timings: dict[str, float] = {}
    image_only: Callable[[], tuple[SiftCandidates, np.ndarray]] | None = None
    if labels is None and context.onnx_threads < context.threads.count:
        image_only = context.threads.beside(lambda: _image_only(photo.image_rgb, timings))
    t0 = time.perf_counter()
    if labels is None:
        labels = segment(photo.image_rgb, session=load_session(context))
        timings["segmentation"] = 1e3 * (time.perf_counter() - t0)
    candidates, segments = image_only() if image_only is not None else (None, None)
    building_mask = labels == classes.BUILDING

    def features_timed() -> Features:
        t0 = time.perf_counter()
        features = extract_features(photo.image_rgb, building_mask, candidates=candidates)
        timings["features"] = 1e3 * (time.perf_counter() - t0)
        return features

    features_result = context.threads.beside(features_timed)  # the features need only the mask: beside the facades
    t0 = time.perf_counter()
    analysis = analyze_image(photo.image_rgb, labels, photo.intrinsics, segments=segments)
    rotation = analysis.vanishing_points.rotation_upright_from_cam
    distances = facade_base_distances(labels, photo.intrinsics, rotation)
    tops = facade_top_elevations(labels, photo.intrinsics, rotation)
    model = _image_model(analysis, distances, tops, photo.intrinsics)
    timings["facades"] = 1e3 * (time.perf_counter() - t0)
    features = features_result()
    return PhotoEvidence(np.asarray(labels), analysis, distances, tops, model, features, timings)


def _image_only(image_rgb: np.ndarray, timings: dict[str, float]) -> tuple[SiftCandidates, np.ndarray]:
    """What the vision stage needs of the image alone: whole-image SIFT and line segments (timed: "image_only")."""
    t0 = time.perf_counter()
    found = sift_candidates(image_rgb), detect_line_segments(image_rgb)
    timings["image_only"] = 1e3 * (time.perf_counter() - t0)
    return found


def _image_model(
    analysis: ImageAnalysis,
    column_distance_m: np.ndarray,
    column_top_tan_elevation: np.ndarray,
    intrinsics: Intrinsics,
    identity: ColumnIdentity | None = None,
) -> ImageModel:
    deco = analysis.decomposition
    return image_model_from_columns(
        intrinsics,
        deco.column_present,
        np.nan_to_num(deco.column_theta_deg),
        column_identity_prob=None if identity is None else identity.column_prob,
        identity_building_ids=None if identity is None else identity.building_ids,
        column_distance_m=column_distance_m,
        bin_deg=analysis.image_model.bin_deg,
        column_top_tan_elevation=column_top_tan_elevation,
    )


def image_model_with_identity(evidence: PhotoEvidence, identity: ColumnIdentity, intrinsics: Intrinsics) -> ImageModel:
    """The photo's facade image model with per-column identities binned in (identity-aware likelihood)."""
    return _image_model(
        evidence.analysis, evidence.column_distance_m, evidence.column_top_tan_elevation, intrinsics, identity
    )
