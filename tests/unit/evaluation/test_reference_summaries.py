"""The reference-pose figures of ``geoloc eval world`` (issue 19) on hand-made errors, and a world's capture kind."""

from __future__ import annotations

import pytest

from geoloc.evaluation.summaries import (
    angle_summary,
    distance_summary,
    per_walk_summary,
    reference_heading_summary,
    reference_position_summary,
)
from geoloc.evaluation.world import capture_kind

POSITION_ERRORS_M = [0.5, 1.0, 1.5, 2.0, 3.0, 12.0]  # median 1.75 m; 2 of 6 <= 1 m, 4 of 6 <= 2 m
HEADING_ERRORS_DEG = [0.1, 2.0, 2.5, 4.0, 6.0]  # median 2.5 deg; 2 of 5 <= 2 deg, 4 of 5 <= 5 deg


def test_reference_position_summary_shares_and_median_are_exact() -> None:
    summary = reference_position_summary(POSITION_ERRORS_M)
    assert summary == {
        "n": 6,
        "median_m": 1.75,
        "within_1m": round(2 / 6, 4),
        "within_2m": round(4 / 6, 4),
        "within_5m": round(5 / 6, 4),
        "within_10m": round(5 / 6, 4),
    }


def test_reference_summaries_only_add_keys_to_the_old_ones() -> None:
    """The existing keys keep their values (the evaluation JSON of a scattered world only gains keys)."""
    old_position, new_position = distance_summary(POSITION_ERRORS_M), reference_position_summary(POSITION_ERRORS_M)
    old_heading, new_heading = angle_summary(HEADING_ERRORS_DEG), reference_heading_summary(HEADING_ERRORS_DEG)
    assert {k: new_position[k] for k in old_position} == old_position
    assert {k: new_heading[k] for k in old_heading} == old_heading
    assert set(new_position) - set(old_position) == {"within_1m", "within_2m"}
    assert set(new_heading) - set(old_heading) == {"within_2deg"}


def test_reference_heading_summary_shares_and_median_are_exact() -> None:
    assert reference_heading_summary(HEADING_ERRORS_DEG) == {
        "n": 5,
        "median": 2.5,
        "within_2deg": 0.4,
        "within_5deg": 0.8,
    }
    assert reference_heading_summary([]) == {"n": 0}


def test_per_walk_summary_groups_by_walk_and_leaves_out_references_off_walks() -> None:
    walk_ids: list[int | None] = [1, 0, 1, None, 0, 1]
    position_m = [4.0, 1.0, 2.0, 100.0, 3.0, 9.0]
    heading_deg = [1.0, 7.0, 6.0, 0.0, 2.0, 3.0]
    assert per_walk_summary(walk_ids, position_m, heading_deg) == [
        {"walk_id": 0, "n": 2, "position_median_m": 2.0, "heading_within_5deg": 0.5},
        {"walk_id": 1, "n": 3, "position_median_m": 4.0, "heading_within_5deg": round(2 / 3, 4)},
    ]
    assert per_walk_summary([None, None], [1.0, 2.0], [1.0, 2.0]) == []


@pytest.mark.parametrize(
    ("manifest", "kind"),
    [
        ({"version": 1, "options": {"n_references": 60, "seed": 1}}, "scattered"),  # older/scattered: no key
        ({"version": 1}, "scattered"),
        ({"version": 1, "options": {"capture": "walk"}}, "walk"),
    ],
)
def test_capture_kind_reads_a_manifest_without_capture_as_scattered(manifest: dict[str, object], kind: str) -> None:
    assert capture_kind(manifest) == kind
