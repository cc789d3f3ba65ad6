"""``geoloc ingest DIR --map ID``: upload a folder of geo-tagged photos as references of a map.

Every file is checked by content (JPEG, PNG, WEBP, TIFF; anything else is skipped with a reason),
hashed (sha256) and posted to ``POST /v1/maps/{id}/references``. Files with the same content in
the folder are uploaded once. The service answers ``duplicate: true`` for a photo it already holds,
so a second run creates nothing new. Connection errors, 408, 429 and 5xx are retried with
exponential backoff (``Retry-After`` honoured). ``--wait`` then polls ``GET /v1/references/{id}``
until every new reference is labelled (``done``) or ``failed``.

Exit codes: 0 nothing failed (rejected photos are not failures), 1 some photos failed after
retries (or, with ``--wait``, failed labelling or the wait timed out), 2 nothing could be done
(service unreachable, bad API key, unknown map).
"""

from __future__ import annotations

import hashlib
import json
import random
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import httpx
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

RETRY_STATUSES = frozenset({408, 429, 500, 502, 503, 504})
"""Answers worth another try: the request may succeed later."""
NOT_THE_PHOTOS_FAULT = frozenset({401, 403, 404})
"""4xx answers that are failures (key, scope, map gone), not a rejection of the photo."""
MAX_BACKOFF_S = 30.0
FINAL_REFERENCE_STATES = frozenset({"done", "failed"})

OUTCOMES: dict[str, str] = {
    "accepted": "accepted (new reference)",
    "present": "already present (same sha256)",
    "duplicate": "duplicate within the folder",
    "rejected": "rejected by the service",
    "skipped": "skipped (not a photo)",
    "failed": "failed after retries",
}
"""Outcome of one file -> its label in the summary, in summary order."""


def sniff_photo(head: bytes) -> str | None:
    """MIME type of a photo from its first bytes (JPEG, PNG, WEBP, TIFF), else None."""
    if head.startswith(b"\xff\xd8\xff"):
        return "image/jpeg"
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "image/png"
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "image/webp"
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "image/tiff"
    return None


@dataclass
class FileResult:
    """What happened to one file (one row of ``--json``)."""

    path: str
    outcome: str
    reason: str | None = None
    sha256: str | None = None
    size_bytes: int | None = None
    mime_type: str | None = None
    http_status: int | None = None
    error_code: str | None = None
    details: dict[str, Any] | None = None
    reference_id: int | None = None
    job_id: int | None = None
    attempts: int = 0
    duplicate_of: str | None = None
    final_status: str | None = None
    final_error: str | None = None


@dataclass
class Candidate:
    """A photo to upload."""

    path: Path
    relative: str
    sha256: str
    size_bytes: int
    mime_type: str


@dataclass
class IngestReport:
    """Results of a run: one :class:`FileResult` per file, plus what ``--wait`` found."""

    url: str
    map_id: int
    map_name: str | None = None
    files: list[FileResult] = field(default_factory=list)
    waited: bool = False
    wait_timed_out: bool = False

    def counts(self) -> dict[str, int]:
        """Files per outcome (every outcome present, in summary order)."""
        found = Counter(f.outcome for f in self.files)
        return {outcome: found.get(outcome, 0) for outcome in OUTCOMES}

    def labelling_counts(self) -> dict[str, int]:
        """With ``--wait``: references per final status (``done``, ``failed``, or still pending)."""
        return dict(Counter(f.final_status or "pending" for f in self.files if f.outcome == "accepted"))

    @property
    def exit_code(self) -> int:
        failed = self.counts()["failed"] > 0
        if self.waited:
            labels = self.labelling_counts()
            failed = failed or self.wait_timed_out or labels.get("failed", 0) > 0
        return 1 if failed else 0

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "url": self.url,
            "map_id": self.map_id,
            "map_name": self.map_name,
            "summary": self.counts(),
            "exit_code": self.exit_code,
            "files": [asdict(f) for f in self.files],
        }
        if self.waited:
            out["labelling"] = self.labelling_counts()
            out["wait_timed_out"] = self.wait_timed_out
        return out


class ServiceUnreachable(Exception):
    """The service did not answer (connection or protocol errors) after all retries."""


