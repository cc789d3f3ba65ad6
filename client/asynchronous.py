"""``AsyncClient``: the same API as :class:`client.sync.Client`, for asyncio (``httpx.AsyncClient``).

    async with AsyncClient("http://127.0.0.1:8000", api_key="KEY") as client:
        query = await client.upload_query(map_id, "photo.jpg", wait_s=0)
        answer = await client.wait_for_query(query.id)

The requests (:mod:`client.calls`), the retry policy, the models and the errors are the sync
client's; only the sending and the sleeping are awaited.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from types import TracebackType
from typing import TypeVar, Unpack, cast

import httpx

import client.calls as calls  # noqa: PLR0402 (a from-import counts as importing the package: a circle)
import client.models as models  # noqa: PLR0402 (as above)
from client.base import ClientBase, ClientOptions, finish, is_final
from client.calls import Call, MapFields, QueryFields, ReferenceFields, Sent, TrackFields, Upload
from client.errors import RateLimitedError, ServiceUnreachableError
from client.retry import RetryPolicy, WaitLoop

T = TypeVar("T")


class AsyncClient(ClientBase):
    """An asyncio client (on one event loop); an async context manager. Options: :class:`ClientBase`."""

    def __init__(
        self,
        base_url: str,
        api_key: str | None = None,
        *,
        transport: httpx.AsyncBaseTransport | None = None,
        sleep: Callable[[float], Awaitable[None]] = asyncio.sleep,
        **options: Unpack[ClientOptions],
    ) -> None:
        super().__init__(base_url, api_key, **options)
        self.sleep = sleep
        self.http = httpx.AsyncClient(transport=transport, **self._http_args())

    async def __aenter__(self) -> AsyncClient:
        """The client itself; closed on leaving the block."""
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        """Close the connection pool."""
        await self.close()

    async def close(self) -> None:
        """Close the connection pool."""
        await self.http.aclose()

    async def call(self, call: Call[T], *, retry: RetryPolicy | None = None) -> Sent[T]:
        """Send ``call`` with retries (``retry``, else the client's policy); its answer, status and tries."""
        policy = retry or self.retry
        attempt = 0
        while True:
            attempt += 1
            try:
                response = await self.http.request(call.method, call.path, **self._request_args(call))
            except httpx.TransportError as exc:
                delay = policy.delay_after(attempt, exc)
                if delay is None:
                    raise ServiceUnreachableError(f"{type(exc).__name__}: {exc}") from exc
                await self.sleep(delay)
                continue
            delay = policy.delay_after(attempt, response)
            if delay is None:
                return finish(call, response, attempt)
            await self.sleep(delay)

    # --- maps ---------------------------------------------------------------------------------

    async def upload_map(
        self, file: Upload, name: str, *, timeout_s: float = 600.0, **fields: Unpack[MapFields]
    ) -> models.Map:
        """Upload a map file (OSM, GeoJSON, GeoPackage, ...) with its read options and ``attribution``.

        Returns once the map is parsed: the service waits ``wait_s`` (default 60 s; a file it cannot read is
        an :class:`~client.errors.InvalidRequestError` then), and a map still queued after it is polled
        with backoff (:meth:`wait_for_map`, at most ``timeout_s``). The map is returned ``done`` or ``failed``.
        """
        uploaded = (await self.call(calls.upload_map(file, name, {"wait_s": 60.0, **fields}))).value
        if is_final(uploaded):
            return uploaded
        return await self.wait_for_map(uploaded.id, timeout_s=timeout_s)

    async def wait_for_map(self, map_id: int, *, timeout_s: float = 600.0) -> models.Map:
        """Poll until the map is ``done`` or ``failed`` (returned either way), at most ``timeout_s``."""
        return await self.wait(lambda _: self.get_map(map_id), timeout_s=timeout_s, what=f"map {map_id}")

    async def get_map(self, map_id: int) -> models.Map:
        """One map (``GET /v1/maps/{id}``)."""
        return (await self.call(calls.get_map(map_id))).value

    async def list_maps(self) -> list[models.Map]:
        """All maps, oldest first."""
        return (await self.call(calls.list_maps())).value

    async def delete_map(self, map_id: int) -> None:
        """Delete a map with everything on it."""
        await self.call(calls.delete("maps", map_id))

    async def buildings(self, map_id: int) -> models.FeatureCollection:
        """The map's buildings as GeoJSON (WGS84), with ``attribution``."""
        return (await self.call(calls.buildings(map_id))).value

    # --- references ---------------------------------------------------------------------------

    async def upload_reference(
        self, map_id: int, image: Upload, **fields: Unpack[ReferenceFields]
    ) -> models.ReferenceAccepted:
        """Add a geo-tagged photo (``lat``/``lon`` override its EXIF GPS) and queue its labelling."""
        return (await self.call(calls.upload_reference(map_id, image, fields))).value

    async def get_reference(self, reference_id: int) -> models.Reference:
        """A reference: its status and, once labelled, what labelling found."""
        return (await self.call(calls.get_reference(reference_id))).value

    async def list_references(self, map_id: int, *, after_id: int = 0, limit: int = 100) -> models.ReferenceList:
        """One page of the map's references (ids above ``after_id``)."""
        return (await self.call(calls.list_references(map_id, after_id, limit))).value

    async def delete_reference(self, reference_id: int) -> None:
        """Delete a reference with its labels (its queued job is cancelled)."""
        await self.call(calls.delete("references", reference_id))

    async def wait_for_reference(self, reference_id: int, *, timeout_s: float = 600.0) -> models.Reference:
        """Poll until the reference is ``done`` or ``failed`` (returned either way), at most ``timeout_s``."""
        return await self.wait(
            lambda _: self.get_reference(reference_id), timeout_s=timeout_s, what=f"reference {reference_id}"
        )

    async def wait_for_map_placed(self, map_id: int, *, timeout_s: float = 600.0) -> models.ReferenceList:
        """Poll until every reference of the map is labelled (or failed) and its walks placed, at most ``timeout_s``.

        Then every pose is final (``ReferenceList.placed``: no reference ``queued`` or ``processing``,
        ``walks_placing`` 0); returns the map's first reference page as last read (totals, ``counts``).
        """
        return await self.wait(
            lambda _: self.list_references(map_id, limit=1),
            timeout_s=timeout_s,
            done=lambda page: page.placed,
            what=f"map {map_id}'s labelling and walk placement",
        )

    # --- queries and jobs ---------------------------------------------------------------------

    async def upload_query(self, map_id: int, image: Upload, **fields: Unpack[QueryFields]) -> models.Query:
        """Geolocate a photo: the answer if ready within ``wait_s`` (default 60 s), else the queued query."""
        return (await self.call(calls.upload_query(map_id, image, fields))).value

    async def get_query(self, query_id: int, *, wait_s: float = 0.0) -> models.Query:
        """The query; with ``wait_s`` the service holds the request until the answer is ready (a long poll)."""
        return (await self.call(calls.get_query(query_id, wait_s))).value

    async def get_query_geojson(self, query_id: int, *, wait_s: float = 0.0) -> models.FeatureCollection:
        """The answer as GeoJSON (``format=geojson``): poses, view cones, buildings; ``attribution``."""
        return (await self.call(calls.query_geojson(query_id, wait_s))).value

    async def delete_query(self, query_id: int) -> None:
        """Delete a query and its stored photo."""
        await self.call(calls.delete("queries", query_id))

    async def wait_for_query(self, query_id: int, *, timeout_s: float = 600.0) -> models.Query:
        """Until the query is ``done`` or ``failed`` (returned either way), by long polls that grow like a backoff."""
        return await self.wait(
            lambda pause: self.get_query(query_id, wait_s=pause), timeout_s=timeout_s, what=f"query {query_id}"
        )

    # --- tracks -------------------------------------------------------------------------------

    async def upload_track(self, map_id: int, images: list[Upload], **fields: Unpack[TrackFields]) -> models.Track:
        """Locate a walk of photos together (frame order as given): the answer if ready within ``wait_s``."""
        return (await self.call(calls.upload_track(map_id, images, fields))).value

    async def track_of_queries(self, map_id: int, query_ids: list[int], **fields: Unpack[TrackFields]) -> models.Track:
        """A track of earlier queries of the map (their photos, in this order)."""
        return (await self.call(calls.track_of_queries(map_id, query_ids, fields))).value

    async def get_track(self, track_id: int, *, wait_s: float = 0.0) -> models.Track:
        """The track; with ``wait_s`` the service holds the request until the answer is ready (a long poll)."""
        return (await self.call(calls.get_track(track_id, wait_s))).value

    async def get_track_geojson(self, track_id: int, *, wait_s: float = 0.0) -> models.FeatureCollection:
        """The track as GeoJSON: the trajectory, a point and a view cone per frame; ``attribution``."""
        return (await self.call(calls.track_geojson(track_id, wait_s))).value

    async def delete_track(self, track_id: int) -> None:
        """Delete a track with its frames' queries and photos."""
        await self.call(calls.delete("tracks", track_id))

    async def wait_for_track(self, track_id: int, *, timeout_s: float = 600.0) -> models.Track:
        """Until the track is ``done`` or ``failed`` (returned either way), by long polls that grow like a backoff."""
        return await self.wait(
            lambda pause: self.get_track(track_id, wait_s=pause), timeout_s=timeout_s, what=f"track {track_id}"
        )

    async def get_job(self, job_id: int) -> models.Job:
        """A background job: status, attempts, result or last error."""
        return (await self.call(calls.get_job(job_id))).value

    async def get_file(self, call: Call[bytes]) -> bytes:
        """A stored file: ``calls.file_of("references", id, "labels.png")``, ``("queries", id, "heatmap.png")``, ..."""
        return (await self.call(call)).value

    # --- system -------------------------------------------------------------------------------

    async def health(self) -> models.Health:
        """``/healthz``: the process answers."""
        return (await self.call(calls.health())).value

    async def ready(self) -> models.Readiness:
        """``/readyz``; a service not ready raises ServerError 503 ``not_ready`` (``details`` say why)."""
        return (await self.call(calls.ready())).value

    async def about(self) -> models.About:
        """The service's version and licence table (``/v1/about``)."""
        return (await self.call(calls.about())).value

    # --- waiting ------------------------------------------------------------------------------

    async def wait(
        self,
        fetch: Callable[[float], Awaitable[T]],
        *,
        timeout_s: float,
        done: Callable[[T], bool] = is_final,
        what: str = "the job",
    ) -> T:
        """As :meth:`client.sync.Client.wait` (exponential backoff, long polls, 429s waited out), awaited."""
        loop: WaitLoop[T] = WaitLoop(timeout_s, done, what, time.monotonic)
        while True:
            pause_s = loop.begin()
            try:
                sleep_s = loop.after(await fetch(pause_s))
            except RateLimitedError as exc:
                sleep_s = loop.after(None, exc)
            if sleep_s is None:
                return cast(T, loop.last)
            await self.sleep(sleep_s)
