"""GeoJSON answers (``?format=geojson`` or ``Accept: application/geo+json``), as a client reads them.

The service builds these collections as plain JSON (:mod:`service.geojson`) and documents them by hand
(``GEOJSON_RESPONSE``): they are not in the OpenAPI components.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import ConfigDict

from contracts.api.base import ApiModel


class Feature(ApiModel):
    """A GeoJSON feature (WGS84 lon/lat); ``properties`` as the API documents them per collection."""

    model_config = ConfigDict(extra="allow")

    type: Literal["Feature"]
    geometry: dict[str, Any] | None
    properties: dict[str, Any] | None = None


class FeatureCollection(ApiModel):
    """A GeoJSON FeatureCollection; foreign members (``attribution``, ``status``, ...) in ``model_extra``."""

    model_config = ConfigDict(extra="allow")

    type: Literal["FeatureCollection"]
    features: list[Feature]

    def member(self, name: str) -> Any:
        """A foreign member such as ``attribution`` or ``status`` (None when absent)."""
        return (self.model_extra or {}).get(name)
