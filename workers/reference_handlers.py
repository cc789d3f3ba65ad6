"""The reference job (``label_reference``): a reference photo labelled with its map, indexed, its pose stored.

It computes first, builds its answer as the API's models (:class:`contracts.answers.ReferenceLabels`, inside
:func:`workers.handlers.answer_checked`: a malformed answer fails the job at once and nothing is stored), and then
writes everything in one transaction with replace semantics (its label, :func:`db.references.save_label`; its
index postings), so a job that runs again after a crash leaves the same state. A reference that may join a walk
then queues the map's sequence job (:mod:`workers.sequence_handlers`). Importing this module registers the handler.
"""

from __future__ import annotations

import time

import numpy as np

from contracts.jobs import (
    LABEL_REFERENCE,
    PLACE_SEQUENCE,
    LabelReferencePayload,
    LabelReferenceResult,
    PlaceSequencePayload,
)
from db import Database, sbow, transaction
from db import jobs as job_store
from db import references as reference_store
from workers.handler_helpers import city_map_for, vocabulary_for
from workers.handlers import PermanentJobError, register
from workers.metrics import observe_stages
from workers.reference_labels import label_alone, label_record, reference_labels


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
        walk_frame = alone.walk_frame() if walker else None
        reference_store.save_label(db, label_record(reference_id, labelled, labels, "alone", walk_frame))
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
