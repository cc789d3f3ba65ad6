"""``GEOLOC_API_KEYS``: scopes and tenants per key, the old ``KEY:SCOPES`` form, and clear errors."""

from __future__ import annotations

import pytest

from contracts.keys import ApiKey, parse_api_keys
from contracts.settings import Settings, SettingsError

READ = frozenset({"read"})
BOTH = frozenset({"read", "write"})


def test_tenants_are_parsed_per_key_and_old_entries_have_none() -> None:
    keys = parse_api_keys(" a:read+write@team-a , b:read@team.b_2,c:write, d , e@Team-E,")
    assert keys == {
        "a": ApiKey(BOTH, "team-a"),
        "b": ApiKey(READ, "team.b_2"),
        "c": ApiKey(BOTH, None),
        "d": ApiKey(BOTH, None),
        "e": ApiKey(BOTH, "Team-E"),
    }


def test_the_tenant_is_split_at_the_last_at_sign() -> None:
    assert parse_api_keys("k@ey:read@t") == {"k@ey": ApiKey(READ, "t")}


def test_a_tenant_of_64_characters_is_accepted_and_65_refused() -> None:
    assert parse_api_keys("k:read@" + "t" * 64)["k"].tenant == "t" * 64
    with pytest.raises(ValueError, match="must be 1 to 64 letters"):
        parse_api_keys("k:read@" + "t" * 65)


@pytest.mark.parametrize(
    ("raw", "reason"),
    [
        ("k:read@", "tenant '' must be"),
        ("k:read@team/a", "tenant 'team/a' must be"),
        ("k:read@tëam", "tenant 'tëam' must be"),
        (":read@team", "expected KEY:read"),
        ("k:admin@team", "expected KEY:read"),
    ],
)
def test_bad_entries_are_refused_with_the_reason(raw: str, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        parse_api_keys(raw)


def test_settings_hold_the_key_records() -> None:
    settings = Settings.from_values(api_keys="w:write@a,r:read")
    assert settings.api_keys == {"w": ApiKey(BOTH, "a"), "r": ApiKey(READ)} and settings.auth_enabled
    with pytest.raises(SettingsError, match="GEOLOC_API_KEYS"):
        Settings.from_values(api_keys="w:write@a b")
