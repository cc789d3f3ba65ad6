"""Helpers for service and worker tests.

A real ``geoloc serve``/``geoloc worker`` subprocess on a free loopback port with its own data folder,
table counts, test images, and test-only job handlers.

The handlers below register themselves when this file is loaded as a worker plugin
(``GEOLOC_WORKER_PLUGINS=<path of this file>``); they are never shipped with the service.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from contracts.jobs import JobPayload, JobResult
from testbed.maps import ONE_BUILDING
from workers.handlers import register

REPO_ROOT = Path(__file__).resolve().parent.parent
THIS_FILE = Path(__file__).resolve()
WRITE_KEY = "test-write-key"
READ_KEY = "test-read-key"


# --- test-only job handlers ---------------------------------------------------------------------


def _append_line(path: str, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (text + "\n").encode())
    finally:
        os.close(fd)


class RecordPayload(JobPayload):
    """``test_record``: append ``token pid`` to the file ``log`` after ``seconds``."""

    token: int
    log: str
    seconds: float = 0.0


class RecordResult(JobResult):
    """``test_record``'s result: the token and the process that ran it."""

    token: int
    pid: int


class SleepPayload(JobPayload):
    """``test_sleep``: sleep ``seconds``, logging start and end to the file ``log``."""

    seconds: float
    log: str


class SleepResult(JobResult):
    """``test_sleep``'s result."""

    slept_s: float


class FailPayload(JobPayload):
    """``test_fail``: fail with ``reason``."""

    reason: str = "test"


@register("test_record", RecordPayload)
def record_handler(_db: Any, payload: RecordPayload) -> RecordResult:
    """Append ``token pid`` to ``payload.log`` (detects a job run twice)."""
    time.sleep(payload.seconds)
    _append_line(payload.log, f"{payload.token} {os.getpid()}")
    return RecordResult(token=payload.token, pid=os.getpid())


@register("test_sleep", SleepPayload)
def sleep_handler(_db: Any, payload: SleepPayload) -> SleepResult:
    """Log ``start pid``, sleep ``payload.seconds``, log ``end pid`` (for crash tests)."""
    _append_line(payload.log, f"start {os.getpid()}")
    time.sleep(payload.seconds)
    _append_line(payload.log, f"end {os.getpid()}")
    return SleepResult(slept_s=payload.seconds)


@register("test_fail", FailPayload)
def fail_handler(_db: Any, payload: FailPayload) -> JobResult:
    """Always fail (retry tests)."""
    raise RuntimeError(f"deliberate failure: {payload.reason}")


# --- processes ----------------------------------------------------------------------------------


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def geoloc_command() -> list[str]:
    """How to run the ``geoloc`` console script of this environment."""
    script = Path(sys.executable).parent / "geoloc"
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "from cli.main import app; app()"]


def service_env(data_dir: Path, **overrides: str) -> dict[str, str]:
    """Environment for a service/worker subprocess: its own data dir, short leases, test handlers."""
    env = {
        **os.environ,
        "GEOLOC_DATA_DIR": str(data_dir),
        "GEOLOC_JOB_LEASE_S": "2",
        "GEOLOC_JOB_RETRY_DELAY_S": "0.1",
        "GEOLOC_WORKER_POLL_MAX_S": "0.2",
        "GEOLOC_WORKER_GRACE_S": "2",
        "GEOLOC_READY_WORKER_S": "10",
        "GEOLOC_WORKER_PLUGINS": str(THIS_FILE),
        "PYTHONUNBUFFERED": "1",
    }
    env.update(overrides)
    return env


