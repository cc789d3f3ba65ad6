"""GeoJSON answers (:mod:`service.geojson`) built from the API's own models: cones, buildings, references."""

from __future__ import annotations

import copy
from datetime import UTC, datetime
from typing import Any

import pytest
import shapely.geometry

from contracts.answers import QueryResult
from contracts.api import QueryOut, ReferenceList, ReferenceOut
from service.geojson import query_collection, references_collection
from tests.answer_plugin import WELL_FORMED
from tests.geojson_checks import check_query_collection

ATTRIBUTION = "© OpenStreetMap contributors"
FOOTPRINT = {
    "type": "Polygon",
    "coordinates": [[[24.94, 60.17], [24.9402, 60.17], [24.9402, 60.1701], [24.94, 60.1701], [24.94, 60.17]]],
}


def _query(answer: dict[str, Any] | None, status: str = "done", error: str | None = None) -> QueryOut:
    result = None if answer is None else QueryResult.model_validate(answer)
    return QueryOut(id=5, map_id=1, status=status, error=error, params={}, result=result, attribution=ATTRIBUTION)


def test_an_answer_has_a_point_a_cone_per_pose_and_the_buildings() -> None:
    answer = copy.deepcopy(WELL_FORMED)
    answer["locations"].append({**answer["locations"][0], "rank": 2, "lat": 60.1701, "heading_deg": 355.0})
    answer["camera"]["hfov_deg"] = 73.7
    out = _query(answer)
    collection = query_collection(out, {0: FOOTPRINT})
    by_type = check_query_collection(collection, out.model_dump(mode="json"))
    assert [c["properties"]["fov_deg"] for c in by_type["view_cone"]] == [73.7] * 2
    (building,) = by_type["building"]
    assert building["geometry"] == FOOTPRINT and building["id"] == 0
    assert building["properties"] == {
        "feature_type": "building",
        "building_id": 0,
        "osm_id": "way/1",
        "name": "B0",
        "pixel_share": 1.0,
        "probability": 0.9,
    }


def test_a_building_without_a_footprint_on_the_map_is_left_out() -> None:
    collection = query_collection(_query(copy.deepcopy(WELL_FORMED)), {})
    assert [f["properties"]["feature_type"] for f in collection["features"]] == ["pose", "view_cone"]


@pytest.mark.parametrize(("status", "error"), [("queued", None), ("processing", None), ("failed", "no facades")])
def test_a_query_without_an_answer_is_an_empty_collection_that_says_why(status: str, error: str | None) -> None:
    collection = query_collection(_query(None, status, error), {})
    assert collection["features"] == [] and collection["status"] == status
    assert collection.get("error") == error and collection["attribution"] == ATTRIBUTION


def _reference(ref_id: int, estimated: dict[str, Any] | None) -> ReferenceOut:
    now = datetime.now(tz=UTC)
    return ReferenceOut.model_validate(
        {
            "id": ref_id,
            "map_id": 1,
            "status": "done" if estimated else "queued",
            "sha256": "a" * 64,
            "width": 640,
            "height": 480,
            "position": {"lat": 60.17, "lon": 24.94, "source": "exif"},
            "prior_heading_deg": 80.0,
            "estimated": estimated,
            "attribution": ATTRIBUTION,
            "created_at": now,
            "updated_at": now,
        }
    )


def test_references_are_points_at_their_estimated_pose_else_their_uploaded_position() -> None:
    page = ReferenceList(
        map_id=1,
        references=[_reference(1, {"lat": 60.1701, "lon": 24.9403, "heading_deg": 91.5}), _reference(2, None)],
        total=2,
        counts={"done": 1, "queued": 1},
        walks_placing=0,
        next_after_id=None,
        attribution=ATTRIBUTION,
    )
    collection = references_collection(page)
    assert collection["attribution"] == ATTRIBUTION and collection["total"] == 2
    labelled, queued = collection["features"]
    assert shapely.geometry.shape(labelled["geometry"]).is_valid
    assert labelled["geometry"]["coordinates"] == [24.9403, 60.1701]
    assert labelled["properties"]["pose_source"] == "estimated" and labelled["properties"]["heading_deg"] == 91.5
    assert queued["geometry"]["coordinates"] == [24.94, 60.17]
    assert queued["properties"]["pose_source"] == "exif" and queued["properties"]["heading_deg"] == 80.0
