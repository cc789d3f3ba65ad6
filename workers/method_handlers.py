"""The method's job handlers: label a reference, answer a query. Thin: all of the method is in ``geoloc``.

Both compute first, build their answer as the API's models (:mod:`contracts.answers`, inside
:func:`workers.handlers.answer_checked`: a malformed answer fails the job at once and nothing is stored), and
then write everything in one transaction with replace semantics, so a job that runs again after a crash
leaves the same state. A reference's arrays are stored in the format of :mod:`contracts.references`. Loaded
maps and the segmentation session are cached per worker process.

The method runs with the process's context (:func:`workers.context.worker_context`: the models folder and
the job and network threads from the settings; its first call in a process also limits numpy's BLAS and
OpenCV to ``GEOLOC_WORKER_THREADS`` threads). Importing this module only registers the handlers.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from contracts.answers import (
    BoundingBox,
    BuildingInPhoto,
    EstimatedPose,
    Heatmap,
    LatLon,
    QueryResult,
    RankedLocation,
    ReferenceLabels,
    ReferenceUsed,
)
from contracts.jobs import (
    LABEL_REFERENCE,
    LOCALIZE_QUERY,
    PLACE_SEQUENCE,
    LabelReferencePayload,
    LabelReferenceResult,
    LocalizeQueryPayload,
    LocalizeQueryResult,
    PlaceSequencePayload,
)
from contracts.queries import PriorPosition, QueryParams
from contracts.settings import data_dir, get_settings
from db import Database, database_key, sbow, transaction
from db import jobs as job_store
from db import maps as map_store
from db import queries as query_store
from db import references as reference_store
from db.files import open_store
from db.rows import ReferenceRow
from geoloc.core.geo import LocalFrame
from geoloc.localize.grid import PositionPrior
from geoloc.localize.labeling import stated_heading_prior
from geoloc.localize.query import QueryAnswer, geolocate, preset_config
from geoloc.localize.reference import LabelledReference, label_reference_photo
from geoloc.localize.retrieval import Vocabulary, default_vocabulary
from geoloc.localize.sequence.frames import FrameLabel, frame_arrays
from geoloc.maps import CityMap, MapReadOptions, load_map_cached, map_cache_dir
from geoloc.maps.places import PlaceIndex, find_place, place_index
from geoloc.photos.heading_prior import HeadingPrior, compass_heading_prior
from geoloc.photos.photo import Photo, load_photo
from geoloc.vision.evidence import analyze_photo
from geoloc.vision.model_files import vocabulary_path
from geoloc.vision.onnx_session import used_device
from geoloc.vision.segmentation import ModelNotBuiltError, network_name
from workers.context import worker_context
from workers.handlers import PermanentJobError, answer_checked, register, treat_as_permanent
from workers.metrics import observe_stages
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


def _heading_prior(
    frame: LocalFrame, heading_deg: float | None, accuracy_deg: float | None, east_m: float = 0.0, north_m: float = 0.0
) -> HeadingPrior | None:
    """The heading prior of a stored heading (deg from true north) at a local point (m) of ``frame``.

    No accuracy: a heading the uploader stated (or one stored before accuracies were), today's plain Gaussian
    (:func:`geoloc.localize.labeling.stated_heading_prior`). With one: the photo's compass, the robust prior
    (:func:`geoloc.photos.heading_prior.compass_heading_prior`: sigma floored, uniform outlier floor).
    """
    if heading_deg is None:
        return None
    if accuracy_deg is None:
        return stated_heading_prior(float(frame.heading_to_bearing(heading_deg, east_m, north_m)))
    return compass_heading_prior(heading_deg, accuracy_deg, frame, east_m, north_m)


@dataclass(frozen=True)
class AloneLabel:
    """A reference labelled alone: its photo, label, GPS tag (local m of its map) and compass prior."""

    photo: Photo
    labelled: LabelledReference
    gps_xy: tuple[float, float]
    heading_prior: HeadingPrior | None

    @property
    def column_scale(self) -> float:
        """Uploaded photo's pixels per working-size pixel (:func:`reference_labels`)."""
        return column_scale(self.photo.original_size, self.photo.intrinsics.width)

    def walk_frame(self) -> dict[str, np.ndarray]:
        """What the sequence job needs of this label (:func:`geoloc.localize.sequence.frames.frame_arrays`).

        With the uploaded photo's (width, height) as ``original_size``, stored beside the labels.
        """
        frame = frame_arrays(FrameLabel.of(self.labelled, self.photo.intrinsics))
        return frame | {"original_size": np.array(self.photo.original_size, np.int64)}