@dataclass
class RunningProcess:
    """A supervised ``geoloc`` process with its data folder, database and log file.

    The database is a SQLite path or a PostgreSQL URL.
    """

    process: subprocess.Popen
    data_dir: Path
    log_path: Path
    database: Path | str
    base_url: str | None = None

    def client(self, api_key: str | None = WRITE_KEY, timeout: float = 60.0) -> httpx.Client:
        headers = {"X-API-Key": api_key} if api_key else {}
        assert self.base_url is not None
        return httpx.Client(base_url=self.base_url, headers=headers, timeout=timeout)

    def log_tail(self, lines: int = 60) -> str:
        text = self.log_path.read_text(errors="replace") if self.log_path.exists() else ""
        return "\n".join(text.splitlines()[-lines:])

    def stop(self, timeout: float = 30.0) -> int:
        """SIGTERM the supervisor (it stops its children) and wait."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        return int(self.process.returncode)


def start_process(args: list[str], data_dir: Path, env: dict[str, str], cwd: Path = REPO_ROOT) -> RunningProcess:
    """Start ``geoloc ARGS`` in its own process group, output to ``data_dir/../<name>-<command>[-n].log``.

    ``cwd``: the folder it runs in (first on its children's ``python -m`` import path: another release's code).
    """
    data_dir.mkdir(parents=True, exist_ok=True)
    log_path = data_dir.parent / f"{data_dir.name}-{args[0]}.log"
    for n in range(2, 100):  # a second process on the same data folder (two API processes) gets its own log
        if not log_path.exists():
            break
        log_path = data_dir.parent / f"{data_dir.name}-{args[0]}-{n}.log"
    log_file = log_path.open("ab")
    process = subprocess.Popen(
        [*geoloc_command(), *args],
        cwd=cwd,
        env=env,
        stdout=log_file,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    log_file.close()
    return RunningProcess(process, data_dir, log_path, env.get("GEOLOC_DATABASE_URL") or data_dir / "geoloc.sqlite3")


def wait_for(predicate: Any, timeout: float, interval: float = 0.1, what: Any = "condition") -> Any:
    """Poll ``predicate()`` until it returns something truthy; fail after ``timeout`` seconds.

    ``what`` (a string, or a callable giving one, e.g. to show a log) describes the wait.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise TimeoutError(f"timed out after {timeout:.0f} s waiting for {what() if callable(what) else what}")


API_KEYS = f"{WRITE_KEY}:write,{READ_KEY}:read"


def _link_models(data_dir: Path, models: Path) -> None:
    # Imported here: this file is also loaded on its own, as a worker plugin, where relative imports fail.
    from tests.model_fixtures import link_models

    link_models(data_dir, models)


@contextlib.contextmanager
def running_service(
    data_dir: Path,
    *,
    workers: int = 1,
    models: Path | None = None,
    api_keys: str | None = API_KEYS,
    cwd: Path = REPO_ROOT,
    log_level: str = "warning",
    **env_overrides: str,
) -> Iterator[RunningProcess]:
    """``geoloc serve`` on a free loopback port (with ``api_keys``, none if None); yields once /healthz answers.

    ``log_level``: of the API and the workers (``info`` logs each request and each job).

    Workers need the built models: pass ``models`` (the ``built_models`` fixture) to link them into
    ``data_dir`` when ``workers`` > 0. ``workers=0`` still runs one worker that claims only ``load_map`` jobs
    (``GEOLOC_WORKER_KINDS``), so that maps are parsed and every other job stays queued. ``cwd``: as for
    :func:`start_process`.
    """
    port = free_port()
    if models is not None:
        _link_models(data_dir, models)
    if workers == 0:  # maps are parsed by load_map jobs: one worker that claims nothing else (needs no models)
        workers = 1
        env_overrides.setdefault("GEOLOC_WORKER_KINDS", "load_map")
    env = service_env(data_dir, **env_overrides)
    if api_keys is not None:
        env["GEOLOC_API_KEYS"] = api_keys
    else:
        env.pop("GEOLOC_API_KEYS", None)
    running = start_process(
        ["serve", "--host", "127.0.0.1", "--port", str(port), "--workers", str(workers), "--log-level", log_level],
        data_dir,
        env,
        cwd,
    )
    running.base_url = f"http://127.0.0.1:{port}"

    def healthy() -> bool:
        if running.process.poll() is not None:
            raise RuntimeError(f"geoloc serve exited early:\n{running.log_tail()}")
        try:
            return httpx.get(f"{running.base_url}/healthz", timeout=1.0).status_code == 200
        except httpx.HTTPError:
            return False

    try:
        wait_for(healthy, timeout=60, what="the API to answer /healthz")
        yield running
    finally:
        running.stop()