class IngestAbort(Exception):
    """The run cannot start (unknown map, bad API key, service unreachable)."""


def path_order(relative: str) -> tuple[tuple[str, ...], str, str]:
    """Sort key of a relative path: by folder, then name without suffix (``a.jpg`` before ``a-copy.jpg``)."""
    path = Path(relative)
    return path.parent.parts, path.stem, path.suffix


def scan_folder(folder: Path, *, recursive: bool) -> tuple[list[Candidate], list[FileResult]]:
    """Photos to upload (sorted by path, content-checked, hashed, one per sha256) and the files skipped."""
    found = (p for p in (folder.rglob("*") if recursive else folder.iterdir()) if p.is_file())
    paths = sorted(found, key=lambda p: path_order(p.relative_to(folder).as_posix()))
    candidates: list[Candidate] = []
    others: list[FileResult] = []
    first_by_sha: dict[str, str] = {}
    for path in paths:
        relative = path.relative_to(folder).as_posix()
        try:
            data = path.read_bytes()
        except OSError as exc:
            others.append(FileResult(relative, "skipped", f"cannot read the file: {exc.strerror or exc}"))
            continue
        if not data:
            others.append(FileResult(relative, "skipped", "empty file", size_bytes=0))
            continue
        mime = sniff_photo(data[:16])
        if mime is None:
            others.append(
                FileResult(
                    relative, "skipped", "not a photo: content is not JPEG, PNG, WEBP or TIFF", size_bytes=len(data)
                )
            )
            continue
        sha = hashlib.sha256(data).hexdigest()
        if sha in first_by_sha:
            others.append(
                FileResult(
                    relative,
                    "duplicate",
                    f"same content as {first_by_sha[sha]}; uploaded once",
                    sha256=sha,
                    size_bytes=len(data),
                    mime_type=mime,
                    duplicate_of=first_by_sha[sha],
                )
            )
            continue
        first_by_sha[sha] = relative
        candidates.append(Candidate(path, relative, sha, len(data), mime))
    return candidates, others


def _error_fields(response: httpx.Response) -> tuple[str | None, str, dict[str, Any] | None]:
    """(code, message, details) from the API's error body, or from whatever came back."""
    try:
        error = response.json().get("error") or {}
        return error.get("code"), str(error.get("message") or response.reason_phrase), error.get("details")
    except (ValueError, AttributeError):
        text = response.text.strip().replace("\n", " ")
        return None, (text[:200] or response.reason_phrase or f"HTTP {response.status_code}"), None


def _retry_after_s(response: httpx.Response) -> float | None:
    raw = response.headers.get("retry-after", "")
    try:
        return min(max(float(raw), 0.0), 60.0)
    except ValueError:
        return None


