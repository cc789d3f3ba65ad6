"""Coordinates of GIS files to WGS84 longitude/latitude, with a clear refusal when they cannot be.

A layer's coordinates are converted from the CRS it declares (or the one the user names, which
overrides it) with pyproj (``always_xy``: x = easting/longitude). A layer that declares no CRS is
taken as WGS84 lon/lat, as RFC 7946 says for GeoJSON. Refused, with :class:`MapLoadError` saying what
the coordinates look like and how to fix it:

- coordinates read as lon/lat that cannot be (outside +-180 / +-90): the message guesses the CRS
  (swapped lat/lon, projected metres such as EPSG:3857 Web Mercator or a UTM zone) and, for Web
  Mercator, where the data would then lie;
- a layer whose features disagree (some in degrees, some in metres: a mixed CRS), told from
  coordinates that cannot be lon/lat next to ones that can, or, in a projected CRS, from features
  whose every coordinate is within +-180 next to ones in metres;
- a map wider than :data:`MAX_MAP_EXTENT_KM` (a map is a city or a region, not a continent).
"""

from __future__ import annotations

import math

import numpy as np
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError, ProjError

from geoloc.maps.model import MapLoadError

MAX_MAP_EXTENT_KM = 300.0
"""Widest accepted map (bounding box diagonal of its buildings)."""
WGS84 = CRS.from_epsg(4326)
NO_CRS = "none declared (read as WGS84 lon/lat)"
_WEB_MERCATOR_LIMIT_M = 20_037_508.35
_FIX = (
    "Fix: reproject the file to WGS84 (e.g. `ogr2ogr -t_srs EPSG:4326 out.gpkg in.gpkg`), make the file "
    "declare its CRS, or name the CRS of its coordinates with the crs option (form field crs=EPSG:3857, "
    "geoloc map info --crs EPSG:3857)."
)


def parse_crs(text: str) -> CRS:
    """A CRS from user input (``EPSG:3857``, ``3857``, a WKT or PROJ string); :class:`MapLoadError` if unknown."""
    value = text.strip()
    try:
        return CRS.from_user_input(int(value) if value.isdigit() else value)
    except (CRSError, ValueError, TypeError) as exc:
        raise MapLoadError(
            f"unknown CRS {text!r}: give an EPSG code such as EPSG:3857, or a WKT/PROJ definition",
            code="invalid_crs",
        ) from exc


def crs_label(crs: CRS) -> str:
    """``EPSG:nnnn`` where the CRS has an EPSG code, else its name."""
    code = crs.to_epsg(min_confidence=70)
    return f"EPSG:{code}" if code else crs.name


