"""The sequence job: a map's walks of references placed jointly on the map, in the background (issue 19).

Each reference of a walk is labelled alone first (:func:`workers.reference_handlers.label_reference`, which then queues
this job for its map unless one already waits) and is served with that label meanwhile. The job groups the map's
references into walks (:func:`geoloc.localize.sequence.group_sequences`) and, for each walk that is wholly labelled
and not yet placed as it stands, reads back each reference's stored label alone (labelling it alone again, the same
deterministic label, when it was stored without one), places the walk
(:func:`geoloc.localize.sequence.place_labelled_sequence`) and stores every frame the placement joined to the others
with its new pose, identities and anchors, in one transaction per walk: queries see the old walk or the new one,
never a mix. Every reference of a placed walk gets ``placement`` = ``sequence`` (a frame that keeps its own label,
:func:`geoloc.localize.sequence.stage.keeps_own_label`, keeps its pose). A reference added later is labelled
``alone`` and queues the job again, which re-places its whole walk (the part that changed is the walk: walks are
short). A walk with a reference still being labelled waits for the job that reference's label job queues.
"""

from __future__ import annotations

import time
from datetime import datetime

from contracts.jobs import PLACE_SEQUENCE, PlaceSequencePayload, PlaceSequenceResult
from contracts.references import WalkFrameArrays
from db import Database, transaction
from db import references as reference_store
from db.rows import ReferenceRow
from geoloc.core.geo import LocalFrame
from geoloc.localize.sequence import SequenceMember, group_sequences, place_labelled_sequence
from geoloc.localize.sequence.frames import FrameLabel
from geoloc.localize.sequence.stage import LabelledFrame, PlacedSequence, capture_seconds
from geoloc.maps import CityMap
from workers.handler_helpers import city_map_for, column_scale, reference_priors
from workers.handlers import register
from workers.metrics import observe_stage
from workers.reference_labels import label_alone, label_record, reference_labels

PENDING_STATUSES = ("queued", "processing")
"""Reference statuses of a reference still being labelled."""


def _capture_time(value: str | None) -> datetime | None:
    """A stored capture time (ISO 8601) as a datetime, None when absent or unreadable."""
    if value is None:
        return None
    try:
        return datetime.fromisoformat(value)
    except ValueError:
        return None


def _members(rows: list[ReferenceRow], frame: LocalFrame) -> list[SequenceMember]:
    """The grouping's view of stored references (GPS in the map's local metres; upload order by id)."""
    members = []
    for row in rows:
        x, y = (float(v) for v in frame.to_local(row["gps_lat"], row["gps_lon"]))
        members.append(
            SequenceMember(
                row["id"], row["sequence_id"], _capture_time(row["capture_time"]), row["device"], (x, y), row["id"]
            )
        )
    return members


def _walk_frame(db: Database, city: CityMap, row: ReferenceRow) -> tuple[WalkFrameArrays, LabelledFrame]:
    """A walk reference's stored label alone and the placement's frame of it (module docstring)."""
    stored = reference_store.load_walk_frame(db, row["id"])
    if stored is None:  # labelled before the label job stored it: label it alone again
        stored = label_alone(city, row).walk_frame()
    gps_xy, prior = reference_priors(city, row)
    time_s = capture_seconds(_capture_time(row["capture_time"]))
    return stored, LabelledFrame(FrameLabel.from_stored(stored), gps_xy, heading_prior=prior, capture_time_s=time_s)


def _place_walk(db: Database, city: CityMap, walk: list[ReferenceRow]) -> PlacedSequence:
    """Place one wholly labelled walk and store it (module docstring)."""
    t0 = time.perf_counter()
    stored_frames, frames = zip(*(_walk_frame(db, city, row) for row in walk), strict=True)
    placed = place_labelled_sequence(city, frames)
    observe_stage(PLACE_SEQUENCE, "placement", time.perf_counter() - t0)
    total_ms = 1e3 * (time.perf_counter() - t0) / len(walk)
    # A frame that keeps its own label comes back as None: its stored label stands (and is marked placed).
    moved = {
        row["id"]: (ref, reference_labels(city, _scale(stored, frame), ref, total_ms), stored)
        for row, stored, frame, ref in zip(walk, stored_frames, frames, placed.references, strict=True)
        if ref is not None
    }
    with transaction(db):
        for row in walk:
            current = reference_store.get_reference(db, row["id"])
            if current is None or current["status"] != "done":
                continue  # deleted (or re-queued) while the walk was placed: leave it be
            if row["id"] in moved:
                ref, labels, stored = moved[row["id"]]
                # its label alone stays stored
                reference_store.save_label(db, label_record(row["id"], ref, labels, "sequence", stored))
            else:
                reference_store.set_reference_placement(db, row["id"], "sequence")
    return placed


def _scale(stored: WalkFrameArrays, frame: LabelledFrame) -> float:
    """Uploaded photo's pixels per working-size pixel of a stored walk frame."""
    return column_scale(stored.original_size, frame.alone.intrinsics.width)


@register(PLACE_SEQUENCE, PlaceSequencePayload)
def place_sequences(db: Database, payload: PlaceSequencePayload) -> PlaceSequenceResult:
    """Place every walk of ``payload.map_id`` that is wholly labelled and changed (module docstring)."""
    city = city_map_for(db, payload.map_id)
    rows = reference_store.sequence_candidates(db, payload.map_id)
    by_id = {row["id"]: row for row in rows}
    walks = references = placed = edges = waiting = 0
    for group in group_sequences(_members(rows, city.frame)):
        members = [by_id[int(str(i))] for i in group]
        if any(row["status"] in PENDING_STATUSES for row in members):
            waiting += 1
            continue
        walk = [row for row in members if row["status"] == "done"]
        if len(walk) < 2 or all(row["placement"] == "sequence" for row in walk):
            continue
        result = _place_walk(db, city, walk)
        walks, references = walks + 1, references + len(walk)
        placed += sum(ref is not None for ref in result.references)
        edges += result.n_edges
    return PlaceSequenceResult(
        reference_id=payload.reference_id,
        walks=walks,
        references=references,
        placed=placed,
        edges=edges,
        waiting=waiting,
    )
