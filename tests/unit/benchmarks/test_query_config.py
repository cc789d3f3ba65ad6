"""bench_query_config's ``--config NAME=FIELD:VALUE,...``: typed fields of the default QueryConfig, errors named."""

from __future__ import annotations

import pytest

from benchmarks.bench_query_config import parse_config
from geoloc.localize.query import QueryConfig


def test_config_fields_are_replaced_with_their_types() -> None:
    name, config = parse_config("lean=anchor_references:3,pnp_threshold_px:5.5,refine_anchored:false")
    assert name == "lean"
    assert config.anchor_references == 3 and isinstance(config.anchor_references, int)
    assert config.pnp_threshold_px == 5.5 and config.refine_anchored is False
    assert config.shortlist == QueryConfig().shortlist  # the rest is the default's


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("lean=no_such_field:3", "no field 'no_such_field'"),
        ("lean=", "expected NAME=FIELD:VALUE"),
        ("=shortlist:10", "expected NAME=FIELD:VALUE"),
        ("lean=shortlist:ten", "shortlist is int, not 'ten'"),
        ("lean=use_anchors:maybe", "use_anchors is bool"),
    ],
)
def test_bad_configs_are_refused_with_the_reason(text: str, reason: str) -> None:
    with pytest.raises(SystemExit, match=reason):
        parse_config(text)
