"""What the method's job handlers share: their inputs, priors and the parts of their answers.

The inputs: a map's loaded form and its places (cached per worker process), a stored photo, the map's visual
vocabulary, its references for the query stage. The priors, in the map's local frame (East-North metres, yaw from
the frame's north): a query's position and heading, a reference's GPS tag and heading. The answers' parts: the
buildings seen (columns in the uploaded photo's pixels) and a query's answer in WGS84 and compass headings.
Used by :mod:`workers.reference_handlers`, :mod:`workers.sequence_handlers`, :mod:`workers.query_handlers` and
:mod:`workers.track_handlers`; the method runs with the process's context (:func:`workers.context.worker_context`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from functools import lru_cache
from typing import cast

import numpy as np

from contracts.answers import (
    BoundingBox,
    BuildingInPhoto,
    CameraUsed,
    Heatmap,
    LatLon,
    QueryResult,
    RankedLocation,
    ReferenceUsed,
)
from contracts.queries import PriorPosition, QueryParams
from contracts.settings import data_dir, get_settings
from db import Database, database_key, sbow, transaction
from db import maps as map_store
from db.files import open_store
from db.rows import ReferenceRow
from geoloc.localize.grid import PositionPrior
from geoloc.localize.identity import BuildingExtent
from geoloc.localize.query import QueryAnswer
from geoloc.localize.reference import heading_prior_at
from geoloc.localize.retrieval import Vocabulary, default_vocabulary
from geoloc.maps import CityMap, MapReadOptions, load_map_cached, map_cache_dir
from geoloc.maps.places import PlaceIndex, find_place, place_index
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo, load_photo
from geoloc.vision.model_files import vocabulary_path
from geoloc.vision.segmentation import ModelNotBuiltError
from workers.context import worker_context
from workers.handlers import PermanentJobError, treat_as_permanent
from workers.reference_store import DatabaseReferenceStore
from workers.sbow_files import sbow_cache_dir

treat_as_permanent(ModelNotBuiltError)  # a missing model stays missing until `geoloc models build` runs


@lru_cache(maxsize=4)
def _city_map(source_path: str, sha256: str, read_options: str) -> CityMap:
    """The map's CityMap, loaded once per worker process (keyed by file, checksum and read options).

    Loaded from the copy the API cached at upload; parsed from the source only when that copy is
    missing.
    """
    options = MapReadOptions.from_dict(json.loads(read_options))
    source = open_store(get_settings().file_store_dir).local_path(source_path)
    return load_map_cached(source, map_cache_dir(data_dir()), options, sha256=sha256)


MAX_REPORTED_RADIUS_M = 100_000.0
"""Uncertainty radii are capped here (an answer with no evidence at all has an infinite one)."""


@lru_cache(maxsize=4)
def _place_index(source_path: str, sha256: str, read_options: str) -> PlaceIndex:
    """The places of a map (:func:`geoloc.maps.places.place_index`), built once per worker process."""
    return place_index(_city_map(source_path, sha256, read_options))


def _map_key(db: Database, map_id: int) -> tuple[str, str, str]:
    """What identifies a map's loaded forms (file, checksum, read options); a permanent job error if it is gone."""
    row = map_store.get_map(db, map_id)
    if row is None:
        raise PermanentJobError(f"map {map_id} no longer exists")
    return row["source_path"], row["sha256"], json.dumps(row["read_options"], sort_keys=True)


def city_map_for(db: Database, map_id: int) -> CityMap:
    """The CityMap of map ``map_id`` (cached per process); a permanent job error if the map is gone."""
    return _city_map(*_map_key(db, map_id))


def reference_store_for(db: Database, map_id: int) -> DatabaseReferenceStore:
    """The map's references for the query stage, on the machine's shared SBoW base (:mod:`workers.sbow_share`)."""
    return DatabaseReferenceStore(db, map_id, shared_dir=sbow_cache_dir(data_dir()))


def position_prior_for(db: Database, map_id: int, city: CityMap, prior: PriorPosition) -> PositionPrior:
    """A query's position prior in the map's frame: near the named place's shape, else the stated disc.

    A place's radius stored with the query is the place's own unless the request gave one (then it is the
    distance from the place's shape, :meth:`PositionPrior.of_place`).
    """
    x, y = (float(v) for v in city.frame.to_local(prior.lat, prior.lon))
    if prior.source == "place" and prior.place is not None and prior.place_kind is not None:
        place = find_place(_place_index(*_map_key(db, map_id)), prior.place, prior.place_kind, x, y)
        if place is not None:
            return PositionPrior.of_place(place, None if prior.radius_m == place.radius_m else prior.radius_m)
    return PositionPrior.from_radius(x, y, float(prior.radius_m))


def stored_photo(relative_path: str, focal_35mm: float | None) -> Photo:
    """A stored photo (its key in the file store); an unreadable one fails the job for good."""
    try:
        return load_photo(open_store(get_settings().file_store_dir).local_path(relative_path), focal_35mm=focal_35mm)
    except (OSError, ValueError) as exc:
        raise PermanentJobError(f"cannot read the stored photo: {exc}") from exc


CACHED_VOCABULARIES = 8
"""Decoded vocabularies kept per process (2 MB each with 4,096 words)."""
_VOCABULARIES: dict[tuple[str, int], tuple[float, Vocabulary]] = {}
"""Decoded vocabularies by (database, map id), with the stored row's time they were read at."""


