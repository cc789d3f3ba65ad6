"""Small maps that the tests and the benchmarks both upload (GeoJSON, WGS84 lon/lat)."""

from __future__ import annotations

from typing import Any

ONE_BUILDING: dict[str, Any] = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "id": "way/1",
            "properties": {"building": "yes", "name": "Hall"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [
                    [[24.94, 60.17], [24.9404, 60.17], [24.9404, 60.1702], [24.94, 60.1702], [24.94, 60.17]]
                ],
            },
        }
    ],
}
"""One building, "Hall" (about 22 x 22 m in Helsinki): a map that loads in a moment."""
