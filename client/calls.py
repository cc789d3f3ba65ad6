"""Each API request as a value: method, path, parameters, form and files, and how to read the answer.

The sync and the async client send the same :class:`Call` objects (built by the functions below, one
per endpoint), so what a request looks like is written once. Form fields left None are not sent (the
service applies its defaults). ``Upload`` is a path (read when the call is built), or ``(filename,
bytes)`` / ``(filename, bytes, media_type)``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Literal, TypedDict, TypeVar

import httpx
from pydantic import BaseModel

import client.models as models  # noqa: PLR0402 (a from-import counts as importing the package: a circle)

T = TypeVar("T")
M = TypeVar("M", bound=BaseModel)
Upload = Path | str | tuple[str, bytes] | tuple[str, bytes, str]
"""A file to upload: a path, or (filename, content) with an optional media type."""
GEOJSON = "application/geo+json"
FileTuple = tuple[str, bytes] | tuple[str, bytes, str]
"""A file as httpx sends it: (filename, content) with an optional media type."""


class MapFields(TypedDict, total=False):
    """``POST /v1/maps``'s optional form fields (openapi.md: read options, attribution)."""

    layer: str
    name_attribute: str
    height_attribute: str
    levels_attribute: str
    crs: str
    attribution: str
    wait_s: float


class ReferenceFields(TypedDict, total=False):
    """``POST /v1/maps/{id}/references``'s optional fields: position (WGS84 deg), heading (deg from north)."""

    lat: float
    lon: float
    heading_deg: float
    focal_length_35mm: float
    sequence: str


class QueryFields(TypedDict, total=False):
    """``POST /v1/maps/{id}/queries``'s optional fields: priors, answer size, ``wait_s`` (s) before 202."""

    lat: float
    lon: float
    radius_m: float
    heading_deg: float
    use_exif_gps: bool
    focal_length_35mm: float
    top_n: int
    k: int
    wait_s: float
    preset: Literal["fast", "balanced", "accurate"]


class TrackFields(TypedDict, total=False):
    """``POST /v1/maps/{id}/tracks``'s optional fields: order, answer size, ``wait_s`` (s) before 202.

    ``priors`` (multipart only): one entry per frame, None or a dict of ``lat``, ``lon``, ``radius_m``,
    ``heading_deg``, ``place`` as a query's fields.
    """

    priors: list[dict[str, Any] | None]
    use_exif_gps: bool
    by_capture_time: bool
    top_n: int
    k: int
    wait_s: float
    preset: Literal["fast", "balanced", "accurate"]


@dataclass(frozen=True)
class Call(Generic[T]):
    """One request and the reader of its 2xx answer (an error answer is raised, never read)."""

    method: Literal["GET", "POST", "DELETE"]
    path: str
    read: Callable[[httpx.Response], T]
    params: dict[str, Any] = field(default_factory=dict)
    data: dict[str, str] = field(default_factory=dict)
    files: dict[str, FileTuple] | list[tuple[str, FileTuple]] = field(default_factory=dict)
    """Files by field, or (field, file) pairs where a field repeats (a track's ``images``)."""
    headers: dict[str, str] = field(default_factory=dict)
    json: dict[str, Any] | None = None
    """A JSON body instead of a form."""


@dataclass(frozen=True)
class Sent(Generic[T]):
    """A call's answer read into ``value``, the HTTP ``status`` and how many ``attempts`` it took."""

    value: T
    status: int
    attempts: int


def _model(kind: type[M]) -> Callable[[httpx.Response], M]:
    return lambda response: kind.model_validate(response.json())


def _nothing(_response: httpx.Response) -> None:
    return None


def _bytes(response: httpx.Response) -> bytes:
    return response.content


def _form(fields: Any) -> dict[str, str]:
    """Form values as the service reads them (booleans as ``true``/``false``), None left out."""
    return {
        k: ("true" if v else "false") if isinstance(v, bool) else str(v) for k, v in fields.items() if v is not None
    }


def _file(upload: Upload) -> FileTuple:
    if isinstance(upload, str | Path):
        path = Path(upload)
        return (path.name, path.read_bytes())
    return upload


def upload_map(file: Upload, name: str, fields: MapFields) -> Call[models.Map]:
    """``POST /v1/maps``: 201 a new map parsed within ``wait_s``, 202 one still queued, 200 the same file again."""
    data = _form({"name": name, **fields})
    return Call("POST", "/v1/maps", _model(models.Map), data=data, files={"file": _file(file)})


def get_map(map_id: int) -> Call[models.Map]:
    """One map (``GET /v1/maps/{id}``)."""
    return Call("GET", f"/v1/maps/{map_id}", _model(models.Map))


def list_maps() -> Call[list[models.Map]]:
    """All maps, oldest first."""
    return Call("GET", "/v1/maps", lambda r: [models.Map.model_validate(m) for m in r.json()["maps"]])


def delete(kind: Literal["maps", "references", "queries", "tracks"], item_id: int) -> Call[None]:
    """``DELETE /v1/{kind}/{id}`` (204)."""
    return Call("DELETE", f"/v1/{kind}/{item_id}", _nothing)


