"""Numeric bounds of the form fields and of the ids in paths.

One table that both checks requests and documents them.

A value outside its bounds (or not finite) is a 422 ``invalid_request`` that names the field, its
bounds and the value sent; the OpenAPI schema shows the same bounds as ``minimum``/``maximum``.
Ids are SQLite row ids: 64-bit signed integers from 1 (:data:`MAX_ID`), so a larger number in a path
is a 422 rather than an overflow deep in the database driver.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

from fastapi import Form, Path

from service.errors import ApiError

MAX_ID = 2**63 - 1
"""Largest id: SQLite's INTEGER PRIMARY KEY is a signed 64-bit integer."""


def _id_in_path(what: str) -> Any:
    return Path(ge=1, le=MAX_ID, description=f"The {what}'s id (a 64-bit integer from 1)")


MapId = Annotated[int, _id_in_path("map")]
ReferenceId = Annotated[int, _id_in_path("reference")]
QueryId = Annotated[int, _id_in_path("query")]
TrackId = Annotated[int, _id_in_path("track")]
JobId = Annotated[int, _id_in_path("job")]

BOUNDS: dict[str, tuple[float, float]] = {
    "lat": (-90.0, 90.0),
    "lon": (-180.0, 180.0),
    "radius_m": (1.0, 5000.0),
    "heading_deg": (0.0, 360.0),
    "focal_length_35mm": (1.0, 2000.0),
    "top_n": (1, 50),
    "k": (1, 20),
    "wait_s": (0.0, 300.0),
}
"""Inclusive (low, high) per form field name."""


def documented(name: str) -> dict[str, Any]:
    """``json_schema_extra`` for a form field: its bounds as OpenAPI ``minimum`` and ``maximum``."""
    low, high = BOUNDS[name]
    return {"minimum": low, "maximum": high}


def bounded_form(name: str, description: str) -> Any:
    """A form field ``name`` with ``description`` and its bounds documented (:func:`documented`)."""
    return Form(description=description, json_schema_extra=documented(name))


def check_bounds(name: str, value: float | None) -> None:
    """Raise a 422 when ``value`` (None passes) is not finite or outside ``BOUNDS[name]``.

    Raises
    ------
    ApiError
        422 ``invalid_request`` with the field, its bounds and the value in the message.
    """
    low, high = BOUNDS[name]
    if value is not None and not (math.isfinite(value) and low <= value <= high):
        raise ApiError(422, "invalid_request", f"{name} must be between {low:g} and {high:g}, got {value}")
