"""What the routes' reads share: the loaded map of a map row, the errors a read answers, a row's work status."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

from contracts.jobs import WorkStatus, reported_status
from contracts.settings import Settings
from db.files import FileStore
from db.rows import JobRow, MapRow
from geoloc.maps import CityMap, MapReadOptions, load_map_cached, map_cache_dir
from service.responses import error_responses
from service.tenancy import check_ready

READ_ERRORS = error_responses(404)
"""Errors a read answers itself (the specification adds auth, rate-limit and validation statuses)."""


@lru_cache(maxsize=2)
def _cached_map(source: str, cache_dir: str, read_options: str, sha256: str) -> CityMap:
    options = MapReadOptions.from_dict(json.loads(read_options))
    return load_map_cached(source, Path(cache_dir), options, sha256=sha256)


def loaded_map(settings: Settings, store: FileStore, row: MapRow) -> CityMap:
    """The loaded map of a map row (streets, footprints in local metres), from the copy cached at upload.

    Kept in memory for the last two maps asked (the heat map picture, the streets' GeoJSON). 409 while the
    map is not done.
    """
    check_ready(row)
    return _cached_map(
        str(store.local_path(row["source_path"])),
        str(map_cache_dir(settings.data_dir)),
        json.dumps(row["read_options"], sort_keys=True),
        row["sha256"],
    )


def work_status(status: str, error: str | None, job: JobRow | None) -> tuple[WorkStatus, str | None]:
    """What to report for a reference or query with this status and error and this job (or none).

    :func:`contracts.jobs.reported_status` on the job row's status, attempts and error.
    """
    if job is None:
        return reported_status(status, error, None)
    return reported_status(status, error, job["status"], job["attempts"], job["error"])
