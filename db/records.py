"""The typed records the store's writes take: a new reference, a reference's label.

Rows come back as ``TypedDict``s (:mod:`db.rows`); what a caller hands in to be written is a frozen dataclass,
one per write, so that a write is one call with one argument that mypy checks field by field. Positions are WGS84
degrees, headings degrees clockwise from true north, times ISO 8601 as the photo states them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from contracts.references import ReferenceKeypoints, ReferenceLabelArrays, WalkFrameArrays


@dataclass(frozen=True)
class NewReference:
    """A reference photo to insert, queued (:func:`db.references.insert_reference`).

    image_path: its key in the file store; position_source: ``request`` or ``exif``. prior_heading_accuracy_deg:
    the accuracy (deg) of a heading prior from the photo's compass, None for a heading the uploader stated (the
    worker weights the two differently, see :mod:`workers.handler_helpers`). sequence_id, capture_time, device:
    what groups it into a walk (:mod:`geoloc.localize.sequence`).
    """

    map_id: int
    image_path: str
    original_filename: str | None
    sha256: str
    size_bytes: int
    image_format: str
    width: int
    height: int
    gps_lat: float
    gps_lon: float
    position_source: str
    prior_heading_deg: float | None = None
    prior_heading_accuracy_deg: float | None = None
    focal_length_35mm: float | None = None
    sequence_id: str | None = None
    capture_time: str | None = None
    device: str | None = None


@dataclass(frozen=True)
class ReferenceLabel:
    """A labelled reference to store (:func:`db.references.save_label`); the reference is then ``done``.

    arrays, keypoints: its identity map and keypoints (:mod:`contracts.references`); estimated_*: its pose (WGS84
    degrees, heading deg from true north); buildings_seen, timings (ms): the JSON of its answer
    (:class:`contracts.answers.ReferenceLabels`); placement: ``alone`` (its own label) or ``sequence`` (its walk's
    joint placement); walk_frame: its label alone for the sequence job, for a reference that may join a walk
    (:func:`db.references.save_labels`).
    """

    reference_id: int
    arrays: ReferenceLabelArrays
    keypoints: ReferenceKeypoints
    estimated_lat: float | None
    estimated_lon: float | None
    estimated_heading_deg: float | None
    buildings_seen: list[dict[str, Any]]
    timings: dict[str, float]
    placement: Literal["alone", "sequence"]
    walk_frame: WalkFrameArrays | None = None