@contextlib.contextmanager
def running_workers(
    data_dir: Path, *, concurrency: int = 1, models: Path | None = None, **env_overrides: str
) -> Iterator[RunningProcess]:
    """``geoloc worker --concurrency N`` against ``data_dir`` (``models`` linked in, as for :func:`running_service`)."""
    if models is not None:
        _link_models(data_dir, models)
    running = start_process(
        ["worker", "--concurrency", str(concurrency), "--log-level", "info"],
        data_dir,
        service_env(data_dir, **env_overrides),
    )
    try:
        yield running
    finally:
        running.stop()


# --- database inspection ------------------------------------------------------------------------


def read_rows(database: Path | str, sql: str, params: tuple[Any, ...] = ()) -> list[dict[str, Any]]:
    """Rows of a query (``?`` placeholders) on a (possibly live) database, SQLite path or PostgreSQL URL, as dicts."""
    from db import connect

    db = connect(database)
    try:
        return list(db.query(sql, params))
    finally:
        db.close()


def table_counts(database: Path | str) -> dict[str, int]:
    """Rows per data table (db.stats)."""
    from db import connect
    from db.stats import table_counts as counts

    db = connect(database)
    try:
        return counts(db)
    finally:
        db.close()


def stored_files(data_dir: Path) -> list[str]:
    """Every file under images/, maps/ and tmp/ (relative paths, sorted)."""
    return sorted(
        str(path.relative_to(data_dir))
        for folder in ("images", "maps", "tmp", "queries")
        if (data_dir / folder).exists()
        for path in (data_dir / folder).rglob("*")
        if path.is_file()
    )


def get_job_row(database: Path | str, job_id: int) -> dict[str, Any]:
    """One job row with its payload decoded."""
    row = read_rows(database, "SELECT * FROM jobs WHERE id = ?", (job_id,))[0]
    row["payload"] = json.loads(row["payload"])
    return row


# --- test data ------------------------------------------------------------------------------------


def upload_hall_map(client: httpx.Client) -> int:
    """Upload :data:`ONE_BUILDING` as the map "hall" (waiting up to 120 s for it to load); its id."""
    files = {"file": ("hall.geojson", json.dumps(ONE_BUILDING).encode())}
    response = client.post("/v1/maps", files=files, data={"wait_s": "120", "name": "hall"})
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


"""A GeoJSON map of one building in Helsinki (loads in milliseconds)."""
INSIDE_ONE_BUILDING = {"lat": "60.1699", "lon": "24.9402"}
"""Form fields placing a reference just south of that building."""


# --- test images --------------------------------------------------------------------------------


