"""A reference labelled alone, its answer and its stored label: what the reference and walk handlers share.

A reference is labelled alone with its map (:func:`label_alone`: its photo, its GPS tag and compass prior in the
map's local metres); its answer is the API's :class:`contracts.answers.ReferenceLabels` (pose in WGS84 and compass
degrees, built inside :func:`workers.handlers.answer_checked`); what is stored of it is one
:class:`db.records.ReferenceLabel`, written by :func:`db.references.save_label` in the caller's transaction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from contracts.answers import EstimatedPose, ReferenceLabels
from contracts.references import WalkFrameArrays
from db.records import ReferenceLabel
from db.rows import ReferenceRow
from geoloc.localize.reference import LabelledReference, label_reference_photo
from geoloc.localize.sequence.frames import FrameLabel
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from workers.context import worker_context
from workers.handler_helpers import column_scale, describe_buildings, reference_priors, stored_photo
from workers.handlers import answer_checked


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

    def walk_frame(self) -> WalkFrameArrays:
        """What the sequence job needs of this label (:meth:`geoloc.localize.sequence.frames.FrameLabel.stored`)."""
        return FrameLabel.of(self.labelled, self.photo.intrinsics).stored(self.photo.original_size)


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
            buildings_seen=describe_buildings(city, labelled.identity.building_extents(), scale),
            timings=timings,
        )


def label_record(
    reference_id: int,
    labelled: LabelledReference,
    labels: ReferenceLabels,
    placement: Literal["alone", "sequence"],
    walk_frame: WalkFrameArrays | None = None,
) -> ReferenceLabel:
    """What is stored of a labelled reference (:func:`db.references.save_label`); it is then ``done``.

    placement: ``alone`` (its own label) or ``sequence`` (its walk's joint placement); walk_frame: its label
    alone for the sequence job (:meth:`AloneLabel.walk_frame`), for a reference that may join a walk.
    """
    stored = labels.model_dump(mode="json")
    estimated = labels.estimated
    return ReferenceLabel(
        reference_id=reference_id,
        arrays=labelled.label_arrays(),
        keypoints=labelled.keypoints(),
        estimated_lat=estimated.lat,
        estimated_lon=estimated.lon,
        estimated_heading_deg=estimated.heading_deg,
        buildings_seen=stored["buildings_seen"],
        timings=stored["timings"],
        placement=placement,
        walk_frame=walk_frame,
    )