def column_scale(original_size: tuple[int, int] | np.ndarray, working_width: int) -> float:
    """Uploaded photo's pixels per working-size pixel: (width, height) uploaded over the working width."""
    return float(original_size[0] / working_width)


def reference_priors(city: CityMap, ref: ReferenceRow) -> tuple[tuple[float, float], HeadingPrior | None]:
    """A stored reference's GPS tag (local m of ``city``) and heading prior (:func:`_heading_prior`)."""
    frame = city.frame
    gps_x, gps_y = (float(v) for v in frame.to_local(ref["gps_lat"], ref["gps_lon"]))
    prior = _heading_prior(frame, ref["prior_heading_deg"], ref["prior_heading_accuracy_deg"], gps_x, gps_y)
    return (gps_x, gps_y), prior


def label_alone(city: CityMap, ref: ReferenceRow) -> AloneLabel:
    """Label a stored reference with its map, alone (the label job's method, and a sequence's first step)."""
    photo = stored_photo(ref["image_path"], ref["focal_length_35mm"])
    gps_xy, prior = reference_priors(city, ref)
    labelled = label_reference_photo(city, photo, gps_xy, heading_prior=prior, context=worker_context())
    return AloneLabel(photo, labelled, gps_xy, prior)


def reference_labels(city: CityMap, scale: float, labelled: LabelledReference, total_ms: float) -> ReferenceLabels:
    """A labelled reference's answer (pose in WGS84 and compass degrees, buildings seen, timings).

    scale: uploaded photo's pixels per working-size pixel (:func:`column_scale`).
    """
    label, frame = labelled.label, city.frame
    lat, lon = (float(v) for v in frame.to_wgs84(label.x_m, label.y_m))
    heading = float(frame.bearing_to_heading(label.yaw_deg, label.x_m, label.y_m))
    timings = {k: round(v, 1) for k, v in labelled.timings_ms.items()}
    timings["total"] = round(total_ms, 1)
    with answer_checked("reference labels"):
        return ReferenceLabels(
            estimated=EstimatedPose(lat=lat, lon=lon, heading_deg=round(heading, 2)),
            buildings_seen=_describe_buildings(city, labelled.identity.building_extents(), scale),
            timings=timings,
        )


def save_labels(
    db: Database,
    reference_id: int,
    labelled: LabelledReference,
    labels: ReferenceLabels,
    placement: str,
    walk_frame: dict[str, np.ndarray] | None = None,
) -> None:
    """Store a labelled reference's arrays and answer (inside the caller's transaction); it is ``done``.

    placement: ``alone`` (its own label) or ``sequence`` (its walk's joint placement); walk_frame: its label
    alone for the sequence job (:meth:`AloneLabel.walk_frame`), for a reference that may join a walk.
    """
    stored = labels.model_dump(mode="json")
    estimated = labels.estimated
    reference_store.save_labels(db, reference_id, labelled.label_arrays(), walk_frame)
    reference_store.save_keypoints(db, reference_id, labelled.keypoints())
    reference_store.update_reference_result(
        db,
        reference_id,
        status="done",
        estimated_lat=estimated.lat,
        estimated_lon=estimated.lon,
        estimated_heading_deg=estimated.heading_deg,
        buildings_seen=stored["buildings_seen"],
        timings=stored["timings"],
    )
    reference_store.set_reference_placement(db, reference_id, placement)