def _dms(value: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    value = abs(value)
    degrees = int(value)
    minutes = int((value - degrees) * 60)
    seconds = round(((value - degrees) * 60 - minutes) * 60 * 10000)
    return ((degrees, 1), (minutes, 1), (seconds, 10000))


def jpeg_bytes(
    width: int = 640,
    height: int = 480,
    *,
    gps: tuple[float, float] | None = None,
    seed: int = 0,
    quality: int = 90,
    description: str | None = None,
    direction: tuple[float, str] | None = None,
) -> bytes:
    """A textured JPEG, optionally with EXIF GPS (lat, lon) and a 35 mm focal length.

    description: the 0th IFD's ImageDescription (e.g. Mapillary's JSON); direction: EXIF GPSImgDirection
    (deg) and its ref ("T" or "M").
    """
    import numpy as np
    import piexif
    from PIL import Image

    rng = np.random.default_rng(seed)
    pixels = rng.integers(0, 255, size=(height // 8 + 1, width // 8 + 1, 3), dtype=np.uint8)
    image = Image.fromarray(pixels).resize((width, height), Image.Resampling.NEAREST)
    exif: dict[str, Any] = {"0th": {}, "Exif": {piexif.ExifIFD.FocalLengthIn35mmFilm: 28}, "GPS": {}}
    if gps is not None:
        lat, lon = gps
        exif["GPS"] = {
            piexif.GPSIFD.GPSLatitudeRef: b"N" if lat >= 0 else b"S",
            piexif.GPSIFD.GPSLatitude: _dms(lat),
            piexif.GPSIFD.GPSLongitudeRef: b"E" if lon >= 0 else b"W",
            piexif.GPSIFD.GPSLongitude: _dms(lon),
        }
    if description is not None:
        exif["0th"][piexif.ImageIFD.ImageDescription] = description.encode()
    if direction is not None:
        exif["GPS"][piexif.GPSIFD.GPSImgDirection] = (int(round(direction[0] * 100)), 100)
        exif["GPS"][piexif.GPSIFD.GPSImgDirectionRef] = direction[1].encode()
    buffer = io.BytesIO()
    image.save(buffer, "JPEG", quality=quality, exif=piexif.dump(exif))
    return buffer.getvalue()


def png_header_only(width: int, height: int) -> bytes:
    """A PNG that declares ``width x height`` but carries one tiny IDAT.

    A decompression bomb's header: Pillow learns the size without decoding.
    """

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


def phone_photo_twins(source: Path, max_side: int = 816) -> tuple[bytes, bytes]:
    """A real phone photo as a JPEG and a HEIC twin: the same pixels (resized) and the same EXIF bytes.

    ``source`` is a JPEG with EXIF (e.g. ``shared/data/berlin/images/01.jpg``: GPS, compass, focal length);
    the HEIC is written by pillow-heif, as an iPhone would store the photo.
    """
    import pillow_heif
    from PIL import Image

    pillow_heif.register_heif_opener()
    with Image.open(source) as original:
        exif = original.info["exif"]
        scale = max_side / max(original.size)
        image = original.convert("RGB").resize((round(original.width * scale), round(original.height * scale)))
    twins = []
    for kind in ("JPEG", "HEIF"):
        buffer = io.BytesIO()
        image.save(buffer, kind, quality=80, exif=exif)
        twins.append(buffer.getvalue())
    return twins[0], twins[1]


def panorama_jpeg_bytes(
    width: int = 1024, height: int = 512, *, xmp: str | None = "attribute", gps: tuple[float, float] | None = None
) -> bytes:
    """A 2:1 JPEG as a 360-degree camera writes it: equirectangular, with Google's GPano XMP in an APP1 segment.

    xmp: ``"attribute"`` (``GPano:ProjectionType="equirectangular"``), ``"element"``
    (``<GPano:ProjectionType>equirectangular</GPano:ProjectionType>``) or None (no XMP, no EXIF focal length:
    told by its shape alone). gps: EXIF GPS (lat, lon), as :func:`jpeg_bytes` writes it.
    """
    import piexif

    plain = jpeg_bytes(width, height, gps=gps, seed=11)
    exif = piexif.load(plain)
    exif["Exif"].pop(piexif.ExifIFD.FocalLengthIn35mmFilm, None)  # a 360-degree camera states no perspective lens
    out = io.BytesIO()
    piexif.insert(piexif.dump(exif), plain, out)
    data = out.getvalue()
    if xmp is None:
        return data
    sizes = f'GPano:FullPanoWidthPixels="{width}" GPano:FullPanoHeightPixels="{height}"'
    if xmp == "attribute":
        description = f'GPano:UsePanoramaViewer="True" GPano:ProjectionType="equirectangular" {sizes}/>'
    else:
        description = f"{sizes}><GPano:ProjectionType>equirectangular</GPano:ProjectionType></rdf:Description>"
    packet = (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/">'
        '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about="" '
        f'xmlns:GPano="http://ns.google.com/photos/1.0/panorama/" {description}</rdf:RDF></x:xmpmeta>'
        '<?xpacket end="w"?>'
    ).encode()
    segment = b"http://ns.adobe.com/xap/1.0/\x00" + packet
    at = 4 + struct.unpack(">H", data[4:6])[0] if data[2:4] == b"\xff\xe1" else 2  # after the EXIF APP1, as cameras
    return data[:at] + b"\xff\xe1" + struct.pack(">H", len(segment) + 2) + segment + data[at:]