class Client:
    """An ``httpx.Client`` with retries of transient errors and exponential backoff."""

    def __init__(
        self,
        url: str,
        api_key: str | None,
        *,
        retries: int = 5,
        backoff_s: float = 0.5,
        timeout_s: float = 120.0,
        transport: httpx.BaseTransport | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        headers = {"X-API-Key": api_key} if api_key else {}
        self.http = httpx.Client(
            base_url=url.rstrip("/"),
            headers=headers,
            timeout=httpx.Timeout(timeout_s, connect=10.0),
            transport=transport,
        )
        self.retries = retries
        self.backoff_s = backoff_s
        self.sleep = sleep
        self.stop = threading.Event()

    def close(self) -> None:
        self.http.close()

    def request(self, method: str, path: str, **kwargs: Any) -> tuple[httpx.Response, int]:
        """The response and the number of attempts; retries 408/429/5xx and transport errors.

        Returns the last response when retries run out on a retryable status; raises
        :class:`ServiceUnreachable` when they run out on transport errors.
        """
        attempt = 0
        while True:
            attempt += 1
            try:
                response = self.http.request(method, path, **kwargs)
            except httpx.TransportError as exc:
                if attempt > self.retries or self.stop.is_set():
                    raise ServiceUnreachable(f"{type(exc).__name__}: {exc}") from exc
                self.sleep(self._delay(attempt, None))
                continue
            if response.status_code not in RETRY_STATUSES or attempt > self.retries or self.stop.is_set():
                return response, attempt
            self.sleep(self._delay(attempt, _retry_after_s(response)))

    def alive(self) -> bool:
        """Whether ``/healthz`` answers now (one try)."""
        try:
            return self.http.get("/healthz", timeout=5.0).status_code == 200
        except httpx.HTTPError:
            return False

    def _delay(self, attempt: int, retry_after: float | None) -> float:
        if retry_after is not None:
            return retry_after
        return min(self.backoff_s * 2 ** (attempt - 1), MAX_BACKOFF_S) * random.uniform(0.75, 1.25)


def fetch_map(client: Client, map_id: int) -> dict[str, Any]:
    """The map (checks reachability, the API key and the map id before anything is uploaded)."""
    try:
        response, _ = client.request("GET", f"/v1/maps/{map_id}")
    except ServiceUnreachable as exc:
        raise IngestAbort(f"cannot reach the service at {client.http.base_url}: {exc}") from exc
    if response.status_code == 200:
        return response.json()
    code, message, _ = _error_fields(response)
    raise IngestAbort(
        f"GET /v1/maps/{map_id} answered {response.status_code} {code or ''}: {message}".replace("  ", " ")
    )


def upload_one(client: Client, map_id: int, photo: Candidate) -> FileResult:
    """Post one photo; classify the answer."""
    result = FileResult(
        photo.relative, "failed", sha256=photo.sha256, size_bytes=photo.size_bytes, mime_type=photo.mime_type
    )
    if client.stop.is_set():
        result.reason = "not attempted: the service stopped answering"
        return result
    try:
        data = photo.path.read_bytes()
    except OSError as exc:
        result.reason = f"cannot read the file: {exc.strerror or exc}"
        return result
    try:
        response, result.attempts = client.request(
            "POST", f"/v1/maps/{map_id}/references", files={"image": (photo.path.name, data, photo.mime_type)}
        )
    except ServiceUnreachable as exc:
        if not client.alive():
            client.stop.set()  # the rest would only wait for the same dead service
        result.attempts = client.retries + 1
        result.reason = f"service unreachable after {result.attempts} attempts: {exc}"
        return result
    result.http_status = response.status_code
    if response.status_code in (200, 201, 202):
        body = response.json()
        result.reference_id, result.job_id = body.get("id"), body.get("job_id")
        if body.get("duplicate"):
            result.outcome = "present"
            result.reason = f"already reference {result.reference_id} of map {map_id} (status {body.get('status')})"
        else:
            result.outcome = "accepted"
        return result
    result.error_code, message, result.details = _error_fields(response)
    distance = (result.details or {}).get("distance_m")
    if isinstance(distance, int | float) and distance >= 10_000:
        message += f" (about {distance / 1000:,.0f} km)"
    result.reason = f"{response.status_code} {result.error_code or 'error'}: {message}"
    if response.status_code in RETRY_STATUSES:
        result.reason = f"{result.reason} (gave up after {result.attempts} attempts)"
    photo_refused = 400 <= response.status_code < 500 and response.status_code not in RETRY_STATUSES
    result.outcome = "rejected" if photo_refused and response.status_code not in NOT_THE_PHOTOS_FAULT else "failed"
    return result


def _progress(console: Console) -> Progress:
    return Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[status]}"),
        console=console,
        transient=False,
    )


def _count_text(results: Iterable[FileResult]) -> str:
    counts = Counter(r.outcome for r in results)
    return " ".join(f"{name} {counts[name]}" for name in ("accepted", "present", "rejected", "failed") if counts[name])


def upload_all(
    client: Client, map_id: int, photos: list[Candidate], *, concurrency: int, console: Console
) -> list[FileResult]:
    """Upload ``photos`` with ``concurrency`` threads and a progress bar; results in ``photos`` order."""
    results: dict[int, FileResult] = {}
    with _progress(console) as progress, ThreadPoolExecutor(max_workers=concurrency) as pool:
        task = progress.add_task("uploading", total=len(photos), status="")
        futures = {pool.submit(upload_one, client, map_id, photo): i for i, photo in enumerate(photos)}
        try:
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                progress.update(task, advance=1, status=_count_text(results.values()))
        except KeyboardInterrupt:
            client.stop.set()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return [results[i] for i in range(len(photos))]