def vocabulary_for(db: Database, map_id: int) -> Vocabulary:
    """The map's visual vocabulary: the default one, stored with the map the first time it is needed.

    Decoded once per process and kept while the stored row is unchanged.
    """
    key = (database_key(db), map_id)
    stamp = sbow.vocabulary_stamp(db, map_id)
    cached = _VOCABULARIES.get(key)
    if stamp is not None and cached is not None and cached[0] == stamp:
        return cached[1]
    stored = sbow.load_vocabulary(db, map_id)
    if stamp is not None and stored is not None:
        _VOCABULARIES.pop(key, None)
        _VOCABULARIES[key] = (stamp, Vocabulary(stored["centers"]))
        while len(_VOCABULARIES) > CACHED_VOCABULARIES:
            del _VOCABULARIES[next(iter(_VOCABULARIES))]  # the one read longest ago
        return _VOCABULARIES[key][1]
    models = worker_context().models_dir
    if not vocabulary_path(models).exists():  # built by `geoloc models build`, never inside a job (minutes of work)
        raise PermanentJobError(f"SBoW vocabulary not found at {vocabulary_path(models)}; run `geoloc models build`")
    vocabulary = default_vocabulary(models)
    with transaction(db):
        if sbow.load_vocabulary(db, map_id) is None:
            sbow.save_vocabulary(db, map_id, {"centers": vocabulary.centroids})
    return vocabulary


def column_scale(original_size: tuple[int, int] | np.ndarray, working_width: int) -> float:
    """Uploaded photo's pixels per working-size pixel: (width, height) uploaded over the working width."""
    return float(original_size[0] / working_width)


def reference_priors(city: CityMap, ref: ReferenceRow) -> tuple[tuple[float, float], HeadingPrior | None]:
    """A stored reference's GPS tag (local m of ``city``) and heading prior (:func:`heading_prior_at`)."""
    frame = city.frame
    gps_x, gps_y = (float(v) for v in frame.to_local(ref["gps_lat"], ref["gps_lon"]))
    prior = heading_prior_at(frame, ref["prior_heading_deg"], ref["prior_heading_accuracy_deg"], gps_x, gps_y)
    return (gps_x, gps_y), prior


def query_priors(
    db: Database, map_id: int, city: CityMap, params: QueryParams
) -> tuple[PositionPrior | None, HeadingPrior | None]:
    """A query's stored priors in the map's frame: position (:func:`position_prior_for`), heading."""
    position_prior = None if params.prior is None else position_prior_for(db, map_id, city, params.prior)
    heading = heading_prior_at(city.frame, params.prior_heading_deg, params.prior_heading_accuracy_deg)
    return position_prior, heading


def describe_buildings(city: CityMap, extents: Sequence[BuildingExtent], column_scale: float) -> list[BuildingInPhoto]:
    """Building extents with their OSM ids and names, columns in the uploaded photo's pixels."""
    out = []
    for entry in extents:
        building = city.buildings[entry["building_id"]]
        out.append(
            BuildingInPhoto(
                building_id=entry["building_id"],
                osm_id=building.osm_id,
                name=building.name,
                pixel_share=round(entry["pixel_share"], 4),
                x_start=int(entry["x_start"] * column_scale),
                x_end=int(round((entry["x_end"] + 1) * column_scale)) - 1,
                probability=round(entry["probability"], 4),
            )
        )
    return out


def query_result(city: CityMap, photo: Photo, answer: QueryAnswer, timings_ms: dict[str, float]) -> QueryResult:
    """The answer (WGS84 and compass headings) of a :class:`geoloc.localize.query.QueryAnswer`."""
    frame = city.frame
    loc = answer.localization
    locations = []
    for pose in answer.poses:
        lat, lon = (float(v) for v in frame.to_wgs84(pose.x_m, pose.y_m))
        heading = float(frame.bearing_to_heading(pose.yaw_deg, pose.x_m, pose.y_m)) % 360.0
        locations.append(
            RankedLocation(
                rank=pose.rank,
                lat=round(lat, 7),
                lon=round(lon, 7),
                heading_deg=round(heading, 2),
                probability=round(pose.probability, 6),
                uncertainty_radius_m=round(min(pose.uncertainty_radius_m, MAX_REPORTED_RADIUS_M), 1),
                source=pose.source,
                inliers=int(pose.inliers),
            )
        )
    grid = loc.grid
    min_x, min_y, max_x, max_y = grid.bounds_m
    corner_lat, corner_lon = frame.to_wgs84(np.array([min_x, max_x]), np.array([min_y, max_y]))
    origin_lat, origin_lon = (float(v) for v in frame.to_wgs84(*grid.origin_m))
    heatmap = Heatmap(
        origin=LatLon(lat=round(origin_lat, 7), lon=round(origin_lon, 7)),
        origin_local_m=(round(grid.origin_m[0], 2), round(grid.origin_m[1], 2)),
        cell_m=grid.cell_m,
        shape=(grid.shape[0], grid.shape[1]),
        bounds=BoundingBox(
            min_lat=round(float(corner_lat.min()), 7),
            min_lon=round(float(corner_lon.min()), 7),
            max_lat=round(float(corner_lat.max()), 7),
            max_lon=round(float(corner_lon.max()), 7),
        ),
        values=np.round(loc.heatmap, 6).tolist(),
    )
    scale = column_scale(photo.original_size, photo.intrinsics.width)
    return QueryResult(
        locations=locations,
        heatmap=heatmap,
        buildings=describe_buildings(city, answer.buildings, scale),
        references=[
            # the service's reference store keys references by their integer ids
            ReferenceUsed(
                reference_id=cast(int, r.reference_id), score=r.score, matches=r.n_matches, inliers=r.n_inliers
            )
            for r in answer.references
        ],
        search=answer.search,
        camera=CameraUsed(
            hfov_deg=round(photo.intrinsics.hfov_deg, 2),
            focal_source=photo.intrinsics.source,
            width=photo.original_size[0],
            height=photo.original_size[1],
        ),
        timings_ms=timings_ms,
    )
