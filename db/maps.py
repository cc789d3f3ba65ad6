"""Maps, their buildings and facades.

A map row holds the source file's path (relative to ``GEOLOC_DATA_DIR``, kept so that workers can
reload the full :class:`geoloc.maps.CityMap`), checksum, the options it was read with
(``read_options``, JSON of :meth:`geoloc.maps.MapReadOptions.as_dict`; a file read with other
options is another map), WGS84 bounding box, the local frame's origin, counts and the loader's
repair report. Buildings are rows (footprint as WGS84 GeoJSON text for the API and local-frame WKB
for the method). Facades are one (uncompressed) npz blob per map with the arrays of
:class:`geoloc.maps.Facades` (start, end, normal, normal_bearing_deg, length_m, building_id).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, fields
from typing import Any, Required, TypedDict, Unpack, cast

import numpy as np

from contracts.jobs import LOAD_MAP
from db.blobs import pack_arrays, unpack_arrays
from db.connection import Database
from db.jobs import cancel_queued_jobs
from db.rows import DeletedMap, MapRow


@dataclass
class BuildingRow:
    """One building as stored."""

    building_id: int
    osm_id: str | None
    name: str | None
    height_m: float | None
    footprint_geojson: dict[str, Any] | str  # a GeoJSON geometry, or its JSON text
    footprint_local_wkb: bytes | None = None


@dataclass
class MapContent:
    """What a loaded map contributes to the database (built by :func:`map_content_from_city_map`)."""

    bbox_wgs84: tuple[float, float, float, float]  # min_lat, min_lon, max_lat, max_lon
    origin_lat: float
    origin_lon: float
    buildings: list[BuildingRow]
    facade_arrays: dict[str, np.ndarray]
    repair_report: dict[str, Any]


def map_content_from_city_map(city_map: Any) -> MapContent:
    """Convert a ``geoloc.maps.CityMap`` into rows (duck-typed: db does not import geoloc).

    Vectorised over all buildings (one coordinate transform, GeoJSON and WKB written by GEOS), so a
    100,000-building map converts in seconds.
    """
    import shapely

    frame = city_map.frame
    footprints = np.empty(len(city_map.buildings), dtype=object)
    footprints[:] = [b.polygon for b in city_map.buildings]

    def to_wgs84(coords: np.ndarray) -> np.ndarray:
        lat, lon = frame.to_wgs84(coords[:, 0], coords[:, 1])
        return np.round(np.column_stack([lon, lat]), 7)

    geojson = shapely.to_geojson(shapely.transform(footprints, to_wgs84))
    wkb = shapely.to_wkb(footprints)
    buildings = [
        BuildingRow(
            building_id=int(b.building_id),
            osm_id=str(b.osm_id) if b.osm_id is not None else None,
            name=b.name,
            height_m=float(b.height_m) if b.height_m is not None else None,
            footprint_geojson=str(text),
            footprint_local_wkb=bytes(blob),
        )
        for b, text, blob in zip(city_map.buildings, geojson, wkb, strict=True)
    ]
    facades = city_map.facades
    facade_arrays = {f.name: np.asarray(getattr(facades, f.name)) for f in fields(facades)}
    report = city_map.report.as_dict() if hasattr(city_map.report, "as_dict") else dict(city_map.report)
    min_lat, min_lon, max_lat, max_lon = city_map.bbox_wgs84
    return MapContent(
        bbox_wgs84=(float(min_lat), float(min_lon), float(max_lat), float(max_lon)),
        origin_lat=float(frame.origin_lat),
        origin_lon=float(frame.origin_lon),
        buildings=buildings,
        facade_arrays=facade_arrays,
        repair_report=report,
    )


def _decode_map(row: dict[str, Any]) -> MapRow:
    row = dict(row)
    row["repair_report"] = json.loads(row["repair_report"] or "{}")
    row["read_options"] = json.loads(row.get("read_options") or "{}")
    row["error_details"] = json.loads(row.get("error_details") or "{}")
    row["bbox_wgs84"] = (row["min_lat"], row["min_lon"], row["max_lat"], row["max_lon"])
    return cast(MapRow, row)


class MapSource(TypedDict, total=False):
    """A map's row as the upload states it (name, file, checksum, read options, attribution)."""

    name: Required[str]
    source_filename: Required[str]
    source_format: Required[str]
    source_path: Required[str]
    sha256: Required[str]
    size_bytes: Required[int]
    read_options: dict[str, Any] | None
    """How the file was read (``MapReadOptions.as_dict()``; default ``{}``)."""
    attribution: str | None
    """What the upload stated, None for none (the column, from migration 6, is then left to its NULL)."""
    tenant: str | None
    """The uploading key's tenant (migration 8), None for untenanted (the column is then left to its NULL)."""


def insert_map(db: Database, *, content: MapContent, **source: Unpack[MapSource]) -> int:
    """Insert a map with its buildings and facades (status ``done``); returns the map id. Call inside a transaction."""
    map_id = _insert_row(db, source, pending=False)  # the status column's default, done (none before migration 9)
    _write_content(db, map_id, content)
    return map_id


