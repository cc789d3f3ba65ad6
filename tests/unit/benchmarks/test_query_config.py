"""The benchmarks' ``--config NAME=FIELD:VALUE,...``: typed fields of a default configuration, errors named."""

from __future__ import annotations

import pytest

from benchmarks.config_args import parse_config
from geoloc.localize.query import QueryConfig
from geoloc.localize.sequence import PlacementOptions


def test_config_fields_are_replaced_with_their_types() -> None:
    name, config = parse_config("lean=anchor_references:3,pnp_threshold_px:5.5,refine_anchored:false", QueryConfig())
    assert name == "lean"
    assert config.anchor_references == 3 and isinstance(config.anchor_references, int)
    assert config.pnp_threshold_px == 5.5 and config.refine_anchored is False
    assert config.shortlist == QueryConfig().shortlist  # the rest is the default's


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("lean=no_such_field:3", "QueryConfig has no field 'no_such_field'"),
        ("lean=", "expected NAME=FIELD:VALUE"),
        ("=shortlist:10", "expected NAME=FIELD:VALUE"),
        ("lean=shortlist:ten", "shortlist is int, not 'ten'"),
        ("lean=use_anchors:maybe", "use_anchors is bool"),
    ],
)
def test_bad_configs_are_refused_with_the_reason(text: str, reason: str) -> None:
    with pytest.raises(SystemExit, match=reason):
        parse_config(text, QueryConfig())


def test_placement_options_take_none_and_refuse_what_a_flag_cannot_spell() -> None:
    name, options = parse_config("independent=gps_correlation_m:none,step_sigma_m:1", PlacementOptions())
    assert name == "independent" and options.gps_correlation_m is None and options.step_sigma_m == 1.0
    with pytest.raises(SystemExit, match="steps is tuple, which --config cannot set"):
        parse_config("two=steps:2", PlacementOptions())
