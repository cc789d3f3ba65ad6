"""The OpenAPI document follows the configuration (``service/spec.py``), and the rate limiter's arithmetic."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from contracts.settings import Settings
from service.app import create_app
from service.errors import allowed_methods
from service.limits import RateLimiter


def _spec(**values: Any) -> dict[str, Any]:
    return create_app(Settings.from_values(data_dir=Path("/nonexistent-geoloc-data"), **values)).openapi()


def _operations(spec: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    return [(path, method, op) for path, item in spec["paths"].items() for method, op in item.items()]


def test_without_keys_no_operation_asks_for_one() -> None:
    spec = _spec()
    assert "securitySchemes" not in spec["components"]
    for path, method, op in _operations(spec):
        assert "security" not in op and not {"401", "403"} & set(op["responses"]), (method, path)
        if "429" in op["responses"]:
            assert "rate_limited" not in op["responses"]["429"]["description"], (method, path)


def test_with_keys_each_v1_operation_has_its_scope_401_403_and_the_rate_limit() -> None:
    spec = _spec(api_keys="k:read+write", rate_limit_per_min=120)
    for path, method, op in _operations(spec):
        if not path.startswith("/v1/"):
            assert "security" not in op, (method, path)
            continue
        # A track is a set of queries: asking where photos were taken needs read, as a query does.
        scope = "read" if method == "get" or (method == "post" and path.endswith(("/queries", "/tracks"))) else "write"
        assert op["security"] == [{"APIKeyHeader": [scope]}], (method, path)
        assert {"401", "403", "429"} <= set(op["responses"]), (method, path)
        assert "120 requests a minute" in op["responses"]["429"]["description"]
        assert op["responses"]["429"]["headers"]["Retry-After"]["schema"]["type"] == "integer"


def test_rate_limit_off_leaves_only_the_queue_429() -> None:
    spec = _spec(api_keys="k:read+write", rate_limit_per_min=0)
    assert "429" not in spec["paths"]["/v1/maps"]["get"]["responses"]
    assert "queue_full" in spec["paths"]["/v1/maps/{map_id}/queries"]["post"]["responses"]["429"]["description"]


def test_forms_carry_no_null_files_are_not_empty_and_errors_have_one_body() -> None:
    spec = _spec()
    schemas = spec["components"]["schemas"]
    assert "HTTPValidationError" not in schemas
    form = schemas["Body_create_query_v1_maps__map_id__queries_post"]["properties"]
    assert form["lat"]["type"] == "number" and "anyOf" not in form["lat"] and "default" not in form["lat"]
    assert form["image"]["minLength"] == 1
    for path, method, op in _operations(spec):
        for status, response in op["responses"].items():
            if status.startswith(("4", "5")):
                assert response["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorResponse")
        if method in ("post", "delete"):
            assert "507" in op["responses"], (method, path)
    ids = spec["paths"]["/v1/maps/{map_id}"]["get"]["parameters"][0]["schema"]
    assert (ids["minimum"], ids["maximum"]) == (1, 2**63 - 1)


def test_allow_lists_every_documented_method_of_a_path() -> None:
    app = create_app(Settings.from_values(data_dir=Path("/nonexistent-geoloc-data")))
    assert allowed_methods(app, "/v1/maps/7") == ["DELETE", "GET"]
    assert allowed_methods(app, "/v1/maps") == ["GET", "POST"]
    assert allowed_methods(app, "/v1/maps/7/buildings") == ["GET"]
    assert allowed_methods(app, "/nowhere") == []


@pytest.mark.parametrize("per_minute", [1, 5, 600])
def test_rate_limiter_allows_a_minute_then_refills_evenly(per_minute: int) -> None:
    now = [1000.0]
    limiter = RateLimiter(per_minute, clock=lambda: now[0])
    assert all(limiter.acquire("k") is None for _ in range(per_minute))
    wait_s = limiter.acquire("k")
    assert wait_s == max(1, round(60 / per_minute))
    assert limiter.acquire("other") is None, "each key has its own bucket"
    now[0] += 60 / per_minute
    assert limiter.acquire("k") is None and limiter.acquire("k") is not None
