"""A worker plugin for ``tests/e2e/test_pictures.py``: a query handler with an answer placed on the map.

The one pose stands :data:`POSE_SOUTH_M` south of building 0's centroid looking north (compass 0); the heat map
is a 9 x 9 grid of 5 m cells centred on the pose, peaking :data:`PEAK_SOUTH_M` south of it. Loaded with
``GEOLOC_WORKER_PLUGINS=<this file>``, it replaces the method's ``localize_query`` handler.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from contracts.answers import QueryResult
from contracts.jobs import LOCALIZE_QUERY, LocalizeQueryPayload, LocalizeQueryResult
from db import Database, transaction
from db import queries as query_store
from tests.answer_parts import WHOLE_MAP_SEARCH
from workers.handler_helpers import city_map_for
from workers.handlers import answer_checked, register

ToWgs84 = Callable[[float, float], tuple[Any, Any]]
POSE_SOUTH_M = 25.0
PEAK_SOUTH_M = 10.0
CELL_M = 5.0
CELLS = 9


def placed_answer(map_xy: tuple[float, float], to_wgs84: ToWgs84) -> dict[str, Any]:
    """The answer around a pose at local ``map_xy``; ``to_wgs84``: the map frame's ``to_wgs84``."""
    x, y = map_xy
    lat, lon = to_wgs84(x, y)
    origin = (x - CELL_M * (CELLS // 2), y - CELL_M * (CELLS // 2))
    rows, cols = np.mgrid[0:CELLS, 0:CELLS]
    peak_row = CELLS // 2 - PEAK_SOUTH_M / CELL_M
    values = np.exp(-((rows - peak_row) ** 2 + (cols - CELLS // 2) ** 2) / 4.0)
    values /= values.sum()
    o_lat, o_lon = to_wgs84(*origin)
    s_lat, s_lon = to_wgs84(origin[0] - CELL_M / 2, origin[1] - CELL_M / 2)
    n_lat, n_lon = to_wgs84(origin[0] + CELL_M * (CELLS - 0.5), origin[1] + CELL_M * (CELLS - 0.5))
    return {
        "locations": [
            {
                "rank": 1,
                "lat": float(lat),
                "lon": float(lon),
                "heading_deg": 0.0,
                "probability": 0.6,
                "uncertainty_radius_m": 8.0,
                "source": "likelihood",
                "inliers": 0,
            }
        ],
        "heatmap": {
            "origin": {"lat": float(o_lat), "lon": float(o_lon)},
            "origin_local_m": [float(origin[0]), float(origin[1])],
            "cell_m": CELL_M,
            "shape": [CELLS, CELLS],
            "bounds": {
                "min_lat": float(s_lat),
                "min_lon": float(s_lon),
                "max_lat": float(n_lat),
                "max_lon": float(n_lon),
            },
            "values": values.tolist(),
        },
        "buildings": [],
        "references": [],
        "search": WHOLE_MAP_SEARCH,
        "camera": {"hfov_deg": 50.0, "focal_source": "default_hfov", "width": 640, "height": 480},
        "timings_ms": {"total": 1.0},
    }


@register(LOCALIZE_QUERY, LocalizeQueryPayload)
def answer_placed(db: Database, payload: LocalizeQueryPayload) -> LocalizeQueryResult:
    """Store :func:`placed_answer` south of the map's building 0, checked as the real handler checks it."""
    city_map = city_map_for(db, payload.map_id)
    centroid = city_map.buildings[0].polygon.centroid
    answer = placed_answer((centroid.x, centroid.y - POSE_SOUTH_M), city_map.frame.to_wgs84)
    with answer_checked("query answer"):
        result = QueryResult.model_validate(answer).model_dump(mode="json")
    with transaction(db):
        query_store.update_query_result(db, payload.query_id, status="done", result=result)
    return LocalizeQueryResult(query_id=payload.query_id, locations=1)
