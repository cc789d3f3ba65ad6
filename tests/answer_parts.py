"""The ``search`` of a hand-made answer (the test plugins' handlers store answers without running the method)."""

from __future__ import annotations

from typing import Any

WHOLE_MAP_SEARCH: dict[str, Any] = {
    "region": "whole_map",
    "buildings": [],
    "positions": 4,
    "yaws": 72,
    "cell_m": 10.0,
    "identity": False,
    "position_prior": False,
    "heading_prior": False,
    "anchors": {"trusted": False, "inliers": 0, "references": [], "checks": {}},
    "config": {},
}
"""A likelihood search over the whole map without priors or anchors, as :class:`contracts.answers.QuerySearch`."""
