"""The method end to end on photos: one function per product step, shared by the evaluation and the workers.

- :func:`load_photo`: decode a JPEG/PNG, apply its EXIF orientation, read GPS and focal length,
  resize to the working size, intrinsics from EXIF (or a default field of view).
- :func:`analyze_photo`: segmentation, lines, vanishing points, facade image model, local features
  on building pixels.
- :func:`label_reference_photo`: a geo-tagged photo -> heading, corrected position, per-column
  building identities (greedy and marginalised) and its keypoints' identity probabilities.
- the query stage (retrieval, transfer, anchored pose, likelihood) is :func:`geoloc.localize.query.geolocate`.

Positions in and out of this module are local metres of the map's frame; converting to WGS84 and
compass headings is the caller's (``city_map.frame``).
"""

from __future__ import annotations

import io
import time
from collections.abc import Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageOps

from geoloc.core import labels as classes
from geoloc.core.camera import DEFAULT_HFOV_DEG, Intrinsics, intrinsics_from_focal
from geoloc.core.parallel import run_beside
from geoloc.localize.anchors import CameraPose, MapAnchors, anchor_keypoints
from geoloc.localize.identity import IdentityMap
from geoloc.localize.labeling import (
    DEFAULT_GPS_SIGMA_M,
    DEFAULT_REFERENCE_CELL_M,
    DEFAULT_REFERENCE_HALF_SIZE_M,
    ReferenceLabel,
    label_reference,
)
from geoloc.localize.likelihood import DEFAULT_SIGMA_M
from geoloc.localize.posterior import DEFAULT_SHARPNESS
from geoloc.maps import CityMap
from geoloc.photos.exif import ExifInfo, read_exif
from geoloc.vision.facades import ImageAnalysis, analyze_image
from geoloc.vision.features import Features, extract_features
from geoloc.vision.ground import DEFAULT_CAMERA_HEIGHT_M, facade_base_distances, facade_top_elevations
from geoloc.vision.image_model import ImageModel, image_model_from_columns

if TYPE_CHECKING:
    from geoloc.localize.query import StoredReference

WORKING_MAX_SIDE = 1024
"""Photos are analysed at most this many pixels on their long side (phone photos are 3-12 MP)."""


@dataclass
class Photo:
    """A decoded photo at working size. image_rgb: (H, W, 3) uint8; intrinsics of that image."""

    image_rgb: np.ndarray
    intrinsics: Intrinsics
    exif: ExifInfo
    original_size: tuple[int, int]  # (width, height) after EXIF orientation, before resizing

    @property
    def gps(self) -> tuple[float, float] | None:
        """(lat, lon) degrees from EXIF, or None when the photo carries no GPS."""
        lat, lon = self.exif.lat, self.exif.lon
        return None if lat is None or lon is None else (lat, lon)


def load_photo(
    source: bytes | str | Path,
    *,
    focal_35mm: float | None = None,
    default_hfov_deg: float = DEFAULT_HFOV_DEG,
    max_side: int = WORKING_MAX_SIDE,
) -> Photo:
    """Decode a photo (bytes or path) for analysis.

    ``focal_35mm`` overrides the EXIF focal length. Raises ``ValueError`` for data that is not an
    image Pillow can decode.
    """
    data = source if isinstance(source, bytes) else Path(source).read_bytes()
    try:
        image: Image.Image = Image.open(io.BytesIO(data))
        image.load()
    except Exception as exc:  # Pillow raises many types for bad data
        raise ValueError(f"not a decodable image: {exc}") from exc
    exif = read_exif(data)
    image = ImageOps.exif_transpose(image).convert("RGB")
    width, height = image.size
    intrinsics = intrinsics_from_focal(
        width,
        height,
        focal_35mm=focal_35mm or exif.focal_35mm,
        default_hfov_deg=default_hfov_deg,
    )
    scale = min(1.0, max_side / max(width, height))
    if scale < 1.0:
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        image = image.resize(size, Image.Resampling.LANCZOS)
        intrinsics = intrinsics.scaled(*size)
    return Photo(np.asarray(image), intrinsics, exif, (width, height))


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


