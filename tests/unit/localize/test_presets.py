"""The query presets: each name maps to its documented ``QueryConfig``; ``balanced`` is today's default."""

from __future__ import annotations

from dataclasses import fields

import pytest

from contracts.queries import DEFAULT_QUERY_PRESET, QUERY_PRESETS, QueryParams
from contracts.settings import Settings, SettingsError
from geoloc.localize.query import PRESETS, QueryConfig, preset_config

CHEAPER_WHEN_SMALLER = ("shortlist", "anchor_references", "n_yaws", "refine_poses")
"""Knobs whose smaller value is less work; a larger ``cell_m`` is less work."""


def test_every_preset_has_a_config_and_balanced_is_the_default() -> None:
    assert tuple(PRESETS) == QUERY_PRESETS
    assert PRESETS["balanced"] == QueryConfig()
    assert DEFAULT_QUERY_PRESET == "balanced" and Settings.from_values().query_preset == "balanced"


def test_fast_does_less_and_accurate_more_than_balanced() -> None:
    fast, balanced, accurate = PRESETS["fast"], PRESETS["balanced"], PRESETS["accurate"]
    for name in CHEAPER_WHEN_SMALLER:
        assert getattr(fast, name) <= getattr(balanced, name) <= getattr(accurate, name), name
    assert fast.cell_m >= balanced.cell_m >= accurate.cell_m
    assert fast != balanced != accurate
    # Only the cost knobs differ: the trust rules and the likelihood's model are the same in every preset.
    cost = {*CHEAPER_WHEN_SMALLER, "cell_m"}
    for field in fields(QueryConfig):
        if field.name not in cost:
            assert getattr(fast, field.name) == getattr(balanced, field.name) == getattr(accurate, field.name)


def test_preset_config_keeps_the_query_k() -> None:
    assert preset_config("fast") is PRESETS["fast"]
    config = preset_config("accurate", k=7)
    assert config.k == 7 and config.shortlist == PRESETS["accurate"].shortlist
    assert preset_config("balanced", k=4) == QueryConfig()


def test_parameters_stored_without_a_preset_are_balanced() -> None:
    old = QueryParams.from_json({"top_n": 10, "k": 4, "prior": None})
    assert old.preset is None and old.preset_name == "balanced" and "preset" not in old.to_json()
    new = QueryParams(top_n=10, k=4, preset="fast")
    assert QueryParams.from_json(new.to_json()).preset_name == "fast"


def test_the_default_preset_setting_is_checked() -> None:
    assert Settings.from_values(query_preset="accurate").query_preset == "accurate"
    with pytest.raises(SettingsError, match="QUERY_PRESET"):
        Settings.from_values(query_preset="fastest")