def insert_pending_map(db: Database, **source: Unpack[MapSource]) -> int:
    """Insert a map whose file is not parsed yet (status ``queued``, no buildings, zeros for box and counts).

    Returns the map id; call inside a transaction. :func:`store_map_content` fills it once parsed.
    """
    return _insert_row(db, source, pending=True)


def _insert_row(db: Database, source: MapSource, pending: bool) -> int:
    """Insert a map's row with zeros for box and counts (``pending``: status ``queued``, else the default)."""
    optional = {"attribution": source.get("attribution"), "tenant": source.get("tenant")}
    stated = tuple(name for name, value in optional.items() if value is not None)
    status = ("status",) if pending else ()
    columns = ", ".join(("repair_report", "read_options", "created_at", *status, *stated))
    return db.insert_returning_id(
        "INSERT INTO maps (name, source_filename, source_format, source_path, sha256, size_bytes,"
        " min_lat, min_lon, max_lat, max_lon, origin_lat, origin_lon, building_count, facade_count,"
        f" {columns}) VALUES ({', '.join('?' * (17 + len(status) + len(stated)))})",
        (
            *(source[key] for key in ("name", "source_filename", "source_format", "source_path", "sha256")),
            source["size_bytes"],
            *(0.0,) * 6,
            0,
            0,
            "{}",
            _options_json(source.get("read_options")),
            time.time(),
            *(("queued",) if pending else ()),
            *(optional[name] for name in stated),
        ),
    )


def store_map_content(db: Database, map_id: int, content: MapContent) -> bool:
    """Write a parsed map's buildings, facades, box and counts, and mark it ``done``; call inside a transaction.

    Replace semantics (a parse that runs again after a crash leaves the same rows). False, and nothing
    written, when the map is gone (deleted while it was parsed): the row's update comes first and holds the
    row (PostgreSQL) or the database (SQLite) until commit, so a delete cannot slip in between.
    """
    cursor = db.execute(
        "UPDATE maps SET status = 'done', error = NULL, parsed_buildings = ? WHERE id = ?",
        (len(content.buildings), map_id),
    )
    if cursor.rowcount != 1:
        return False
    _write_content(db, map_id, content)
    return True


def _write_content(db: Database, map_id: int, content: MapContent) -> None:
    """A map's box, counts and report on its row, and its buildings and facades (replacing any)."""
    min_lat, min_lon, max_lat, max_lon = content.bbox_wgs84
    facade_count = len(next(iter(content.facade_arrays.values()))) if content.facade_arrays else 0
    db.execute(
        "UPDATE maps SET min_lat = ?, min_lon = ?, max_lat = ?, max_lon = ?, origin_lat = ?, origin_lon = ?,"
        " building_count = ?, facade_count = ?, repair_report = ? WHERE id = ?",
        (
            min_lat,
            min_lon,
            max_lat,
            max_lon,
            content.origin_lat,
            content.origin_lon,
            len(content.buildings),
            facade_count,
            json.dumps(content.repair_report),
            map_id,
        ),
    )
    db.execute("DELETE FROM buildings WHERE map_id = ?", (map_id,))
    db.execute("DELETE FROM facades WHERE map_id = ?", (map_id,))
    db.executemany(
        "INSERT INTO buildings (map_id, building_id, osm_id, name, height_m, footprint_geojson,"
        " footprint_local_wkb) VALUES (?, ?, ?, ?, ?, ?, ?)",
        [
            (
                map_id,
                b.building_id,
                b.osm_id,
                b.name,
                b.height_m,
                b.footprint_geojson if isinstance(b.footprint_geojson, str) else json.dumps(b.footprint_geojson),
                b.footprint_local_wkb,
            )
            for b in content.buildings
        ],
    )
    db.execute(
        "INSERT INTO facades (map_id, facade_count, arrays_npz) VALUES (?, ?, ?)",
        (map_id, facade_count, pack_arrays(content.facade_arrays, compress=False)),
    )


def link_map_job(db: Database, map_id: int, job_id: int) -> None:
    """Record the ``load_map`` job of a map (inside the transaction that queued it)."""
    db.execute("UPDATE maps SET job_id = ? WHERE id = ?", (job_id, map_id))


def set_map_progress(db: Database, map_id: int, elements: int, buildings: int) -> None:
    """Record a parse's progress: elements read and buildings found so far (a map not yet done)."""
    db.execute(
        "UPDATE maps SET parsed_elements = ?, parsed_buildings = ? WHERE id = ? AND status = 'queued'",
        (elements, buildings, map_id),
    )


def fail_map(
    db: Database, map_id: int, error: str, code: str = "invalid_map", details: dict[str, Any] | None = None
) -> None:
    """Mark a map ``failed`` with the reason (shown to users: no server paths), its code and details (JSON-ready)."""
    db.execute(
        "UPDATE maps SET status = 'failed', error = ?, error_code = ?, error_details = ?"
        " WHERE id = ? AND status != 'done'",
        (error, code, json.dumps(details or {}), map_id),
    )


