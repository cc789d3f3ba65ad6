"""The query-upload use-case: a photo to locate, its prior position checked against the map, its job queued.

:class:`QueryIntake` is the photo-upload use-case of :class:`service.intake.PhotoIntake` for a query: the form's
bounds, the prior position (the request's lat/lon, else a named place, else the photo's EXIF GPS unless turned
off) inside the map's margin, and the ``localize_query`` job. A track's frames go through the same checks
(:mod:`service.intake_tracks`). Routes call this module; it imports no route module.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from contracts.jobs import LOCALIZE_QUERY, LocalizeQueryPayload
from contracts.queries import DEFAULT_PRIOR_RADIUS_M, PriorPosition, QueryParams, QueryPreset, gps_prior_radius_m
from contracts.settings import Settings
from db import Database
from db import queries as query_store
from db.files import FileStore
from db.rows import MapRow
from service.bounds import check_bounds
from service.errors import ApiError
from service.images import ImageInfo, distance_outside_bbox_m
from service.intake import PhotoIntake
from service.places import resolve_form_place
from service.uploads import ReceivedFile
from workers.broker import JobPublisher


@dataclass(frozen=True)
class QueryForm:
    """The form fields of a query (checked by :class:`QueryIntake`)."""

    lat: float | None
    lon: float | None
    radius_m: float | None
    heading_deg: float | None
    use_exif_gps: bool
    place: str | None
    focal_length_35mm: float | None
    top_n: int
    k: int
    wait_s: float
    preset: QueryPreset | None = None


class QueryIntake(PhotoIntake):
    """A query upload: its prior position (request, else EXIF GPS unless turned off) inside the map."""

    folder = "queries"
    kind = LOCALIZE_QUERY

    def __init__(self, settings: Settings, store: FileStore, publisher: JobPublisher, form: QueryForm) -> None:
        super().__init__(settings, store, publisher)
        self.form = form
        self.prior: PriorPosition | None = None

    def check_form(self) -> None:
        """Check every number's bounds and that lat and lon come together."""
        form = self.form
        for name in ("lat", "lon", "radius_m", "heading_deg", "focal_length_35mm", "top_n", "k", "wait_s"):
            check_bounds(name, getattr(form, name))
        if (form.lat is None) != (form.lon is None):
            raise ApiError(422, "invalid_request", "give both lat and lon for a prior position, or neither")
        if form.lat is not None and form.place is not None:
            raise ApiError(422, "invalid_request", "give lat/lon or a place for the prior position, not both")

    def check_photo(self, map_row: MapRow, info: ImageInfo) -> None:
        """The prior position, which must lie within the map's margin."""
        form, prior = self.form, None
        if form.lat is not None and form.lon is not None:
            radius_m = form.radius_m or DEFAULT_PRIOR_RADIUS_M
            prior = PriorPosition(lat=form.lat, lon=form.lon, radius_m=radius_m, source="request")
        elif form.place is not None:  # a named place overrides EXIF GPS (service.places)
            place = resolve_form_place(self.settings, map_row, form.place)
            prior = PriorPosition(
                lat=place.lat,
                lon=place.lon,
                radius_m=form.radius_m or place.radius_m,
                source="place",
                place=place.name,
                place_kind=place.kind,
            )
        elif form.use_exif_gps and info.gps_lat is not None and info.gps_lon is not None:
            radius_m = form.radius_m or gps_prior_radius_m(info.gps_accuracy_m)  # the fix's stated accuracy
            fields: dict[str, Any] = {"lat": info.gps_lat, "lon": info.gps_lon, "radius_m": radius_m, "source": "exif"}
            if not form.radius_m and info.gps_accuracy_m is not None:  # set only when it gave the radius
                fields["gps_accuracy_m"] = info.gps_accuracy_m
            prior = PriorPosition.model_validate(fields)
        if prior is not None:
            distance = distance_outside_bbox_m(prior.lat, prior.lon, map_row["bbox_wgs84"])
            margin_m = self.settings.position_margin_m
            if distance > margin_m:
                raise ApiError(
                    422,
                    "outside_map",
                    f"the prior position ({prior.lat:.6f}, {prior.lon:.6f}, from {prior.source}) is "
                    f"{distance:.0f} m outside map {map_row['id']}'s bounding box; send use_exif_gps=false to "
                    "ignore it",
                    {"distance_m": round(distance, 1), "margin_m": margin_m},
                )
        self.prior = prior

    def insert(self, db: Database, map_id: int, key: str, received: ReceivedFile, info: ImageInfo) -> int:
        """Insert the queued query with its parameters (:meth:`params`)."""
        params = self.params(received, info)
        return query_store.insert_query(db, map_id=map_id, params=params, image_path=key, sha256=received.sha256)

    def params(self, received: ReceivedFile, info: ImageInfo) -> QueryParams:
        """The query's parameters from the form, the checked prior and the photo's EXIF (after :meth:`check_photo`)."""
        form = self.form
        return QueryParams(
            top_n=form.top_n,
            k=form.k,
            prior=self.prior,
            prior_heading_deg=form.heading_deg if form.heading_deg is not None else info.heading_deg,
            prior_heading_accuracy_deg=None if form.heading_deg is not None else info.heading_accuracy_deg,
            focal_length_35mm=form.focal_length_35mm,
            original_filename=received.filename,
            preset=form.preset or self.settings.query_preset,
        )

    def payload(self, subject_id: int, map_id: int) -> LocalizeQueryPayload:
        """Answer this query."""
        return LocalizeQueryPayload(query_id=subject_id, map_id=map_id)

    def link(self, db: Database, subject_id: int, job_id: int) -> None:
        """Link the query to its job."""
        query_store.set_query_job(db, subject_id, job_id)
