"""The routes' lookups for a tenant: a map, a reference, a query or a job the caller may see, else ``404``.

A map belongs to the tenant of the key that uploaded it (``maps.tenant``, None: untenanted); a reference, a
query and a track belong to their map's tenant (every one has a map); a job to the tenant stamped when
it was queued (``jobs.tenant``: the tenant given to :func:`db.jobs.enqueue_job`, else its map's). A caller
(:class:`service.auth.Caller`) sees only the rows of its own tenant; a key without a tenant, and every request
while auth is off, sees the untenanted rows. Another tenant's id gets the same ``404`` with the same body as
an id that does not exist, so ids leak nothing.
"""

from __future__ import annotations

from db import Database
from db import jobs as job_store
from db import maps as map_store
from db import queries as query_store
from db import references as reference_store
from db import tracks as track_store
from db.rows import JobRow, MapRow, QueryRow, ReferenceRow, TrackRow
from service.errors import ApiError


def _not_found(what: str, row_id: int) -> ApiError:
    return ApiError(404, "not_found", f"{what} {row_id} not found")


def _map_tenant_is(db: Database, map_id: int, tenant: str | None) -> bool:
    """Whether map ``map_id`` exists and belongs to ``tenant``."""
    row = map_store.get_map(db, map_id)
    return row is not None and row["tenant"] == tenant


def require_map(db: Database, map_id: int, tenant: str | None) -> MapRow:
    """The map row if it exists and belongs to ``tenant``, else 404."""
    row = map_store.get_map(db, map_id)
    if row is None or row["tenant"] != tenant:
        raise _not_found("map", map_id)
    return row


def require_ready_map(db: Database, map_id: int, tenant: str | None) -> MapRow:
    """The map row as :func:`require_map`, or 409 while it is not usable (queued, being parsed, failed)."""
    row = require_map(db, map_id, tenant)
    check_ready(row)
    return row


def check_ready(row: MapRow) -> None:
    """409 ``map_not_ready`` unless the map's status is ``done``; the message says what to do."""
    if row["status"] == "done":
        return
    if row["status"] == "failed":
        raise ApiError(
            409, "map_not_ready", f"map {row['id']} failed to load: {row['error']}; delete it and upload a fixed file"
        )
    raise ApiError(
        409,
        "map_not_ready",
        f"map {row['id']} is still being loaded: wait until GET /v1/maps/{row['id']} reports status done",
    )


def require_reference(db: Database, reference_id: int, tenant: str | None) -> ReferenceRow:
    """The reference row if it exists and its map belongs to ``tenant``, else 404."""
    row = reference_store.get_reference(db, reference_id)
    if row is None or not _map_tenant_is(db, row["map_id"], tenant):
        raise _not_found("reference", reference_id)
    return row


def require_query(db: Database, query_id: int, tenant: str | None) -> QueryRow:
    """The query row if it exists and its map belongs to ``tenant``, else 404."""
    row = query_store.get_query(db, query_id)
    if row is None or not _map_tenant_is(db, row["map_id"], tenant):
        raise _not_found("query", query_id)
    return row


def require_track(db: Database, track_id: int, tenant: str | None) -> TrackRow:
    """The track row if it exists and its map belongs to ``tenant``, else 404."""
    row = track_store.get_track(db, track_id)
    if row is None or not _map_tenant_is(db, row["map_id"], tenant):
        raise _not_found("track", track_id)
    return row


def require_job(db: Database, job_id: int, tenant: str | None) -> JobRow:
    """The job row if it exists and belongs to ``tenant`` (its ``jobs.tenant``), else 404."""
    row = job_store.get_job(db, job_id)
    if row is None or row["tenant"] != tenant:
        raise _not_found("job", job_id)
    return row