def to_lonlat(xy: np.ndarray, owner: np.ndarray, crs: CRS | None, what: str) -> tuple[np.ndarray, str]:
    """Convert coordinates (N, 2) in ``crs`` (None: undeclared, taken as WGS84) to lon/lat degrees.

    owner: (N,) index of the feature each coordinate belongs to (to tell a mixed CRS from a wrong
    one). what: how to name the data in messages (e.g. the layer). Returns (lonlat (N, 2), a label of
    the source CRS). Raises :class:`MapLoadError` when the result cannot be lon/lat of one place.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    label = crs_label(crs) if crs is not None else NO_CRS
    if not np.isfinite(xy).all():
        raise MapLoadError(f"{what}: coordinates include NaN or infinite values", code="invalid_coordinates")
    if crs is None or crs.is_geographic:
        bad = _not_lonlat(xy)
        if bad.any():
            raise _not_lonlat_error(xy, owner, bad, label, what)
        if crs is None or crs.equals(WGS84, ignore_axis_order=True) or _is_crs84(crs):
            lonlat = xy
        else:
            lonlat = _transform(xy, crs, what, label)
    else:
        degree_like = (np.abs(xy) <= 180.0).all(axis=1)
        metric_features = np.unique(owner[~degree_like])
        if 0 < len(metric_features) < len(np.unique(owner)):
            raise _mixed_error(owner, degree_like, label, what)
        lonlat = _transform(xy, crs, what, label)
    _check_extent(lonlat, label, what)
    return lonlat, label


def _is_crs84(crs: CRS) -> bool:
    return crs.to_string().upper() in ("OGC:CRS84", "URN:OGC:DEF:CRS:OGC:1.3:CRS84")


def _not_lonlat(xy: np.ndarray) -> np.ndarray:
    return np.asarray((np.abs(xy[:, 0]) > 180.0) | (np.abs(xy[:, 1]) > 90.0))


def _transform(xy: np.ndarray, crs: CRS, what: str, label: str) -> np.ndarray:
    try:
        transformer = Transformer.from_crs(crs, WGS84, always_xy=True)
        lon, lat = transformer.transform(xy[:, 0], xy[:, 1], errcheck=False)
    except (ProjError, CRSError) as exc:
        raise MapLoadError(f"{what}: cannot convert from {label} to WGS84 ({exc})", code="invalid_crs") from exc
    lonlat = np.column_stack([lon, lat])
    if not np.isfinite(lonlat).all() or _not_lonlat(lonlat).any():
        raise MapLoadError(
            f"{what}: some coordinates lie outside the area of the declared CRS {label} and cannot be "
            f"converted to WGS84; the file's coordinates may not be in {label}. {_FIX}",
            code="crs_mismatch",
            details={"crs": label, **_ranges(xy)},
        )
    return lonlat


def _ranges(xy: np.ndarray) -> dict[str, list[float]]:
    return {
        "x_range": [round(float(xy[:, 0].min()), 3), round(float(xy[:, 0].max()), 3)],
        "y_range": [round(float(xy[:, 1].min()), 3), round(float(xy[:, 1].max()), 3)],
    }


def guess_crs(xy: np.ndarray) -> tuple[str, dict[str, object]]:
    """What coordinates that are not lon/lat look like: (a phrase for a message, details)."""
    x, y = xy[:, 0], xy[:, 1]
    if (np.abs(x) <= 90.0).all() and (np.abs(y) <= 180.0).all():
        phrase = "latitude/longitude in swapped order (latitude first; GeoJSON and GIS files put longitude first)"
        return phrase, {"guess": "swapped_lat_lon"}
    if (np.abs(x) <= _WEB_MERCATOR_LIMIT_M).all() and (np.abs(y) <= _WEB_MERCATOR_LIMIT_M * 1.001).all():
        cx, cy = float(np.median(x)), float(np.median(y))
        lon, lat = Transformer.from_crs("EPSG:3857", WGS84, always_xy=True).transform(cx, cy)
        phrase = (
            f"projected metres, e.g. EPSG:3857 Web Mercator (read so, the data lies near "
            f"{abs(lat):.4f}°{'N' if lat >= 0 else 'S'} {abs(lon):.4f}°{'E' if lon >= 0 else 'W'})"
        )
        if (x >= 100_000).all() and (x <= 900_000).all() and (y >= 0).all() and (y <= 10_000_000).all():
            phrase += ", or a UTM zone (EPSG:326xx north, EPSG:327xx south) or a national grid"
        return phrase, {"guess": "projected_metres", "if_epsg_3857": {"lat": round(lat, 6), "lon": round(lon, 6)}}
    return "no common CRS (values beyond any projected world extent)", {"guess": "unknown"}


def _not_lonlat_error(xy: np.ndarray, owner: np.ndarray, bad: np.ndarray, label: str, what: str) -> MapLoadError:
    if len(np.setdiff1d(np.unique(owner), owner[bad])):  # some features are fine: a mix, not a wrong CRS
        return _mixed_error(owner, ~bad, label, what)
    phrase, details = guess_crs(xy)
    why = "the file declares no CRS" if label == NO_CRS else f"the CRS is {label}"
    return MapLoadError(
        f"{what}: coordinates are read as WGS84 longitude/latitude ({why}) but x spans "
        f"{_span(xy[:, 0])} and y {_span(xy[:, 1])}, which cannot be degrees: they look like {phrase}. {_FIX}",
        code="crs_not_lonlat",
        details={"crs": label, **_ranges(xy), **details},
    )


def _mixed_error(owner: np.ndarray, degree_like: np.ndarray, label: str, what: str) -> MapLoadError:
    """Some features' coordinates look like degrees (all of a feature's ``degree_like``), others like metres."""
    metric_features = np.unique(owner[~degree_like])
    degree_features = np.setdiff1d(np.unique(owner), metric_features)
    return MapLoadError(
        f"{what}: the features mix coordinate systems: {len(degree_features)} have coordinates that look like "
        f"longitude/latitude degrees and {len(metric_features)} like projected metres (the layer's CRS: {label}). "
        "Export all features in one CRS and upload again.",
        code="mixed_crs",
        details={"crs": label, "features_in_degrees": len(degree_features), "features_in_metres": len(metric_features)},
    )


def _check_extent(lonlat: np.ndarray, label: str, what: str) -> None:
    lon, lat = lonlat[:, 0], lonlat[:, 1]
    extent_km = _haversine_km(lat.min(), lon.min(), lat.max(), lon.max())
    if extent_km > MAX_MAP_EXTENT_KM:
        raise MapLoadError(
            f"{what}: the buildings spread over {extent_km:,.0f} km (lat {lat.min():.4f}..{lat.max():.4f}, "
            f"lon {lon.min():.4f}..{lon.max():.4f}); a map covers at most {MAX_MAP_EXTENT_KM:.0f} km: split it into "
            "city-sized extracts, or check that all features use the same CRS",
            code="map_too_wide",
            details={"extent_km": round(extent_km, 1), "crs": label},
        )


def _span(values: np.ndarray) -> str:
    return f"{values.min():,.2f}..{values.max():,.2f}"


def _haversine_km(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * 6371.0088 * math.asin(min(1.0, math.sqrt(h)))