def wait_for_labelling(
    client: Client, results: list[FileResult], *, timeout_s: float, poll_s: float, console: Console
) -> bool:
    """Poll the new references until each is ``done`` or ``failed``; False when ``timeout_s`` (> 0) ran out."""
    pending = {r.reference_id: r for r in results if r.outcome == "accepted" and r.reference_id is not None}
    deadline = time.monotonic() + timeout_s if timeout_s > 0 else None
    with _progress(console) as progress:
        task = progress.add_task("labelling", total=len(pending), status="")
        while pending:
            for reference_id, result in list(pending.items()):
                try:
                    response, _ = client.request("GET", f"/v1/references/{reference_id}")
                except ServiceUnreachable:
                    continue  # keep waiting: the service may come back
                if response.status_code == 200:
                    body = response.json()
                    result.final_status, result.final_error = body.get("status"), body.get("error")
                elif response.status_code < 500 and response.status_code not in RETRY_STATUSES:
                    code, message, _ = _error_fields(response)  # deleted meanwhile, or the key cannot read
                    result.final_status = "failed"
                    result.final_error = f"cannot read the reference: {response.status_code} {code}: {message}"
                if result.final_status in FINAL_REFERENCE_STATES:
                    del pending[reference_id]
                    progress.update(task, advance=1)
            statuses = Counter(r.final_status for r in results if r.outcome == "accepted" and r.final_status)
            progress.update(task, status=" ".join(f"{k} {v}" for k, v in sorted(statuses.items())))
            if not pending:
                break
            if deadline is not None and time.monotonic() >= deadline:
                return False
            time.sleep(poll_s)
    return True


def ingest_folder(
    folder: Path,
    map_id: int,
    *,
    url: str,
    api_key: str | None,
    concurrency: int = 4,
    recursive: bool = False,
    wait: bool = False,
    wait_timeout_s: float = 0.0,
    poll_s: float = 1.0,
    retries: int = 5,
    backoff_s: float = 0.5,
    timeout_s: float = 120.0,
    console: Console | None = None,
    transport: httpx.BaseTransport | None = None,
) -> IngestReport:
    """Scan, upload and (optionally) wait; raises :class:`IngestAbort` when nothing can be done."""
    console = console or Console(stderr=True)
    client = Client(url, api_key, retries=retries, backoff_s=backoff_s, timeout_s=timeout_s, transport=transport)
    try:
        map_row = fetch_map(client, map_id)
        report = IngestReport(url=url, map_id=map_id, map_name=map_row.get("name"))
        photos, others = scan_folder(folder, recursive=recursive)
        console.print(
            f"map {map_id} ({map_row.get('name')}) at {url}: {len(photos)} photo(s) to upload from {folder}"
            + (f", {len(others)} other file(s) not uploaded" if others else "")
        )
        uploaded = upload_all(client, map_id, photos, concurrency=concurrency, console=console) if photos else []
        report.files = sorted([*uploaded, *others], key=lambda r: path_order(r.path))
        if wait:
            report.waited = True
            report.wait_timed_out = not wait_for_labelling(
                client, report.files, timeout_s=wait_timeout_s, poll_s=poll_s, console=console
            )
        return report
    finally:
        client.close()


def _first_line(text: str | None, limit: int = 160) -> str:
    lines = [line for line in (text or "").strip().splitlines() if line.strip()]
    line = lines[-1].strip() if lines else ""
    return line if len(line) <= limit else line[: limit - 1] + "…"


