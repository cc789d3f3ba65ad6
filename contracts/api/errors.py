"""The API's error body ``{"error": {"code", "message", "details"}}`` and every (status, code) it answers with."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from contracts.api.base import ApiModel

CODES_BY_STATUS: dict[int, str] = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    409: "conflict",
    413: "payload_too_large",
    415: "unsupported_media_type",
    422: "invalid_request",
    500: "internal_error",
    503: "unavailable",
    507: "insufficient_storage",
}
"""The code of an HTTP error raised without one of the service's own codes, by status."""

ERROR_CODES: tuple[tuple[int, str], ...] = (
    *sorted(CODES_BY_STATUS.items()),
    (400, "invalid_request_id"),
    (408, "request_timeout"),
    (409, "map_not_ready"),
    (409, "not_ready"),
    (413, "too_many_frames"),
    (413, "too_many_pixels"),
    (415, "not_an_image"),
    (415, "unsupported_image_format"),
    (422, "corrupt_image"),
    (422, "empty_file"),
    (422, "foreign_query"),
    (422, "not_an_image"),
    (422, "unsupported_image_format"),
    (422, "image_too_small"),
    (422, "ambiguous_place"),
    (422, "invalid_map"),
    (422, "no_position"),
    (422, "outside_map"),
    (422, "unknown_place"),
    (422, "unsupported_projection"),
    (429, "queue_full"),
    (429, "rate_limited"),
    (503, "database_unavailable"),
    (503, "not_ready"),
)
"""Every (status, code) the service answers with; the OpenAPI schema of ``ErrorDetail.code`` lists them
(``tests/unit/service/test_openapi_doc.py`` fails when a code is raised that is not here)."""


class ErrorDetail(ApiModel):
    """What went wrong: a machine-readable code, a message for people, and details."""

    code: str = Field(
        description="Machine-readable error code",
        examples=["outside_map"],
        json_schema_extra={
            # A list display (not sorted()'s list[str]) so that it types as a list of JSON values.
            "enum": [*sorted({code for _, code in ERROR_CODES})],
            "x-error-codes": [{"status": status, "code": code} for status, code in sorted(ERROR_CODES)],
        },
    )
    message: str = Field(description="What went wrong, for people", examples=["position is 5300 m outside the map"])
    details: dict[str, Any] | None = Field(default=None, description="Extra facts (limits, distances, fields)")


class ErrorResponse(ApiModel):
    """The body of every 4xx/5xx answer."""

    error: ErrorDetail
