"""The answer contract without a server: answers checked as the API's own models, failures named and permanent.

A worker that stores and serves them is in ``tests/e2e/test_answers.py``.
"""

from __future__ import annotations

import copy
import json
import math
from typing import Any

import pytest

from contracts.answers import QueryResult, RankedLocation, ReferenceLabels
from tests.answer_plugin import WELL_FORMED, stored_answer
from workers.handlers import PermanentJobError, answer_checked


def test_a_well_formed_answer_is_stored_in_the_served_json_form() -> None:
    stored = stored_answer(copy.deepcopy(WELL_FORMED))
    assert stored == json.loads(QueryResult.model_validate(WELL_FORMED).model_dump_json())
    assert stored["heatmap"]["origin_local_m"] == [-10.0, -10.0]


@pytest.mark.parametrize(
    ("defect", "field", "reason"),
    [
        (lambda a: a["locations"][0].update(lat="north"), "locations.0.lat", "valid number"),
        (lambda a: a["heatmap"]["values"][0].__setitem__(0, math.inf), "heatmap.values.0.0", "finite number"),
        (lambda a: a.pop("camera"), "camera", "Field required"),
        (lambda a: a["buildings"][0].update(colour="red"), "buildings.0.colour", "Extra inputs"),
    ],
)
def test_a_malformed_answer_is_a_permanent_error_naming_the_field(defect: Any, field: str, reason: str) -> None:
    answer = copy.deepcopy(WELL_FORMED)
    defect(answer)
    with pytest.raises(PermanentJobError) as error:
        stored_answer(answer)
    message = str(error.value)
    assert message.startswith("malformed query answer, not stored") and f"{field}: " in message and reason in message


def test_reference_labels_are_checked_too() -> None:
    labels = {
        "estimated": {"lat": 60.17, "lon": 24.94, "heading_deg": 12.5},
        "buildings_seen": copy.deepcopy(WELL_FORMED["buildings"]),
        "timings": {"segmentation": 160.2, "total": 900.0},
    }
    with answer_checked("reference labels"):
        assert ReferenceLabels.model_validate(labels).model_dump(mode="json") == labels
    labels["buildings_seen"][0]["x_end"] = "right"
    with (
        pytest.raises(PermanentJobError, match=r"malformed reference labels.*buildings_seen\.0\.x_end"),
        answer_checked("reference labels"),
    ):
        ReferenceLabels.model_validate(labels)


def test_an_answer_built_directly_fails_for_good_naming_the_field() -> None:
    """The handlers build the models field by field: a bad value fails at once, named, before anything is stored."""
    location = copy.deepcopy(WELL_FORMED["locations"][0])
    location["probability"] = math.nan
    with pytest.raises(PermanentJobError) as error, answer_checked("query answer"):
        RankedLocation(**location)
    message = str(error.value)
    assert message.startswith("malformed query answer, not stored") and "against RankedLocation" in message
    assert "probability: Input should be a finite number" in message
