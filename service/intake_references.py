"""The reference-upload use-case: a geo-tagged photo of a map, its position checked, its labelling job queued.

:class:`ReferenceIntake` is the photo-upload use-case of :class:`service.intake.PhotoIntake` for a reference: its
position (the request's lat/lon, else a named place, else the photo's EXIF GPS) inside the map's margin, one
reference per photo and map (a duplicate is reported, nothing stored), and the ``label_reference`` job. Routes
call this module; it imports no route module.
"""

from __future__ import annotations

from dataclasses import dataclass

from contracts.jobs import LABEL_REFERENCE, LabelReferencePayload
from contracts.settings import Settings
from db import Database
from db import references as reference_store
from db.files import FileStore
from db.records import NewReference
from db.rows import MapRow, ReferenceRow
from service.bounds import check_bounds
from service.errors import ApiError
from service.images import ImageInfo, distance_outside_bbox_m
from service.intake import PhotoIntake
from service.places import resolve_form_place
from service.uploads import ReceivedFile
from workers.broker import JobPublisher


def resolve_position(
    lat: float | None, lon: float | None, exif_lat: float | None, exif_lon: float | None
) -> tuple[float, float, str]:
    """The reference's position: the request's lat/lon if given, else EXIF GPS, else 422."""
    if (lat is None) != (lon is None):
        raise ApiError(422, "invalid_request", "give both lat and lon, or neither (to use the photo's EXIF GPS)")
    if lat is not None and lon is not None:
        check_bounds("lat", lat)
        check_bounds("lon", lon)
        return lat, lon, "request"
    if exif_lat is None or exif_lon is None:
        raise ApiError(
            422,
            "no_position",
            "no position: the photo has no GPS position in its EXIF and no lat/lon fields were given",
        )
    return exif_lat, exif_lon, "exif"


@dataclass(frozen=True)
class ReferenceForm:
    """The form fields of a reference upload (checked by :class:`ReferenceIntake`)."""

    lat: float | None
    lon: float | None
    heading_deg: float | None
    focal_length_35mm: float | None
    sequence_id: str | None = None
    place: str | None = None


class ReferenceIntake(PhotoIntake):
    """A reference upload: its position (request, else EXIF GPS) inside the map, one reference per photo."""

    folder = "images"
    kind = LABEL_REFERENCE

    def __init__(
        self,
        settings: Settings,
        store: FileStore,
        publisher: JobPublisher,
        form: ReferenceForm,
    ) -> None:
        super().__init__(settings, store, publisher)
        self.form = form
        self.position: tuple[float, float, str] = (0.0, 0.0, "request")
        self.duplicate: ReferenceRow | None = None

    def check_form(self) -> None:
        """Check the heading and focal length's bounds, and that lat/lon and a place do not come together."""
        check_bounds("heading_deg", self.form.heading_deg)
        check_bounds("focal_length_35mm", self.form.focal_length_35mm)
        if self.form.place is not None and (self.form.lat is not None or self.form.lon is not None):
            raise ApiError(422, "invalid_request", "give lat/lon or a place for the position, not both")

    def check_photo(self, map_row: MapRow, info: ImageInfo) -> None:
        """The reference's position (lat/lon, else the place, else EXIF GPS), which must lie within the map's margin."""
        form = self.form
        if form.place is not None:  # a named place overrides EXIF GPS (service.places); stored as "request"
            place = resolve_form_place(self.settings, map_row, form.place)
            ref_lat, ref_lon, source = place.lat, place.lon, "request"
        else:
            ref_lat, ref_lon, source = resolve_position(form.lat, form.lon, info.gps_lat, info.gps_lon)
        distance = distance_outside_bbox_m(ref_lat, ref_lon, map_row["bbox_wgs84"])
        margin_m = self.settings.position_margin_m
        if distance > margin_m:
            raise ApiError(
                422,
                "outside_map",
                f"the photo's position ({ref_lat:.6f}, {ref_lon:.6f}, from {source}) is {distance:.0f} m outside "
                f"map {map_row['id']}'s bounding box (allowed margin {margin_m:.0f} m)",
                {"distance_m": round(distance, 1), "margin_m": margin_m, "lat": ref_lat, "lon": ref_lon},
            )
        self.position = (ref_lat, ref_lon, source)

    def existing(self, db: Database, map_id: int, sha256: str) -> int | None:
        """The map's reference with this photo, if any (under a lock: the same photo sent twice at once)."""
        db.lock(f"geoloc:reference:{map_id}:{sha256}")
        self.duplicate = reference_store.find_reference_by_sha256(db, map_id, sha256)
        return None if self.duplicate is None else self.duplicate["id"]

    def insert(self, db: Database, map_id: int, key: str, received: ReceivedFile, info: ImageInfo) -> int:
        """Insert the queued reference."""
        ref_lat, ref_lon, source = self.position
        form = self.form
        return reference_store.insert_reference(
            db,
            NewReference(
                map_id=map_id,
                image_path=key,
                original_filename=received.filename,
                sha256=received.sha256,
                size_bytes=received.size_bytes,
                image_format=info.format,
                width=info.width,
                height=info.height,
                gps_lat=ref_lat,
                gps_lon=ref_lon,
                position_source=source,
                # A form heading overrides the compass and is weighted as before (no accuracy stored).
                prior_heading_deg=form.heading_deg if form.heading_deg is not None else info.heading_deg,
                prior_heading_accuracy_deg=None if form.heading_deg is not None else info.heading_accuracy_deg,
                focal_length_35mm=(
                    form.focal_length_35mm if form.focal_length_35mm is not None else info.focal_length_35mm
                ),
                sequence_id=form.sequence_id if form.sequence_id is not None else info.sequence_id,
                capture_time=info.capture_time,
                device=info.device,
            ),
        )

    def payload(self, subject_id: int, map_id: int) -> LabelReferencePayload:
        """Label this reference."""
        return LabelReferencePayload(reference_id=subject_id, map_id=map_id)

    def link(self, db: Database, subject_id: int, job_id: int) -> None:
        """Link the reference to its job."""
        reference_store.set_reference_job(db, subject_id, job_id)

    def job_reference_id(self, subject_id: int) -> int:
        """The job is the reference's (deleting the reference cancels it)."""
        return subject_id
