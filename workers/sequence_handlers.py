"""The sequence job: a walk of references placed jointly on the map, in the background (issue 19).

Each reference of a walk is labelled alone first (:func:`workers.method_handlers.label_reference`, which then
queues this job) and is served with that label meanwhile. The job finds the reference's walk among its map's
references (:func:`geoloc.localize.sequence.group_sequences`) and, once every reference of the walk is labelled,
re-labels each alone again (the same, deterministic label), places the walk
(:func:`geoloc.localize.sequence.place_labelled_sequence`) and stores every frame the placement joined to the
others with its new pose, identities and anchors (``placement`` = ``sequence``), in one transaction: queries see
the old walk or the new one, never a mix. A reference added later resets its own placement to ``alone`` and
queues the job again, which re-places the whole walk ("the part that changed" is the walk: walks are short).

Several jobs for one walk (each reference queues one) do the work once: a job skips while a reference of the walk
is still being labelled, and when every labelled reference of the walk is already placed.
"""

from __future__ import annotations

import time
from datetime import datetime

from contracts.jobs import PLACE_SEQUENCE, PlaceSequencePayload, PlaceSequenceResult
from db import Database, transaction
from db import references as reference_store
from db.rows import ReferenceRow
from geoloc.core.geo import LocalFrame
from geoloc.localize.sequence import SequenceMember, group_sequences, place_labelled_sequence
from geoloc.localize.sequence.stage import LabelledFrame
from workers.handlers import register
from workers.method_handlers import city_map_for, label_alone, reference_labels, save_labels

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


@register(PLACE_SEQUENCE, PlaceSequencePayload)
def place_sequence(db: Database, payload: PlaceSequencePayload) -> PlaceSequenceResult:
    """Place the walk of ``payload.reference_id`` jointly, when all of it is labelled (module docstring)."""
    reference_id, map_id = payload.reference_id, payload.map_id
    city = city_map_for(db, map_id)
    rows = reference_store.sequence_candidates(db, map_id)
    by_id = {row["id"]: row for row in rows}
    group = next((g for g in group_sequences(_members(rows, city.frame)) if reference_id in g), None)

    def skipped(why: str, size: int = 0) -> PlaceSequenceResult:
        return PlaceSequenceResult(reference_id=reference_id, references=size, placed=0, edges=0, skipped=why)

    if group is None:
        return skipped("not in a sequence")
    members = [by_id[int(str(i))] for i in group]
    if any(row["status"] in PENDING_STATUSES for row in members):
        return skipped("a reference of the sequence is still being labelled", len(members))
    done = [row for row in members if row["status"] == "done"]
    if len(done) < 2:
        return skipped("fewer than two labelled references", len(members))
    if all(row["placement"] == "sequence" for row in done):
        return skipped("already placed", len(members))

    t0 = time.perf_counter()
    alone = [label_alone(city, row) for row in done]
    frames = [LabelledFrame(a.photo, a.labelled, a.gps_xy, heading_prior=a.heading_prior) for a in alone]
    placed = place_labelled_sequence(city, frames)
    total_ms = 1e3 * (time.perf_counter() - t0) / len(done)
    # A frame no relative pose joined comes back as it went in: its stored label stands (and is marked placed).
    moved = {
        row["id"]: (ref, reference_labels(city, a.photo, ref, total_ms))
        for row, a, ref in zip(done, alone, placed.references, strict=True)
        if ref is not a.labelled
    }
    with transaction(db):
        for row in done:
            current = reference_store.get_reference(db, row["id"])
            if current is None or current["status"] != "done":
                continue  # deleted (or re-queued) while the walk was placed: leave it be
            if row["id"] in moved:
                save_labels(db, row["id"], *moved[row["id"]])
            reference_store.set_reference_placement(db, row["id"], "sequence")
    return PlaceSequenceResult(
        reference_id=reference_id, references=len(members), placed=len(moved), edges=placed.n_edges
    )