def print_summary(report: IngestReport, console: Console, *, max_rows: int = 100) -> None:
    """The summary table, the files that were not accepted with their reasons, and what it means."""
    counts = report.counts()
    console.print(f"geoloc ingest: map {report.map_id} ({report.map_name}) at {report.url}", highlight=False)
    table = Table()
    table.add_column("outcome")
    table.add_column("files", justify="right")
    for outcome, label in OUTCOMES.items():
        table.add_row(label, str(counts[outcome]))
        if outcome in ("rejected", "failed"):
            reasons = Counter(
                f"{f.http_status or '-'} {f.error_code or 'error'}" for f in report.files if f.outcome == outcome
            )
            for reason, n in sorted(reasons.items()):
                table.add_row(f"  {reason}", str(n), style="dim")
    table.add_row("total", str(len(report.files)), style="bold")
    if report.waited:
        for status, n in sorted(report.labelling_counts().items()):
            table.add_row(f"labelling of new references: {status}", str(n))
    console.print(table)

    listed = [f for f in report.files if f.outcome in ("rejected", "failed", "skipped", "duplicate")]
    if report.waited:
        listed += [f for f in report.files if f.outcome == "accepted" and f.final_status != "done"]
    if listed:
        details = Table(title="files that were not accepted (or not labelled), and why", title_justify="left")
        details.add_column("file", overflow="fold")
        details.add_column("outcome")
        details.add_column("reason", overflow="fold")
        for f in listed[:max_rows]:
            if f.outcome == "accepted":
                details.add_row(f.path, f"labelling {f.final_status or 'pending'}", _first_line(f.final_error))
            else:
                details.add_row(f.path, f.outcome, f.reason or "")
        console.print(details)
        if len(listed) > max_rows:
            console.print(f"... and {len(listed) - max_rows} more (use --json for every file)")

    notes = []
    if counts["rejected"]:
        notes.append(
            f"{counts['rejected']} photo(s) were rejected by the service for the reasons above; "
            "rejections are not failures of this run."
        )
    if counts["failed"]:
        notes.append(f"{counts['failed']} photo(s) failed after retries; run the command again to retry them.")
    failed_labels = report.labelling_counts().get("failed", 0) if report.waited else 0
    if failed_labels:
        notes.append(f"{failed_labels} new reference(s) were stored but their labelling failed (errors above).")
    if report.waited and report.wait_timed_out:
        notes.append("stopped waiting before every new reference was labelled (--wait-timeout).")
    notes.append(f"exit code {report.exit_code}")
    console.print("\n".join(notes))


def ingest(
    folder: Path = typer.Argument(..., exists=True, file_okay=False, dir_okay=True, help="Folder of photos."),
    map_id: int = typer.Option(..., "--map", "-m", help="Id of the map the photos are references of."),
    url: str = typer.Option("http://127.0.0.1:8000", "--url", envvar="GEOLOC_URL", help="Base URL of the service."),
    api_key: str | None = typer.Option(
        None, "--api-key", envvar="GEOLOC_API_KEY", help="API key with the write scope (X-API-Key)."
    ),
    concurrency: int = typer.Option(4, "--workers", "--concurrency", "-j", min=1, max=64, help="Parallel uploads."),
    recursive: bool = typer.Option(False, "--recursive", "-r", help="Include photos in subfolders."),
    wait: bool = typer.Option(False, "--wait", help="Then wait until every new reference is labelled or failed."),
    wait_timeout: float = typer.Option(0.0, "--wait-timeout", min=0, help="Stop waiting after S seconds (0: never)."),
    json_out: Path | None = typer.Option(None, "--json", help="Write every file's outcome to this JSON file."),
    retries: int = typer.Option(5, "--retries", min=0, help="Retries of transient errors (connection, 429, 5xx)."),
    timeout: float = typer.Option(120.0, "--timeout", min=1, help="Seconds per HTTP request."),
) -> None:
    """Upload every photo in a folder as a reference of a map; print what was accepted, rejected and why.

    Exit codes:
    0: nothing failed (photos the service rejects are listed with the reason, they are not failures);
    1: some photos failed after retries (with --wait: some labelling failed or the wait timed out);
    2: the service cannot be reached, the API key is refused, or the map does not exist.
    """
    stdout = Console(width=None if sys.stdout.isatty() else 160)
    stderr = Console(stderr=True)
    try:
        report = ingest_folder(
            folder,
            map_id,
            url=url,
            api_key=api_key,
            concurrency=concurrency,
            recursive=recursive,
            wait=wait,
            wait_timeout_s=wait_timeout,
            retries=retries,
            timeout_s=timeout,
            console=stderr,
        )
    except IngestAbort as exc:
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