def analyze_photo(photo: Photo, labels: np.ndarray | None = None) -> PhotoEvidence:
    """Segmentation (unless ``labels`` are given, e.g. ground truth), facades and features of a photo."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if labels is None:
        from geoloc.vision.segmentation import segment

        labels = segment(photo.image_rgb)
        timings["segmentation"] = 1e3 * (time.perf_counter() - t0)
    building_mask = labels == classes.BUILDING

    def features_timed() -> Features:
        t0 = time.perf_counter()
        features = extract_features(photo.image_rgb, building_mask)
        timings["features"] = 1e3 * (time.perf_counter() - t0)
        return features

    features_result = run_beside(features_timed)  # the features need only the mask: beside the facades
    t0 = time.perf_counter()
    analysis = analyze_image(photo.image_rgb, labels, photo.intrinsics)
    rotation = analysis.vanishing_points.rotation_upright_from_cam
    distances = facade_base_distances(labels, photo.intrinsics, rotation)
    tops = facade_top_elevations(labels, photo.intrinsics, rotation)
    model = _image_model(analysis, distances, tops, photo.intrinsics)
    timings["facades"] = 1e3 * (time.perf_counter() - t0)
    features = features_result()
    return PhotoEvidence(np.asarray(labels), analysis, distances, tops, model, features, timings)


def _image_model(
    analysis: ImageAnalysis,
    column_distance_m: np.ndarray,
    column_top_tan_elevation: np.ndarray,
    intrinsics: Intrinsics,
    identity: IdentityMap | None = None,
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


@dataclass
class LabelledReference:
    """A reference photo labelled with the map: its pose, identities and keypoint identities.

    identity: the identity map used downstream (marginalised by default);
    keypoint_identity: (N, M) identity probabilities of ``evidence.features`` over ``identity.building_ids``;
    anchors: the keypoints' 3D points on the map's facades seen from the label's pose (:mod:`geoloc.localize.anchors`);
    alternative_anchors: the same from the runner-up pose when the label is ambiguous
    (:attr:`geoloc.localize.labeling.ReferenceLabel.is_ambiguous`), else None: a query that sees the scene from
    elsewhere can tell which of the two is right.
    """

    label: ReferenceLabel
    evidence: PhotoEvidence
    identity: IdentityMap
    keypoint_identity: np.ndarray
    anchors: MapAnchors
    timings_ms: dict[str, float] = field(default_factory=dict)
    alternative_anchors: MapAnchors | None = None

    @property
    def camera_pose(self) -> CameraPose:
        """The labelled pose as a camera pose (pitch and roll from the photo's vertical vanishing point)."""
        return _camera_pose(self.label, self.evidence)


def _camera_pose(label: ReferenceLabel, evidence: PhotoEvidence, alternative: bool = False) -> CameraPose:
    rotation = evidence.analysis.vanishing_points.rotation_upright_from_cam
    if alternative and label.alternative is not None:
        alt = label.alternative
        return CameraPose(alt.x_m, alt.y_m, alt.yaw_deg, DEFAULT_CAMERA_HEIGHT_M, rotation)
    return CameraPose(label.x_m, label.y_m, label.yaw_deg, DEFAULT_CAMERA_HEIGHT_M, rotation)


@dataclass(frozen=True)
class LabelOptions:
    """How :func:`label_reference_photo` labels a reference (:func:`geoloc.localize.labeling.label_reference`).

    The defaults are ``label_reference``'s (a test checks that they agree). gps_sigma_m: Gaussian prior on the
    position around the GPS tag (m; None: uniform). sharpness: pose weights are likelihood ** sharpness.
    cell_m, half_size_m: the pose grid around the tag (m). n_yaws: yaws sampled over 360 deg. sigma_m,
    normalization, use_skyline: the pose likelihood's (:func:`geoloc.localize.likelihood.pose_likelihood`).
    n_modes: grid modes refined continuously.
    """

    gps_sigma_m: float | None = DEFAULT_GPS_SIGMA_M
    sharpness: float = DEFAULT_SHARPNESS
    cell_m: float = DEFAULT_REFERENCE_CELL_M
    half_size_m: float = DEFAULT_REFERENCE_HALF_SIZE_M
    n_yaws: int = 120
    sigma_m: float = DEFAULT_SIGMA_M
    normalization: str = "weighted"
    use_skyline: bool = True
    n_modes: int = 3


def label_reference_photo(
    city_map: CityMap,
    photo: Photo,
    gps_xy: tuple[float, float],
    *,
    prior_yaw_deg: float | None = None,
    evidence: PhotoEvidence | None = None,
    strategy: str = "marginalized",
    options: LabelOptions | None = None,
) -> LabelledReference:
    """Label a geo-tagged reference photo (GPS tag in local metres) with the map.

    prior_yaw_deg: optional heading prior (local bearing, deg). evidence: the photo's analysis when already
    done. strategy: "marginalized" (default, the paper's better one) or "greedy" chooses which identity
    map the keypoints carry. options: the labelling's tuning (default :class:`LabelOptions`).
    """
    if strategy not in ("marginalized", "greedy"):
        raise ValueError(f"strategy must be 'marginalized' or 'greedy', got {strategy!r}")
    options = options or LabelOptions()
    evidence = evidence or analyze_photo(photo)
    t0 = time.perf_counter()
    label = label_reference(
        city_map,
        evidence.image_model,
        evidence.building_mask,
        photo.intrinsics,
        gps_xy,
        prior_yaw_deg=prior_yaw_deg,
        gps_sigma_m=options.gps_sigma_m,
        sharpness=options.sharpness,
        cell_m=options.cell_m,
        half_size_m=options.half_size_m,
        n_yaws=options.n_yaws,
        sigma_m=options.sigma_m,
        normalization=options.normalization,
        use_skyline=options.use_skyline,
        n_modes=options.n_modes,
    )
    identity = label.marginalized if strategy == "marginalized" else label.greedy
    keypoint_identity = identity.probabilities_at(evidence.features.xy)
    timings = dict(evidence.timings_ms, labeling=1e3 * (time.perf_counter() - t0))
    t0 = time.perf_counter()
    anchors = anchor_keypoints(city_map, _camera_pose(label, evidence), photo.intrinsics, evidence.features.xy)
    alternative = None
    if label.is_ambiguous:
        pose = _camera_pose(label, evidence, alternative=True)
        alternative = anchor_keypoints(city_map, pose, photo.intrinsics, evidence.features.xy)
    timings["anchors"] = 1e3 * (time.perf_counter() - t0)
    return LabelledReference(label, evidence, identity, keypoint_identity, anchors, timings, alternative)


def stored_reference(reference_id: Hashable, labelled: LabelledReference) -> StoredReference:
    """What the query stage keeps of a labelled reference (:class:`geoloc.localize.query.StoredReference`)."""
    from geoloc.localize.query import StoredReference

    return StoredReference(
        reference_id,
        labelled.evidence.features,
        labelled.keypoint_identity,
        labelled.identity.building_ids,
        labelled.anchors,
        labelled.label.position_covariance,
        np.array([labelled.label.x_m, labelled.label.y_m]),
        labelled.alternative_anchors,
    )


def image_model_with_identity(evidence: PhotoEvidence, identity: IdentityMap, intrinsics: Intrinsics) -> ImageModel:
    """The photo's facade image model with per-column identities binned in (identity-aware likelihood)."""
    return _image_model(
        evidence.analysis, evidence.column_distance_m, evidence.column_top_tan_elevation, intrinsics, identity
    )
