"""Places of a map: ``GET /v1/maps/{id}/places`` (autocompletion) and the ``place`` field of uploads.

A place is a name the map itself holds: a building's name, an address, a street, a landmark
(:mod:`geoloc.maps.places`, offline: no geocoder). The index is built in the API process from the map's
cached copy (the one the upload wrote; the source is parsed again if it is missing) and kept per map file
(:func:`map_places`, a few per process).

Decision (precedence of positions): an explicit ``lat``/``lon`` and a ``place`` together are a 422 (two
answers to one question); a ``place`` overrides the photo's EXIF GPS (a user who names a place means it);
EXIF GPS is used only when neither is given. A query stores the place's disc (:class:`Place`; ``radius_m``
the request's when given); the worker answers it with the prior along the place's shape (docs/places.md).
A reference placed by name is stored with position source ``request`` (the request gave it) at the place's
centre.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Depends, Query
from fastapi.concurrency import run_in_threadpool

from contracts.api import PlaceList, PlaceOut
from contracts.settings import Settings
from db.files import open_store
from db.rows import MapRow
from geoloc.maps import MapReadOptions, load_map_cached, map_cache_dir
from geoloc.maps.places import Place, PlaceIndex, place_index, resolve_place
from service.auth import Caller, request_caller, require_read
from service.bounds import MapId
from service.deps import app_settings, open_db
from service.errors import ApiError
from service.responses import error_responses
from service.tenancy import require_map

router = APIRouter(tags=["maps"])
MAX_PLACE_CHARS = 200


def place_out(place: Place) -> PlaceOut:
    """A place as its API model."""
    return PlaceOut(
        name=place.name,
        kind=place.kind,
        lat=place.lat,
        lon=place.lon,
        radius_m=place.radius_m,
        building_id=place.building_id,
        score=place.score,
    )


@lru_cache(maxsize=4)
def _index(store_dir: str, data_dir: str, source_path: str, sha256: str, read_options: str) -> PlaceIndex:
    options = MapReadOptions.from_dict(json.loads(read_options))
    source = open_store(Path(store_dir)).local_path(source_path)
    return place_index(load_map_cached(source, map_cache_dir(Path(data_dir)), options, sha256=sha256))


def map_places(settings: Settings, map_row: MapRow) -> PlaceIndex:
    """The place index of a stored map (built on first use, then kept per process)."""
    return _index(
        str(settings.file_store_dir),
        str(settings.data_dir),
        map_row["source_path"],
        map_row["sha256"],
        json.dumps(map_row["read_options"], sort_keys=True),
    )


def resolve_form_place(settings: Settings, map_row: MapRow, text: str) -> Place:
    """The one place of the map that ``text`` names; 422 ``ambiguous_place`` (with candidates) or ``unknown_place``."""
    text = text.strip()
    if not text or len(text) > MAX_PLACE_CHARS:
        raise ApiError(422, "invalid_request", f"place must have 1 to {MAX_PLACE_CHARS} characters")
    match = resolve_place(map_places(settings, map_row), text)
    if match.place is not None:
        return match.place
    if match.status == "ambiguous":
        candidates = [place_out(p).model_dump(include={"name", "kind", "lat", "lon"}) for p in match.candidates]
        names = "; ".join(f"{c['name']} ({c['kind']}, {c['lat']:.5f}, {c['lon']:.5f})" for c in candidates)
        raise ApiError(
            422,
            "ambiguous_place",
            f"place {text!r} names several places of map {map_row['id']}: {names}; name one more precisely "
            "(add the house number or the street) or send lat/lon",
            {"place": text, "candidates": candidates},
        )
    raise ApiError(
        422,
        "unknown_place",
        f"place {text!r} matches no building, address, street or landmark of map {map_row['id']} "
        f"(GET /v1/maps/{map_row['id']}/places?q=... lists what it knows)",
        {"place": text},
    )


def _search(settings: Settings, map_id: int, tenant: str | None, q: str, limit: int) -> PlaceList:
    db = open_db(settings)
    try:
        row = require_map(db, map_id, tenant)
    finally:
        db.close()
    places = map_places(settings, row).search(q, limit=limit)
    return PlaceList(query=q, places=[place_out(p) for p in places])


@router.get(
    "/v1/maps/{map_id}/places",
    response_model=PlaceList,
    responses=error_responses(404),
    dependencies=[Depends(require_read)],
)
async def search_places(
    map_id: MapId,
    q: Annotated[
        str,
        Query(min_length=1, max_length=MAX_PLACE_CHARS, description="What the user typed (a name, address, street)"),
    ],
    limit: Annotated[int, Query(ge=1, le=50, description="How many places to return")] = 10,
    settings: Settings = Depends(app_settings),
    caller: Caller = Depends(request_caller),
) -> PlaceList:
    """Places of the map matching ``q``, best first, for autocompletion: buildings' names, addresses, streets.

    Accent- and case-insensitive, fuzzy, the last word also as a prefix (docs/places.md). Each place gives
    the position prior a query's or a reference's ``place`` field would use.
    """
    return await run_in_threadpool(_search, settings, map_id, caller.tenant, q, limit)
