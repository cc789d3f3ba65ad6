"""A worker plugin for ``tests/e2e/test_answers.py``: a query handler whose answer is chosen by ``top_n``.

It stands in for a query handler with a bug: it builds an answer (well-formed for ``top_n`` 1, with
one defect per other value) as the API's model inside :func:`workers.handlers.answer_checked`, as the real
handler does, and stores its JSON form. Loaded with ``GEOLOC_WORKER_PLUGINS=<this file>``, it replaces the
method's ``localize_query`` handler.
"""

from __future__ import annotations

import copy
import math
from typing import Any

from contracts.answers import QueryResult
from contracts.jobs import LOCALIZE_QUERY, LocalizeQueryPayload, LocalizeQueryResult
from db import Database, transaction
from db import queries as query_store
from tests.answer_parts import WHOLE_MAP_SEARCH
from workers.handlers import PermanentJobError, answer_checked, register

WELL_FORMED: dict[str, Any] = {
    "locations": [
        {
            "rank": 1,
            "lat": 60.17,
            "lon": 24.94,
            "heading_deg": 93.0,
            "probability": 0.5,
            "uncertainty_radius_m": 12.0,
            "source": "likelihood",
            "inliers": 0,
        }
    ],
    "heatmap": {
        "origin": {"lat": 60.17, "lon": 24.94},
        "origin_local_m": [-10.0, -10.0],
        "cell_m": 10.0,
        "shape": [2, 2],
        "bounds": {"min_lat": 60.1699, "min_lon": 24.9399, "max_lat": 60.1702, "max_lon": 24.9404},
        "values": [[0.1, 0.2], [0.3, 0.4]],
    },
    "buildings": [
        {
            "building_id": 0,
            "osm_id": "way/1",
            "name": "B0",
            "pixel_share": 1.0,
            "x_start": 0,
            "x_end": 639,
            "probability": 0.9,
        }
    ],
    "references": [],
    "search": WHOLE_MAP_SEARCH,
    "camera": {"hfov_deg": 60.0, "focal_source": "default_hfov", "width": 640, "height": 480},
    "timings_ms": {"total": 1.0},
}


def _answer(top_n: int) -> dict[str, Any]:
    """The answer for a query asked with ``top_n``: 1 is well-formed, 2-4 each carry one defect."""
    answer = copy.deepcopy(WELL_FORMED)
    if top_n == 2:
        answer["locations"][0]["lat"] = "north"  # a wrong type
    elif top_n == 3:
        answer["locations"][0]["probability"] = math.nan  # a NaN would break the JSON answer
    elif top_n == 4:
        del answer["heatmap"]  # a section missing
        answer["heat_map"] = {}  # and one the API does not know
    return answer


def stored_answer(answer: dict[str, Any]) -> dict[str, Any]:
    """``answer`` built as :class:`contracts.answers.QueryResult` (inside ``answer_checked``) in its stored form."""
    with answer_checked("query answer"):
        return QueryResult.model_validate(answer).model_dump(mode="json")


@register(LOCALIZE_QUERY, LocalizeQueryPayload)
def answer_by_top_n(db: Database, payload: LocalizeQueryPayload) -> LocalizeQueryResult:
    """Build the answer chosen by the query's ``top_n``, check it and store it like the real handler."""
    query_id = payload.query_id
    query = query_store.get_query(db, query_id)
    if query is None:
        raise PermanentJobError(f"query {query_id} no longer exists")
    result = stored_answer(_answer(query["params"].top_n))
    with transaction(db):
        query_store.update_query_result(db, query_id, status="done", result=result)
    return LocalizeQueryResult(query_id=query_id, locations=len(result["locations"]))
