"""The method end to end on photos: one function per product step, shared by the evaluation and the workers.

- :func:`load_photo`: decode a JPEG/PNG, apply its EXIF orientation, read GPS and focal length,
  resize to the working size, intrinsics from EXIF (or a default field of view).
- :func:`analyze_photo`: segmentation, lines, vanishing points, facade image model, local features
  on building pixels.
- :func:`label_reference_photo`: a geo-tagged photo -> heading, corrected position, per-column
  building identities (greedy and marginalised) and its keypoints' identity probabilities.
- :func:`geolocate_query`: a photo + retrieved references -> transferred identities, probability
  map, ranked poses and the buildings in the photo.

Positions in and out of this module are local metres of the map's frame; converting to WGS84 and
compass headings is the caller's (``city_map.frame``).
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

from geoloc import labels as classes
from geoloc.camera import DEFAULT_HFOV_DEG, Intrinsics, intrinsics_from_focal
from geoloc.exif import ExifInfo, read_exif
from geoloc.facades import ImageAnalysis, analyze_image
from geoloc.features import Features, extract_features
from geoloc.ground import facade_base_distances
from geoloc.identity import IdentityMap
from geoloc.image_model import ImageModel, image_model_from_columns
from geoloc.labeling import ReferenceLabel, label_reference
from geoloc.localize import Localization, PositionPrior, localize
from geoloc.osm import CityMap

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
        return (self.exif.lat, self.exif.lon) if self.exif.has_gps else None


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
        image = Image.open(io.BytesIO(data))
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
    column_distance_m: (W,) facade distance from the base line (NaN unknown, :mod:`geoloc.ground`);
    image_model: the per-bin facade evidence with those distances; features: local features on
    building pixels; timings_ms per stage.
    """

    labels: np.ndarray
    analysis: ImageAnalysis
    column_distance_m: np.ndarray
    image_model: ImageModel
    features: Features
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def building_mask(self) -> np.ndarray:
        return self.labels == classes.BUILDING


def analyze_photo(photo: Photo, labels: np.ndarray | None = None) -> PhotoEvidence:
    """Segmentation (unless ``labels`` are given, e.g. ground truth), facades and features of a photo."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if labels is None:
        from geoloc.segmentation import segment

        labels = segment(photo.image_rgb)
        timings["segmentation"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    analysis = analyze_image(photo.image_rgb, labels, photo.intrinsics)
    distances = facade_base_distances(labels, photo.intrinsics, analysis.vanishing_points.rotation_upright_from_cam)
    model = _image_model(analysis, distances, photo.intrinsics)
    timings["facades"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    features = extract_features(photo.image_rgb, labels == classes.BUILDING)
    timings["features"] = 1e3 * (time.perf_counter() - t0)
    return PhotoEvidence(np.asarray(labels), analysis, distances, model, features, timings)


def _image_model(
    analysis: ImageAnalysis, column_distance_m: np.ndarray, intrinsics: Intrinsics, identity: IdentityMap | None = None
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
    )


@dataclass
class LabelledReference:
    """A reference photo labelled with the map: its pose, identities and keypoint identities.

    identity: the identity map used downstream (marginalised by default);
    keypoint_identity: (N, M) identity probabilities of ``evidence.features`` over ``identity.building_ids``.
    """

    label: ReferenceLabel
    evidence: PhotoEvidence
    identity: IdentityMap
    keypoint_identity: np.ndarray
    timings_ms: dict[str, float] = field(default_factory=dict)


def label_reference_photo(
    city_map: CityMap,
    photo: Photo,
    gps_xy: tuple[float, float],
    *,
    prior_yaw_deg: float | None = None,
    evidence: PhotoEvidence | None = None,
    strategy: str = "marginalized",
    **label_options: float,
) -> LabelledReference:
    """Label a geo-tagged reference photo (GPS tag in local metres) with the map.

    strategy: "marginalized" (default, the paper's better one) or "greedy" chooses which identity
    map the keypoints carry. ``label_options`` go to :func:`geoloc.labeling.label_reference`.
    """
    if strategy not in ("marginalized", "greedy"):
        raise ValueError(f"strategy must be 'marginalized' or 'greedy', got {strategy!r}")
    evidence = evidence or analyze_photo(photo)
    t0 = time.perf_counter()
    label = label_reference(
        city_map,
        evidence.image_model,
        evidence.building_mask,
        photo.intrinsics,
        gps_xy,
        prior_yaw_deg=prior_yaw_deg,
        **label_options,
    )
    identity = label.marginalized if strategy == "marginalized" else label.greedy
    keypoint_identity = identity.probabilities_at(evidence.features.xy)
    timings = dict(evidence.timings_ms, labeling=1e3 * (time.perf_counter() - t0))
    return LabelledReference(label, evidence, identity, keypoint_identity, timings)


def image_model_with_identity(evidence: PhotoEvidence, identity: IdentityMap, intrinsics: Intrinsics) -> ImageModel:
    """The photo's facade image model with per-column identities binned in (identity-aware likelihood)."""
    return _image_model(evidence.analysis, evidence.column_distance_m, intrinsics, identity)


@dataclass
class QueryAnswer:
    """A geolocated query: where (localization), what (identity) and from which references."""

    localization: Localization
    identity: IdentityMap
    buildings: list[dict]
    references: list[dict]
    timings_ms: dict[str, float] = field(default_factory=dict)


def geolocate_query(
    city_map: CityMap,
    photo: Photo,
    references: list,
    *,
    evidence: PhotoEvidence | None = None,
    use_identity: bool = True,
    position_prior: PositionPrior | None = None,
    prior_yaw_deg: float | None = None,
    top_n: int = 10,
    **localize_options: float,
) -> QueryAnswer:
    """Geolocate a query photo given its retrieved references.

    references: :class:`geoloc.transfer.ReferenceEvidence` of the top-k retrieved references (their
    features and keypoint identities). With ``use_identity=False`` the identities still choose the
    search region but the likelihood is geometry-only (the paper's baseline).
    """
    from geoloc.transfer import transfer_identities

    evidence = evidence or analyze_photo(photo)
    timings = dict(evidence.timings_ms)
    t0 = time.perf_counter()
    transferred = transfer_identities(evidence.features, evidence.building_mask, references)
    identity = transferred.identity
    timings["transfer"] = 1e3 * (time.perf_counter() - t0)
    model = image_model_with_identity(evidence, identity, photo.intrinsics)
    t0 = time.perf_counter()
    localization = localize(
        city_map,
        model,
        use_identity=use_identity,
        position_prior=position_prior,
        prior_yaw_deg=prior_yaw_deg,
        top_n=top_n,
        **localize_options,
    )
    timings["localize"] = 1e3 * (time.perf_counter() - t0)
    timings.update({f"localize_{k}": v for k, v in localization.timings_ms.items()})
    buildings = identity.building_extents()
    for entry in buildings:
        building = city_map.buildings[entry["building_id"]]
        entry.update(osm_id=building.osm_id, name=building.name)
    return QueryAnswer(localization, identity, buildings, [r.as_dict() for r in transferred.references], timings)