@register(LABEL_REFERENCE, LabelReferencePayload)
def label_reference(db: Database, payload: LabelReferencePayload) -> LabelReferenceResult:
    """Label a reference with the map, extract and index its features, store its pose and identities.

    A reference that may belong to a walk (:func:`db.references.may_join_walk`) then queues the map's sequence job
    (:mod:`workers.sequence_handlers`) unless one already waits: it places each walk once all of it is labelled.
    """
    reference_id, map_id = payload.reference_id, payload.map_id
    ref = reference_store.get_reference(db, reference_id)
    if ref is None:
        raise PermanentJobError(f"reference {reference_id} no longer exists")
    city = city_map_for(db, map_id)
    t0 = time.perf_counter()
    alone = label_alone(city, ref)
    labelled = alone.labelled
    vocabulary = vocabulary_for(db, map_id)
    words = vocabulary.words(labelled.cues.features.descriptors)
    labels = reference_labels(city, alone.column_scale, labelled, 1e3 * (time.perf_counter() - t0))
    observe_stages(LABEL_REFERENCE, labelled.timings_ms)
    walker = reference_store.may_join_walk(ref)
    with transaction(db):
        if reference_store.get_reference(db, reference_id) is None:
            raise PermanentJobError(f"reference {reference_id} was deleted while it was labelled")
        save_labels(db, reference_id, labelled, labels, "alone", alone.walk_frame() if walker else None)
        sbow.index_reference(db, map_id, reference_id, words, np.ones(len(words)))
        if walker:
            # One waiting sequence job per map is enough: it places every walk of the map that changed.
            db.lock(f"geoloc:place-sequence:{map_id}")
            if not job_store.has_queued_job(db, PLACE_SEQUENCE, map_id):
                sequence_job = PlaceSequencePayload(reference_id=reference_id, map_id=map_id)
                job_store.enqueue_job(db, PLACE_SEQUENCE, sequence_job, map_id=map_id)
    assert labels.estimated is not None and labels.estimated.heading_deg is not None
    return LabelReferenceResult(
        reference_id=reference_id, heading_deg=labels.estimated.heading_deg, buildings=len(labels.buildings_seen)
    )


def _describe_buildings(
    city: CityMap, extents: Sequence[Mapping[str, Any]], column_scale: float
) -> list[BuildingInPhoto]:
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


def query_priors(
    db: Database, map_id: int, city: CityMap, params: QueryParams
) -> tuple[PositionPrior | None, HeadingPrior | None]:
    """A query's stored priors in the map's frame: position (:func:`position_prior_for`), heading."""
    position_prior = None if params.prior is None else position_prior_for(db, map_id, city, params.prior)
    heading = _heading_prior(city.frame, params.prior_heading_deg, params.prior_heading_accuracy_deg)
    return position_prior, heading


@register(LOCALIZE_QUERY, LocalizeQueryPayload)
def localize_query(db: Database, payload: LocalizeQueryPayload) -> LocalizeQueryResult:
    """Answer a query with the query stage (:func:`geoloc.localize.query.geolocate`); store the JSON answer."""
    context = worker_context()
    query_id, map_id = payload.query_id, payload.map_id
    query = query_store.get_query(db, query_id)
    if query is None:
        raise PermanentJobError(f"query {query_id} no longer exists")
    params = query["params"]
    city = city_map_for(db, map_id)
    t0 = time.perf_counter()
    if query["image_path"] is None:
        raise PermanentJobError(f"query {query_id} has no stored photo")
    photo = stored_photo(query["image_path"], params.focal_length_35mm)
    evidence = analyze_photo(photo, context=context)
    position_prior, heading_prior = query_priors(db, map_id, city, params)
    answer = geolocate(
        city,
        photo,
        evidence,
        reference_store_for(db, map_id),
        vocabulary_for(db, map_id),
        preset_config(params.preset_name, k=params.k),
        position_prior=position_prior,
        heading_prior=heading_prior,
        top_n=params.top_n,
        context=context,
    )
    answer.search["preset"] = params.preset_name  # beside search.config: which preset chose it
    answer.search["device"] = used_device(context.device)  # where segmentation and ALIKED ran: cpu or cuda
    answer.search["segmentation"] = network_name(context)  # which network (its input size) labelled the photo
    timings_ms = {
        **{k: round(v, 1) for k, v in answer.timings_ms.items()},
        "total": round(1e3 * (time.perf_counter() - t0), 1),
    }
    observe_stages(LOCALIZE_QUERY, answer.timings_ms)
    with answer_checked("query answer"):
        result = query_result(city, photo, answer, timings_ms)
    with transaction(db):
        if not query_store.update_query_result(db, query_id, status="done", result=result.model_dump(mode="json")):
            raise PermanentJobError(f"query {query_id} was deleted while it was answered")
    return LocalizeQueryResult(query_id=query_id, locations=len(result.locations))


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
        buildings=_describe_buildings(city, answer.buildings, scale),
        references=[
            ReferenceUsed(reference_id=r["reference_id"], score=r["score"], matches=r["matches"], inliers=r["inliers"])
            for r in answer.references
        ],
        search=answer.search,
        camera={
            "hfov_deg": round(photo.intrinsics.hfov_deg, 2),
            "focal_source": photo.intrinsics.source,
            "width": photo.original_size[0],
            "height": photo.original_size[1],
        },
        timings_ms=timings_ms,
    )
