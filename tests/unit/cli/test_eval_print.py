"""``geoloc eval world``'s printed summary: the reference-pose figures, per walk, and the capture kind."""

from __future__ import annotations

from typing import Any

import pytest

from cli.eval import print_world_summary


def _result(reference_block: dict[str, Any], capture: str | None) -> dict[str, Any]:
    run = {
        "all": {
            "within_1m": 0.1,
            "within_5m": 0.3,
            "within_10m": 0.5,
            "median_error_m": 7.7,
            "heading_median_deg": 0.6,
            "heading_within_5deg": 0.6,
        },
        "shown": {"within_5m": 0.4, "within_10m": 0.6},
        "uncertainty_radius_holds_truth": 0.9,
        "anchored_share": 0.4,
        "top_n_error_m": {str(n): {"mean": 10.0 - n} for n in range(1, 11)},
    }
    result: dict[str, Any] = {
        "world": "/tmp/w",
        "references": 60,
        "queries": 30,
        "query_kinds": {"between": 12, "offset": 9, "unseen": 9},
        "shown_by_references": 20,
        "reference_labelling": {"model": reference_block},
        "query_identity_accuracy": {s: {"1": 0.7, "4": 0.8, "8": 0.8} for s in ("ours", "gt_reference_labels")},
        "gps_baseline": {"median_m": 20.0, "within_5m": 0.1, "within_10m": 0.2},
        "runs": {"ours/gps": run},
    }
    if capture is not None:
        result["capture"] = capture
    return result


def test_walk_world_prints_reference_pose_shares_and_walks(capsys: pytest.CaptureFixture[str]) -> None:
    block = {
        "identity_accuracy": {"greedy": 0.7, "marginalized": 0.72},
        "heading_error_deg": {"n": 60, "median": 0.3, "within_2deg": 0.9, "within_5deg": 0.95},
        "position_error_m": {"n": 60, "median_m": 3.6, "within_1m": 0.1, "within_2m": 0.25, "within_5m": 0.6},
        "per_walk": [{"walk_id": 2, "n": 15, "position_median_m": 2.5, "heading_within_5deg": 0.9333}],
    }
    print_world_summary(_result(block, "walk"), 12.0)
    out = capsys.readouterr().out
    assert "capture walk" in out
    assert "within 1 / 2 m 0.1 / 0.25; heading within 2 / 5 deg 0.9 / 0.95" in out
    assert "walk 2 (15 references): position median 2.5 m, heading within 5 deg 0.9333" in out


def test_json_from_before_the_new_keys_still_prints(capsys: pytest.CaptureFixture[str]) -> None:
    block = {
        "identity_accuracy": {"greedy": 0.7, "marginalized": 0.72},
        "heading_error_deg": {"n": 60, "median": 0.3, "within_5deg": 0.95},
        "position_error_m": {"n": 60, "median_m": 3.6, "within_5m": 0.6},
    }
    print_world_summary(_result(block, None), 12.0)
    out = capsys.readouterr().out
    assert "capture scattered" in out
    assert "within 1 / 2 m None / None" in out
    assert "  walk " not in out


def test_identity_losses_print_when_measured(capsys: pytest.CaptureFixture[str]) -> None:
    block = {
        "identity_accuracy": {"greedy": 0.7, "marginalized": 0.72},
        "heading_error_deg": {"n": 60, "median": 0.3, "within_2deg": 0.9, "within_5deg": 0.95},
        "position_error_m": {"n": 60, "median_m": 3.6, "within_1m": 0.1, "within_2m": 0.25, "within_5m": 0.6},
    }
    result = _result(block, None)
    result["query_identity_losses"] = {
        "outside_mask": 0.12,
        "no_identity": 0.02,
        "building_shown": 0.04,
        "building_not_shown": 0.01,
        "right": 0.81,
    }
    print_world_summary(result, 12.0)
    out = capsys.readouterr().out
    assert "(k=4): outside mask 0.12, no identity 0.02, building shown 0.04, building not shown 0.01, right 0.81" in out
