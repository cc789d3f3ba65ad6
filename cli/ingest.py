"""``geoloc ingest DIR --map ID``: upload a folder of geo-tagged photos as references of a map.

Every file is checked by content (JPEG, PNG, WEBP, TIFF, HEIC; anything else is skipped with a reason),
hashed (sha256), geotagged when asked (``--gpx TRACK.gpx [--time-offset S]``, and a
``mapillary_image_description.json`` beside the photos: :mod:`cli.ingest_geotag` gives each photo its form
fields, or skips it with the reason when the track cannot place it) and posted to
``POST /v1/maps/{id}/references``. Files with the same content in the folder are uploaded once. The
service answers ``duplicate: true`` for a photo it already holds, so a second run creates nothing new.
Connection errors, 408, 429 and 5xx are retried with exponential backoff (``Retry-After`` honoured).
``--wait`` then waits until every new reference is labelled (``done``) or ``failed`` and the map's walks are
placed, so every pose is final; ``--wait labelled`` only for the labelling (:mod:`cli.ingest_wait`).

Exit codes: 0 nothing failed (rejected photos are not failures), 1 some photos failed after
retries (or, with ``--wait``, failed labelling, a walk left unplaced or the wait timed out), 2 nothing could
be done (service unreachable, bad API key, unknown map) or the command line is wrong.

This module runs the steps; :mod:`cli.photo_files` picks the files, the client :mod:`client`
talks to the service (with :data:`~client.retry.TRANSIENT_STATUSES` retried), :mod:`cli.ingest_wait`
waits, :mod:`cli.ingest_report` prints the summary.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import httpx
import typer
from rich.console import Console

from cli.ingest_geotag import geotag_photos, load_geotagging
from cli.ingest_report import IngestReport, print_summary
from cli.ingest_wait import (
    FINAL_REFERENCE_STATES,
    WAIT_MODES,
    WaitFor,
    progress_bar,
    wait_for_labelling,
    wait_for_placement,
)
from cli.photo_files import Candidate, FileResult, path_order, scan_folder
from client import ApiError, Client, Map, RetryPolicy, ServiceUnreachableError, calls
from client.retry import TRANSIENT_STATUSES as RETRY_STATUSES
from geoloc.photos.geotag import GeotagError

NOT_THE_PHOTOS_FAULT = frozenset({401, 403, 404})
"""4xx answers that are failures (key, scope, map gone), not a rejection of the photo."""


class IngestAbortError(Exception):
    """The run cannot start (unknown map, bad API key, service unreachable)."""


NO_RETRY = RetryPolicy(retries=0)
"""One try: whether the service answers now."""


def fetch_map(client: Client, map_id: int) -> Map:
    """The map (checks reachability, the API key and the map id before anything is uploaded), once usable.

    A map still being parsed is waited for (with backoff); one that failed aborts the run with its error.
    """
    try:
        found = client.get_map(map_id)
        found = found if found.status in FINAL_REFERENCE_STATES else client.wait_for_map(map_id)
    except ServiceUnreachableError as exc:
        raise IngestAbortError(f"cannot reach the service at {client.base_url}: {exc}") from exc
    except ApiError as exc:
        raise IngestAbortError(
            f"GET /v1/maps/{map_id} answered {exc.status} {exc.code or ''}: {exc.message}".replace("  ", " ")
        ) from exc
    if found.status == "failed":
        raise IngestAbortError(f"map {map_id} failed to load: {found.error}")
    return found


def _alive(client: Client) -> bool:
    """Whether ``/healthz`` answers now (one try)."""
    try:
        return client.call(calls.health(), retry=NO_RETRY).status == 200
    except (ApiError, ServiceUnreachableError):
        return False


def upload_one(client: Client, stop: threading.Event, map_id: int, photo: Candidate) -> FileResult:
    """Post one photo; classify the answer (``stop`` set: the service is gone, nothing more is tried)."""
    result = FileResult(
        photo.relative, "failed", sha256=photo.sha256, size_bytes=photo.size_bytes, mime_type=photo.mime_type
    )
    if photo.fields:
        result.form_fields, result.field_sources = dict(photo.fields), dict(photo.field_sources)
    if stop.is_set():
        result.reason = "not attempted: the service stopped answering"
        return result
    try:
        data = photo.path.read_bytes()
    except OSError as exc:
        result.reason = f"cannot read the file: {exc.strerror or exc}"
        return result
    try:
        sent = client.call(calls.upload_reference(map_id, (photo.path.name, data, photo.mime_type), photo.fields))
    except ServiceUnreachableError as exc:
        if not _alive(client):
            stop.set()  # the rest would only wait for the same dead service
        result.attempts = client.retry.retries + 1
        result.reason = f"service unreachable after {result.attempts} attempts: {exc}"
        return result
    except ApiError as exc:
        return _refused(result, exc)
    accepted = sent.value
    result.http_status, result.attempts = sent.status, sent.attempts
    result.reference_id, result.job_id = accepted.id, accepted.job_id
    if accepted.duplicate:
        result.outcome = "present"
        result.reason = f"already reference {result.reference_id} of map {map_id} (status {accepted.status})"
    else:
        result.outcome = "accepted"
    return result


def _refused(result: FileResult, exc: ApiError) -> FileResult:
    """``result`` for an upload answered with an error: rejected (the photo's fault) or failed."""
    result.http_status, result.attempts = exc.status, exc.attempts
    result.error_code, message, result.details = exc.code, exc.message, exc.details
    distance = (result.details or {}).get("distance_m")
    if isinstance(distance, int | float) and distance >= 10_000:
        message += f" (about {distance / 1000:,.0f} km)"
    result.reason = f"{exc.status} {result.error_code or 'error'}: {message}"
    if exc.status in RETRY_STATUSES:
        result.reason = f"{result.reason} (gave up after {result.attempts} attempts)"
    photo_refused = 400 <= exc.status < 500 and exc.status not in RETRY_STATUSES
    result.outcome = "rejected" if photo_refused and exc.status not in NOT_THE_PHOTOS_FAULT else "failed"
    return result


def _count_text(results: Iterable[FileResult]) -> str:
    counts = Counter(r.outcome for r in results)
    return " ".join(f"{name} {counts[name]}" for name in ("accepted", "present", "rejected", "failed") if counts[name])


def upload_all(
    client: Client, stop: threading.Event, map_id: int, photos: list[Candidate], *, concurrency: int, console: Console
) -> list[FileResult]:
    """Upload ``photos`` with ``concurrency`` threads and a progress bar; results in ``photos`` order."""
    results: dict[int, FileResult] = {}
    with progress_bar(console) as progress, ThreadPoolExecutor(max_workers=concurrency) as pool:
        task = progress.add_task("uploading", total=len(photos), status="")
        futures = {pool.submit(upload_one, client, stop, map_id, photo): i for i, photo in enumerate(photos)}
        try:
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                progress.update(task, advance=1, status=_count_text(results.values()))
        except KeyboardInterrupt:
            stop.set()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return [results[i] for i in range(len(photos))]


@dataclass(frozen=True)
class IngestOptions:
    """How :func:`ingest_folder` reads the folder, uploads and waits (the ``geoloc ingest`` options).

    url, api_key: the service and a key with the write scope; concurrency: parallel uploads; recursive: photos in
    subfolders too. wait: ``placed`` (until the new references are labelled and the map's walks placed: every
    pose final) or ``labelled`` (labelling only), for at most ``wait_timeout_s`` in all (0: no limit), reading
    every ``poll_s``; None: do not wait. retries, backoff_s: of transient errors; timeout_s: per HTTP request.
    gpx: a GPS track that places every photo by its capture time (+ ``time_offset_s`` seconds), see
    :mod:`cli.ingest_geotag`; a ``mapillary_image_description.json`` in the folder is read with or without it.
    """

    url: str
    api_key: str | None
    concurrency: int = 4
    recursive: bool = False
    wait: WaitFor | None = None
    wait_timeout_s: float = 0.0
    poll_s: float = 1.0
    retries: int = 5
    backoff_s: float = 0.5
    timeout_s: float = 120.0
    gpx: Path | None = None
    time_offset_s: float = 0.0


def ingest_folder(
    folder: Path,
    map_id: int,
    options: IngestOptions,
    *,
    console: Console | None = None,
    transport: httpx.BaseTransport | None = None,
) -> IngestReport:
    """Scan, geotag, upload and (optionally) wait, as ``options`` say; raises :class:`IngestAbortError` when stuck.

    Stuck: nothing can be done (bad track, service unreachable, key refused, no such map). console: where the
    progress goes (stderr); transport: the HTTP transport (the tests mock it).
    """
    console = console or Console(stderr=True)
    url, recursive, wait, poll_s = options.url, options.recursive, options.wait, options.poll_s
    gpx, time_offset_s, wait_timeout_s = options.gpx, options.time_offset_s, options.wait_timeout_s
    try:
        geotagging = load_geotagging(folder, gpx, time_offset_s, recursive=recursive)
    except GeotagError as exc:
        raise IngestAbortError(str(exc)) from exc
    stop = threading.Event()
    policy = RetryPolicy(
        retries=options.retries, backoff_s=options.backoff_s, statuses=RETRY_STATUSES, stop=stop.is_set
    )
    client = Client(url, options.api_key, timeout_s=options.timeout_s, retry=policy, transport=transport)
    try:
        map_row = fetch_map(client, map_id)
        report = IngestReport(url=url, map_id=map_id, map_name=map_row.name)
        photos, others = scan_folder(folder, recursive=recursive)
        photos, unplaced = geotag_photos(photos, geotagging)
        others += unplaced
        if geotagging.active:
            console.print(geotagging.summary(), highlight=False)
        console.print(
            f"map {map_id} ({map_row.name}) at {url}: {len(photos)} photo(s) to upload from {folder}"
            + (f", {len(others)} other file(s) not uploaded" if others else "")
        )
        uploaded = []
        if photos:
            uploaded = upload_all(client, stop, map_id, photos, concurrency=options.concurrency, console=console)
        report.files = sorted([*uploaded, *others], key=lambda r: path_order(r.path))
        if wait is not None:
            report.wait_for = wait
            deadline = time.monotonic() + wait_timeout_s if wait_timeout_s > 0 else None
            in_time = wait_for_labelling(client, report.files, deadline=deadline, poll_s=poll_s, console=console)
            if in_time and wait == "placed":
                report.placement = wait_for_placement(
                    client, map_id, report.files, deadline=deadline, poll_s=poll_s, console=console
                )
                in_time = report.placement is not None
            report.wait_timed_out = not in_time
        return report
    finally:
        client.close()


CONTEXT_SETTINGS = {"allow_extra_args": True}
"""The command's settings: the word after ``--wait`` (``placed``, ``labelled``) arrives as an extra argument."""


def wait_mode(wait: bool, extra: list[str]) -> WaitFor | None:
    """What ``--wait [placed|labelled]`` asks for (None: no waiting); a usage error for anything else.

    Typer has no option with an optional value, so ``--wait`` is a flag and the mode after it is read from
    the command's extra arguments: ``--wait`` alone is ``placed``.
    """
    if not extra:
        return "placed" if wait else None
    for mode in WAIT_MODES:
        if wait and extra == [mode]:
            return mode
    hint = "after --wait: placed or labelled" if wait else "a wait mode follows --wait"
    raise typer.BadParameter(f"unexpected argument(s) {' '.join(extra)!r} ({hint})", param_hint="--wait")


def ingest(
    ctx: typer.Context,
    folder: Path = typer.Argument(..., exists=True, file_okay=False, dir_okay=True, help="Folder of photos."),
    map_id: int = typer.Option(..., "--map", "-m", help="Id of the map the photos are references of."),
    url: str = typer.Option("http://127.0.0.1:8000", "--url", envvar="GEOLOC_URL", help="Base URL of the service."),
    api_key: str | None = typer.Option(
        None, "--api-key", envvar="GEOLOC_API_KEY", help="API key with the write scope (X-API-Key)."
    ),
    concurrency: int = typer.Option(4, "--workers", "--concurrency", "-j", min=1, max=64, help="Parallel uploads."),
    recursive: bool = typer.Option(False, "--recursive", "-r", help="Include photos in subfolders."),
    wait: bool = typer.Option(
        False,
        "--wait",
        help="Then wait until every new reference is labelled (or failed) and the map's walks are placed: every "
        "pose final. '--wait labelled': only until the new references are labelled (walks may still move).",
    ),
    wait_timeout: float = typer.Option(
        0.0, "--wait-timeout", min=0, help="Stop waiting after S seconds in all (0: never)."
    ),
    json_out: Path | None = typer.Option(None, "--json", help="Write every file's outcome to this JSON file."),
    retries: int = typer.Option(5, "--retries", min=0, help="Retries of transient errors (connection, 429, 5xx)."),
    timeout: float = typer.Option(120.0, "--timeout", min=1, help="Seconds per HTTP request."),
    gpx: Path | None = typer.Option(
        None,
        "--gpx",
        exists=True,
        file_okay=True,
        dir_okay=False,
        help="A GPS track: each photo's position (and, without a compass, its heading: the direction of travel) "
        "from its capture time; photos outside the track's time span are skipped with the reason.",
    ),
    time_offset: float = typer.Option(
        0.0,
        "--time-offset",
        help="Seconds added to the photos' capture times before the track is read (a camera clock that is off; "
        "a time without a zone is read as UTC: -7200 for a camera set to UTC+2).",
    ),
) -> None:
    """Upload every photo in a folder as a reference of a map; print what was accepted, rejected and why.

    With --wait, return once every pose is final (labelled, and each walk placed jointly); --wait labelled
    returns once the new references are labelled.

    With --gpx, each photo is placed on the GPS track by its capture time (+ --time-offset); a
    mapillary_image_description.json in the folder gives what a photo's EXIF lacks (position, heading,
    capture time, sequence).

    Exit codes:
    0: nothing failed (photos the service rejects are listed with the reason, they are not failures);
    1: some photos failed after retries (with --wait: some labelling failed, a walk was left unplaced or the
    wait timed out);
    2: the service cannot be reached, the API key is refused, or the map does not exist.
    """
    wait_for = wait_mode(wait, ctx.args)
    stdout = Console(width=None if sys.stdout.isatty() else 160)
    stderr = Console(stderr=True)
    try:
        options = IngestOptions(
            url=url,
            api_key=api_key,
            concurrency=concurrency,
            recursive=recursive,
            wait=wait_for,
            wait_timeout_s=wait_timeout,
            retries=retries,
            timeout_s=timeout,
            gpx=gpx,
            time_offset_s=time_offset,
        )
        report = ingest_folder(folder, map_id, options, console=stderr)
    except IngestAbortError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    except KeyboardInterrupt as exc:
        typer.echo("interrupted: photos already uploaded stay stored; run the command again to finish", err=True)
        raise typer.Exit(130) from exc
    if json_out is not None:
        tmp = json_out.with_name(json_out.name + ".part")
        tmp.write_text(json.dumps(report.as_json(), indent=2, sort_keys=True) + "\n")
        tmp.replace(json_out)
    print_summary(report, stdout)
    raise typer.Exit(report.exit_code)
