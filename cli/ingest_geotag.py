"""``geoloc ingest --gpx TRACK.gpx [--time-offset S]`` and Mapillary's description file: each photo's form fields.

The reference upload already takes what geotagging adds (``POST /v1/maps/{id}/references``: ``lat``/``lon``
override EXIF GPS, ``heading_deg`` is the heading prior, ``sequence`` the walk), so the command sends those
fields and the API is unchanged. Per photo (EXIF read once, by :func:`geoloc.photos.exif.load_exif` and the
capture rules of :mod:`geoloc.photos.capture`; the track and the description file by
:mod:`geoloc.photos.geotag`):

- **position**: with ``--gpx``, the track's position at the capture time, for every photo (the track is what
  the user chose: it replaces EXIF GPS, as exiftool's and mapillary_tools' GPX geotagging do); a photo the
  track cannot place (no capture time, before or after the track, in a gap) is *skipped* with the reason and
  not uploaded. Without ``--gpx``, a photo without EXIF GPS takes ``MAPLatitude``/``MAPLongitude`` from a
  ``mapillary_image_description.json`` beside it; with EXIF GPS nothing is sent (the service reads it).
- **capture time** (to look the photo up on the track): an aware time of the photo (EXIF with its offset, or
  Mapillary's JSON in EXIF), else the description's ``MAPCaptureTime`` (UTC), else EXIF's naive camera time
  (taken as UTC); ``--time-offset S`` is added to it (a camera clock that is off, or set to local time).
  The service has no form field for a capture time, so it is not sent: the service stores the one the
  photo's EXIF says.
- **heading**: nothing when the photo has a compass (EXIF or Mapillary's JSON in EXIF: the service reads it,
  with its accuracy); else the description's ``MAPCompassHeading``; else, with ``--gpx``, the track's
  direction of travel (when the walker moved).
- **sequence**: the description's ``MAPSequenceUUID`` when the photo's EXIF names no sequence.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from cli.photo_files import Candidate, FileResult
from client import ReferenceFields
from geoloc.photos.capture import CaptureInfo, capture_of
from geoloc.photos.exif import exif_info, load_exif
from geoloc.photos.geotag import (
    DESCRIPTION_FILE,
    NO_DESCRIPTIONS,
    GeotagError,
    MapillaryDescriptions,
    Track,
    Unplaced,
    read_gpx,
    read_mapillary_descriptions,
    track_time,
)


@dataclass(frozen=True)
class Geotagging:
    """What ingest adds to the photos' EXIF: a track (``--gpx``) with its time offset, the description files."""

    track: Track | None = None
    time_offset_s: float = 0.0
    descriptions: MapillaryDescriptions = NO_DESCRIPTIONS
    description_files: tuple[str, ...] = ()

    @property
    def active(self) -> bool:
        """Whether there is anything to add (else every photo is sent as before, without form fields)."""
        return self.track is not None or len(self.descriptions) > 0

    def summary(self) -> str:
        """One line for the run's header: the track's span and offset, the description files read."""
        parts = []
        if self.track is not None:
            track = self.track
            parts.append(
                f"GPX track of {len(track.points)} point(s) from {track.start.isoformat()} to "
                f"{track.end.isoformat()} (capture times shifted by {self.time_offset_s:+g} s)"
            )
        if self.description_files:
            parts.append(f"{len(self.descriptions)} image(s) described in {', '.join(self.description_files)}")
        return "geotagging: " + "; ".join(parts) if parts else ""


def description_files(folder: Path, *, recursive: bool) -> list[Path]:
    """The ``mapillary_image_description.json`` files of the folder (and its subfolders with ``recursive``)."""
    found = folder.rglob(DESCRIPTION_FILE) if recursive else [folder / DESCRIPTION_FILE]
    return sorted(p for p in found if p.is_file())