def buildings(map_id: int) -> Call[models.FeatureCollection]:
    """``GET /v1/maps/{id}/buildings``: the buildings as GeoJSON."""
    return Call("GET", f"/v1/maps/{map_id}/buildings", _model(models.FeatureCollection))


def upload_reference(map_id: int, image: Upload, fields: ReferenceFields) -> Call[models.ReferenceAccepted]:
    """``POST /v1/maps/{id}/references``: 202 queued for labelling, 200 already a reference (``duplicate``)."""
    path = f"/v1/maps/{map_id}/references"
    return Call("POST", path, _model(models.ReferenceAccepted), data=_form(fields), files={"image": _file(image)})


def get_reference(reference_id: int) -> Call[models.Reference]:
    """A reference: its status and, once labelled, what labelling found."""
    return Call("GET", f"/v1/references/{reference_id}", _model(models.Reference))


def list_references(map_id: int, after_id: int, limit: int) -> Call[models.ReferenceList]:
    """``GET /v1/maps/{id}/references`` (JSON), one page."""
    params = {"after_id": after_id, "limit": limit, "format": "json"}
    return Call("GET", f"/v1/maps/{map_id}/references", _model(models.ReferenceList), params=params)


def file_of(kind: Literal["references", "queries"], item_id: int, name: str) -> Call[bytes]:
    """A stored file's bytes: ``image`` (both), ``labels.png`` (references), ``heatmap.png`` (queries)."""
    return Call("GET", f"/v1/{kind}/{item_id}/{name}", _bytes)


def upload_query(map_id: int, image: Upload, fields: QueryFields) -> Call[models.Query]:
    """``POST /v1/maps/{id}/queries``: 200 answered within ``wait_s``, else 202 to poll."""
    return Call(
        "POST", f"/v1/maps/{map_id}/queries", _model(models.Query), data=_form(fields), files={"image": _file(image)}
    )


def get_query(query_id: int, wait_s: float = 0.0) -> Call[models.Query]:
    """``GET /v1/queries/{id}``, a long poll of up to ``wait_s`` seconds for the answer."""
    params = {"wait_s": wait_s, "format": "json"}
    return Call("GET", f"/v1/queries/{query_id}", _model(models.Query), params=params)


def query_geojson(query_id: int, wait_s: float = 0.0) -> Call[models.FeatureCollection]:
    """The answer as GeoJSON (``format=geojson``); not answered yet: an empty collection with ``status``."""
    params = {"wait_s": wait_s, "format": "geojson"}
    return Call("GET", f"/v1/queries/{query_id}", _model(models.FeatureCollection), params=params)


def upload_track(map_id: int, images: list[Upload], fields: TrackFields) -> Call[models.Track]:
    """``POST /v1/maps/{id}/tracks`` with the photos in frame order: 200 answered within ``wait_s``, else 202."""
    form: dict[str, Any] = dict(fields)
    if form.get("priors") is not None:
        form["priors"] = json.dumps(form["priors"])
    files = [("images", _file(image)) for image in images]
    return Call("POST", f"/v1/maps/{map_id}/tracks", _model(models.Track), data=_form(form), files=files)


def track_of_queries(map_id: int, query_ids: list[int], fields: TrackFields) -> Call[models.Track]:
    """``POST /v1/maps/{id}/tracks`` with a JSON body naming earlier queries of the map, in frame order."""
    body = {"query_ids": query_ids, **{k: v for k, v in fields.items() if v is not None and k != "priors"}}
    return Call("POST", f"/v1/maps/{map_id}/tracks", _model(models.Track), json=body)


def get_track(track_id: int, wait_s: float = 0.0) -> Call[models.Track]:
    """``GET /v1/tracks/{id}``, a long poll of up to ``wait_s`` seconds for the answer."""
    params = {"wait_s": wait_s, "format": "json"}
    return Call("GET", f"/v1/tracks/{track_id}", _model(models.Track), params=params)


def track_geojson(track_id: int, wait_s: float = 0.0) -> Call[models.FeatureCollection]:
    """The track as GeoJSON (``format=geojson``): the trajectory, a point and a view cone per frame."""
    params = {"wait_s": wait_s, "format": "geojson"}
    return Call("GET", f"/v1/tracks/{track_id}", _model(models.FeatureCollection), params=params)


def get_job(job_id: int) -> Call[models.Job]:
    """A background job: status, attempts, result or last error."""
    return Call("GET", f"/v1/jobs/{job_id}", _model(models.Job))


def health() -> Call[models.Health]:
    """``/healthz``: the process answers."""
    return Call("GET", "/healthz", _model(models.Health))


def ready() -> Call[models.Readiness]:
    """``/readyz``: 200 ready, else 503 ``not_ready``."""
    return Call("GET", "/readyz", _model(models.Readiness))


def about() -> Call[models.About]:
    """The service's version and licence table (``/v1/about``)."""
    return Call("GET", "/v1/about", _model(models.About))
