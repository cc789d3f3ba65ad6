"""The query job (``localize_query``): where was this photo taken? Thin: all of the method is in ``geoloc``.

The query stage (:func:`geoloc.localize.query.geolocate`) answers the stored photo with its stored priors
(:func:`workers.handler_helpers.query_priors`); the answer is built as the API's model
(:func:`workers.handler_helpers.query_result`, inside :func:`workers.handlers.answer_checked`) and stored in one
transaction, replaced as a whole when the job runs again. Importing this module registers the handler.
"""

from __future__ import annotations

import time

from contracts.jobs import LOCALIZE_QUERY, LocalizeQueryPayload, LocalizeQueryResult
from db import Database, transaction
from db import queries as query_store
from geoloc.localize.query import geolocate, preset_config
from geoloc.vision.evidence import analyze_photo
from geoloc.vision.onnx_session import used_device
from geoloc.vision.segmentation import network_name
from workers.context import worker_context
from workers.handler_helpers import (
    city_map_for,
    query_priors,
    query_result,
    reference_store_for,
    stored_photo,
    vocabulary_for,
)
from workers.handlers import PermanentJobError, answer_checked, register
from workers.metrics import observe_stages


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
    answer.search.preset = params.preset_name  # beside search.config: which preset chose it
    answer.search.device = used_device(context.device)  # where segmentation and ALIKED ran: cpu or cuda
    answer.search.segmentation = network_name(context)  # which network (its input size) labelled the photo
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