def get_map(db: Database, map_id: int) -> MapRow | None:
    """One map row (decoded), or None."""
    rows = list(db.query("SELECT * FROM maps WHERE id = ?", (map_id,)))
    return _decode_map(rows[0]) if rows else None


def _options_json(read_options: dict[str, Any] | None) -> str:
    return json.dumps(read_options or {}, sort_keys=True)


def tenant_condition(tenant: str | None, column: str = "tenant") -> tuple[str, tuple[str, ...]]:
    """SQL matching the rows of ``tenant`` (None: the untenanted rows), with its parameters.

    ``column = ?`` never matches NULL, so the untenanted rows are asked with ``IS NULL`` (both engines).
    """
    return (f"{column} IS NULL", ()) if tenant is None else (f"{column} = ?", (tenant,))


def find_map_by_sha256(
    db: Database, sha256: str, read_options: dict[str, Any] | None = None, tenant: str | None = None
) -> MapRow | None:
    """The tenant's oldest map uploaded from a file with this checksum and read with these options, or None.

    A map that failed is not one: the same file sent again is parsed again (by a newer service, say).
    tenant: None for the untenanted maps; another tenant's upload of the same file is another map.
    """
    condition, tenant_args = tenant_condition(tenant)
    rows = list(
        db.query(
            "SELECT * FROM maps WHERE sha256 = ? AND read_options = ? AND status != 'failed'"
            f" AND {condition} ORDER BY id LIMIT 1",
            (sha256, _options_json(read_options), *tenant_args),
        )
    )
    return _decode_map(rows[0]) if rows else None


def list_maps(db: Database, tenant: str | None = None) -> list[MapRow]:
    """The maps of ``tenant`` (None: the untenanted maps), oldest first."""
    condition, tenant_args = tenant_condition(tenant)
    return [_decode_map(row) for row in db.query(f"SELECT * FROM maps WHERE {condition} ORDER BY id", tenant_args)]


def map_reference_counts(db: Database, map_id: int) -> dict[str, int]:
    """Number of references of a map per status."""
    rows = db.query("SELECT status, COUNT(*) AS n FROM reference_images WHERE map_id = ? GROUP BY status", (map_id,))
    return {row["status"]: int(row["n"]) for row in rows}


def list_buildings(
    db: Database, map_id: int, decode: bool = True, building_ids: list[int] | None = None
) -> list[dict[str, Any]]:
    """Buildings of a map (no WKB), by building id; only those of ``building_ids`` when given.

    ``footprint_geojson`` is decoded, or left as its JSON text with ``decode=False``.
    """
    if building_ids is not None and not building_ids:
        return []
    only = "" if building_ids is None else f" AND building_id IN ({', '.join('?' * len(building_ids))})"
    rows = db.query(
        "SELECT building_id, osm_id, name, height_m, footprint_geojson FROM buildings"
        f" WHERE map_id = ?{only} ORDER BY building_id",
        (map_id, *(building_ids or ())),
    )
    out = []
    for row in rows:
        building = dict(row)
        if decode:
            building["footprint_geojson"] = json.loads(building["footprint_geojson"])
        out.append(building)
    return out


def get_facade_arrays(db: Database, map_id: int) -> dict[str, np.ndarray] | None:
    """The facade arrays of a map, or None."""
    row = db.execute("SELECT arrays_npz FROM facades WHERE map_id = ?", (map_id,)).fetchone()
    return unpack_arrays(row[0]) if row else None


def delete_map(db: Database, map_id: int) -> DeletedMap | None:
    """Delete a map and everything under it; call inside a transaction.

    Buildings, facades, references, labels, index and queries cascade; queued jobs are cancelled, and the map's
    finished ``load_map`` job is deleted.
    Returns the deleted map row with the image paths to remove from disk after commit
    (``image_paths``) and whether another map still reads the same source file (``source_shared``),
    or None.
    """
    map_row = get_map(db, map_id)
    if map_row is None:
        return None
    image_paths = [
        r["image_path"] for r in db.query("SELECT image_path FROM reference_images WHERE map_id = ?", (map_id,))
    ]
    image_paths += [
        r["image_path"]
        for r in db.query("SELECT image_path FROM queries WHERE map_id = ? AND image_path IS NOT NULL", (map_id,))
    ]
    cancel_queued_jobs(db, map_id=map_id)
    # The map's own parse job goes with it once finished (a running one finds the map gone when it stores).
    db.execute(
        "DELETE FROM jobs WHERE map_id = ? AND kind = ? AND status IN ('done', 'failed', 'cancelled')",
        (map_id, LOAD_MAP),
    )
    db.execute("DELETE FROM maps WHERE id = ?", (map_id,))
    source_shared = (
        db.execute("SELECT 1 FROM maps WHERE source_path = ? LIMIT 1", (map_row["source_path"],)).fetchone() is not None
    )
    return DeletedMap(**map_row, image_paths=image_paths, source_shared=source_shared)