def load_geotagging(folder: Path, gpx: Path | None, time_offset_s: float, *, recursive: bool) -> Geotagging:
    """The track and the description files of a run; :class:`GeotagError` when one cannot be read."""
    track = None
    if gpx is not None:
        try:
            track = read_gpx(gpx)
        except OSError as exc:
            raise GeotagError(f"cannot read the GPX file {gpx}: {exc.strerror or exc}") from exc
        except GeotagError as exc:
            raise GeotagError(f"{gpx}: {exc}") from exc
    files = description_files(folder, recursive=recursive)
    descriptions = read_mapillary_descriptions(files, folder) if files else NO_DESCRIPTIONS
    names = tuple(p.relative_to(folder).as_posix() for p in files)
    return Geotagging(track, time_offset_s, descriptions, names)


@dataclass
class Tagged:
    """The form fields of one photo and where each came from, or why it is not uploaded."""

    fields: ReferenceFields
    sources: dict[str, str]
    refusal: str | None = None


def photo_fields(photo: Candidate, geotagging: Geotagging) -> Tagged:
    """The reference upload's form fields for one photo (rules in the module docstring)."""
    block = load_exif(photo.path)
    exif, capture = exif_info(block), capture_of(block)
    described = geotagging.descriptions.for_photo(photo.relative)
    fields: ReferenceFields = {}
    sources: dict[str, str] = {}
    travel: float | None = None
    if geotagging.track is not None:
        when, said_by = _capture_time(capture, described.time if described else None)
        if when is None:
            return Tagged(
                {},
                {},
                "no capture time (no EXIF DateTimeOriginal, no Mapillary MAPCaptureTime): the GPX track cannot "
                "place it",
            )
        fix = geotagging.track.locate(track_time(when, geotagging.time_offset_s))
        if isinstance(fix, Unplaced):
            return Tagged({}, {}, f"outside the GPX track: {fix.reason} (capture time from {said_by})")
        fields["lat"], fields["lon"] = round(fix.lat, 8), round(fix.lon, 8)
        sources["position"] = f"GPX track at {fix.time.isoformat()} (capture time from {said_by})"
        travel = fix.heading_deg
    elif not exif.has_gps and described is not None and described.lat is not None and described.lon is not None:
        fields["lat"], fields["lon"] = described.lat, described.lon
        sources["position"] = DESCRIPTION_FILE
    if capture.compass is None:
        if described is not None and described.compass is not None:
            fields["heading_deg"] = round(described.compass.heading_deg, 3)
            sources["heading"] = f"{DESCRIPTION_FILE} ({described.compass.reference})"
        elif travel is not None:
            fields["heading_deg"] = round(travel, 3)
            sources["heading"] = "GPX track's direction of travel"
    if capture.sequence_id is None and described is not None and described.sequence_id is not None:
        fields["sequence"] = described.sequence_id
        sources["sequence"] = DESCRIPTION_FILE
    return Tagged(fields, sources)


def _capture_time(capture: CaptureInfo, described_time: datetime | None) -> tuple[datetime | None, str]:
    """The capture time to place on the track and what said it (rule in the module docstring)."""
    photo_time = capture.time
    if photo_time is not None and photo_time.tzinfo is not None:
        return photo_time, "the photo's Mapillary JSON" if capture.time_source == "mapillary" else "the photo's EXIF"
    if described_time is not None:
        return described_time, f"{DESCRIPTION_FILE} (UTC)"
    if photo_time is not None:
        return photo_time, "the photo's EXIF, no time zone: read as UTC"
    return None, ""


def geotag_photos(photos: list[Candidate], geotagging: Geotagging) -> tuple[list[Candidate], list[FileResult]]:
    """The photos to upload, each with its form fields, and the ones skipped (the track cannot place them)."""
    if not geotagging.active:
        return photos, []
    kept: list[Candidate] = []
    skipped: list[FileResult] = []
    for photo in photos:
        tagged = photo_fields(photo, geotagging)
        if tagged.refusal is not None:
            skipped.append(
                FileResult(
                    photo.relative,
                    "skipped",
                    tagged.refusal,
                    sha256=photo.sha256,
                    size_bytes=photo.size_bytes,
                    mime_type=photo.mime_type,
                )
            )
            continue
        photo.fields, photo.field_sources = tagged.fields, tagged.sources
        kept.append(photo)
    return kept, skipped
