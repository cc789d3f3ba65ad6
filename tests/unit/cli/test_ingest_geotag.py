"""``geoloc ingest --gpx TRACK.gpx [--time-offset S]`` and Mapillary's description file, up to the form fields sent.

No server: a mock transport answers the map lookup and records every reference upload's form. The Lund
photos (29 phone photos of one walk, with GPS and Mapillary's JSON in EXIF) are copied with their GPS
stripped and placed again by a GPX track written from their original positions and capture times.
"""

from __future__ import annotations

import io
import json
import math
from datetime import UTC, datetime, timedelta
from email.message import Message
from email.parser import BytesParser
from email.policy import HTTP
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import piexif
import pytest
from rich.console import Console
from typer.testing import CliRunner

from cli import ingest as ingest_module
from cli.ingest import IngestOptions, ingest_folder
from cli.ingest_report import IngestReport, print_summary
from cli.main import app
from contracts.settings import shared_path
from geoloc.photos.capture import read_capture
from geoloc.photos.exif import ExifFields, read_exif, write_jpeg
from tests.unit.cli.test_ingest_retries import MOCK_MAP

LUND = shared_path("data", "lund", "images")
pytestmark = pytest.mark.skipif(not LUND.is_dir(), reason="the Lund photos are not in the shared data")


def lund_originals() -> dict[str, tuple[float, float, datetime, dict[str, Any]]]:
    """Each Lund photo's name -> (lat, lon, capture time (UTC), its Mapillary JSON), read from the photo."""
    out = {}
    for path in sorted(LUND.glob("*.jpg")):
        exif, capture = read_exif(path), read_capture(path)
        assert exif.lat is not None and exif.lon is not None and capture.time is not None
        description = piexif.load(str(path))["0th"][piexif.ImageIFD.ImageDescription]
        out[path.name] = (exif.lat, exif.lon, capture.time, json.loads(description))
    return out


def stripped_copy(source: Path, target: Path, *, keep_description: bool = True) -> Path:
    """``source`` with its EXIF GPS removed (and its ImageDescription: Mapillary's JSON, unless kept)."""
    exif = piexif.load(str(source))
    exif["GPS"] = {}
    if not keep_description:
        exif["0th"].pop(piexif.ImageIFD.ImageDescription, None)
    piexif.insert(piexif.dump(exif), source.read_bytes(), str(target))
    return target


def write_gpx(path: Path, points: list[tuple[datetime, float, float]]) -> Path:
    """A GPX 1.1 track of (time, lat, lon) points, as a logger writes it."""
    rows = "".join(
        f'<trkpt lat="{lat:.9f}" lon="{lon:.9f}"><ele>35</ele>'
        f"<time>{t.astimezone(UTC).strftime('%Y-%m-%dT%H:%M:%S.%fZ')}</time></trkpt>\n"
        for t, lat, lon in points
    )
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<gpx version="1.1" creator="logger" '
        f'xmlns="http://www.topografix.com/GPX/1/1"><trk><trkseg>\n{rows}</trkseg></trk></gpx>\n'
    )
    return path


def form_of(request: httpx.Request) -> tuple[str, dict[str, str]]:
    """The uploaded file's name and the text fields of a multipart request."""
    head = f"Content-Type: {request.headers['content-type']}\r\n\r\n".encode()
    message = BytesParser(policy=HTTP).parsebytes(head + request.content)
    assert isinstance(message, Message)
    filename, fields = "", {}
    for part in message.iter_parts():
        name = part.get_param("name", header="content-disposition")
        if part.get_filename():
            filename = part.get_filename() or ""
        else:
            fields[str(name)] = part.get_content().strip()
    return filename, fields


def recording_transport(sent: dict[str, dict[str, str]]) -> httpx.MockTransport:
    """Answers the map lookup and every upload (202); ``sent``: the file name -> the form fields posted."""
    counter = iter(range(1, 10_000))

    def handler(request: httpx.Request) -> httpx.Response:
        if request.method == "GET":
            return httpx.Response(200, json=MOCK_MAP)
        filename, fields = form_of(request)
        sent[filename] = fields
        n = next(counter)
        body = {"id": n, "map_id": 1, "job_id": n, "status": "queued", "sha256": "ab", "duplicate": False}
        return httpx.Response(202, json=body)

    return httpx.MockTransport(handler)


def run_ingest(folder: Path, **options: Any) -> tuple[IngestReport, dict[str, dict[str, str]]]:
    sent: dict[str, dict[str, str]] = {}
    report = ingest_folder(
        folder,
        1,
        IngestOptions(url="http://mock", api_key=None, retries=0, **options),
        transport=recording_transport(sent),
        console=Console(file=io.StringIO()),
    )
    return report, sent


def metres(lat_a: float, lon_a: float, lat_b: float, lon_b: float) -> float:
    north = (lat_b - lat_a) * 111_132.0
    east = (lon_b - lon_a) * 111_320.0 * math.cos(math.radians(lat_a))
    return math.hypot(east, north)


@pytest.mark.parametrize("clock_error_s", [0.0, 3600.0])
def test_lund_photos_without_gps_are_placed_by_a_gpx_of_their_walk_within_a_metre(
    tmp_path: Path, clock_error_s: float
) -> None:
    """The camera's clock ``clock_error_s`` behind the logger's: ``--time-offset`` puts it right."""
    originals = lund_originals()
    assert len(originals) == 29
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in originals:
        stripped_copy(LUND / name, photos / name)
        assert read_exif(photos / name).lat is None
    track = [(t + timedelta(seconds=clock_error_s), lat, lon) for lat, lon, t, _ in originals.values()]
    gpx = write_gpx(tmp_path / "walk.gpx", track)
    report, sent = run_ingest(photos, gpx=gpx, time_offset_s=clock_error_s)
    assert report.counts()["accepted"] == 29 and report.exit_code == 0
    for name, (lat, lon, _, _) in originals.items():
        fields = sent[name]
        assert metres(lat, lon, float(fields["lat"]), float(fields["lon"])) < 1.0, name
        assert "heading_deg" not in fields, "the photo's own compass (Mapillary's JSON) is the service's to read"
        assert "sequence" not in fields, "the photo's EXIF names its sequence"
    first = next(f for f in report.files if f.path == "01.jpg")
    assert first.field_sources is not None and "GPX track" in first.field_sources["position"]
    assert "Mapillary JSON" in first.field_sources["position"], "the capture time came from the photo's JSON"


def test_photos_the_track_cannot_place_are_skipped_with_the_reason_and_not_uploaded(tmp_path: Path) -> None:
    originals = lund_originals()
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("27.jpg", "28.jpg", "29.jpg"):
        stripped_copy(LUND / name, photos / name)
    stripped_copy(LUND / "01.jpg", photos / "no-time.jpg", keep_description=False)  # no capture time at all
    on_track = [(t, lat, lon) for name, (lat, lon, t, _) in originals.items() if name < "29"]
    gpx = write_gpx(tmp_path / "walk.gpx", on_track)
    report, sent = run_ingest(photos, gpx=gpx)
    assert sorted(sent) == ["27.jpg", "28.jpg"], "only the photos on the track are uploaded"
    files = {f.path: f for f in report.files}
    late = files["29.jpg"]
    assert late.outcome == "skipped" and late.reason is not None
    assert "outside the GPX track: taken at 2014-06-07T10:27:22.459Z, 7.9 s after the GPX track ends" in late.reason
    assert "no capture time" in (files["no-time.jpg"].reason or "")
    assert report.counts()["skipped"] == 2 and report.exit_code == 0, "skipped photos are not failures"
    printed = Console(file=io.StringIO(), width=300)
    print_summary(report, printed)
    text = printed.file.getvalue()  # type: ignore[attr-defined]
    assert "after the GPX track ends" in text and "not placed by --gpx" in text


def description_entries(originals: dict[str, tuple[float, float, datetime, dict[str, Any]]], folder: Path) -> list[Any]:
    """``mapillary_image_description.json`` as mapillary_tools writes it, from the originals' JSON and GPS."""
    entries: list[Any] = []
    for name, (lat, lon, _, meta) in originals.items():
        entries.append(
            {
                "filename": str(folder / name),
                "filetype": "image",
                "MAPLatitude": lat,
                "MAPLongitude": lon,
                "MAPAltitude": 35.0,
                "MAPCaptureTime": meta["MAPCaptureTime"],
                "MAPCompassHeading": meta["MAPCompassHeading"],
                "MAPSequenceUUID": meta["MAPSequenceUUID"],
                "MAPDeviceMake": "Apple",
                "MAPDeviceModel": "iPhone4,1",
            }
        )
    entries.append({"filename": str(folder / "broken.jpg"), "error": {"type": "MapillaryGeoTaggingError"}})
    return entries


def test_a_mapillary_description_file_supplies_what_the_exif_lacks(tmp_path: Path) -> None:
    originals = lund_originals()
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in originals:
        bare = stripped_copy(LUND / name, photos / name, keep_description=False)
        capture = read_capture(bare)
        assert (capture.time, capture.compass, capture.sequence_id, read_exif(bare).lat) == (None, None, None, None)
    (photos / "mapillary_image_description.json").write_text(json.dumps(description_entries(originals, photos)))
    report, sent = run_ingest(photos)
    assert report.counts()["accepted"] == 29 and len(report.files) == 29, "the description file is not a photo"
    for name, (lat, lon, _, meta) in originals.items():
        fields = sent[name]
        assert (float(fields["lat"]), float(fields["lon"])) == (lat, lon)
        assert float(fields["heading_deg"]) == pytest.approx(meta["MAPCompassHeading"]["TrueHeading"], abs=1e-3)
        assert fields["sequence"] == meta["MAPSequenceUUID"]
    # With a track too: the description's capture time places each photo on it; its compass stays the heading.
    gpx = write_gpx(tmp_path / "walk.gpx", [(t, lat, lon) for lat, lon, t, _ in originals.values()])
    report, sent = run_ingest(photos, gpx=gpx)
    assert report.counts()["accepted"] == 29
    for name, (lat, lon, _, meta) in originals.items():
        assert metres(lat, lon, float(sent[name]["lat"]), float(sent[name]["lon"])) < 1.0, name
        assert float(sent[name]["heading_deg"]) == pytest.approx(meta["MAPCompassHeading"]["TrueHeading"], abs=1e-3)
    sources = next(f for f in report.files if f.path == "02.jpg").field_sources or {}
    assert "mapillary_image_description.json (UTC)" in sources["position"]
    assert sources["heading"].startswith("mapillary_image_description.json")


def test_without_a_compass_the_heading_is_the_direction_of_travel(tmp_path: Path) -> None:
    """A camera set to local time (UTC+2) without a compass, walking east: ``--time-offset -7200``."""
    photos = tmp_path / "photos"
    photos.mkdir()
    start = datetime(2024, 6, 1, 10, 0, 0, tzinfo=UTC)
    deg_per_m_lon = 1.0 / (111_320.0 * math.cos(math.radians(55.7)))
    track = [(start + timedelta(seconds=2 * i), 55.7, 13.19 + 1.5 * i * deg_per_m_lon) for i in range(20)]
    gpx = write_gpx(tmp_path / "walk.gpx", track)
    rgb = np.random.default_rng(1).integers(0, 255, size=(240, 320, 3), dtype=np.uint8)
    for i, seconds in enumerate((5, 13, 30)):
        local = (start + timedelta(hours=2, seconds=seconds)).replace(tzinfo=None)
        write_jpeg(photos / f"p{i}.jpg", rgb + i, ExifFields(focal_35mm=28, taken=local))
    report, sent = run_ingest(photos, gpx=gpx, time_offset_s=-7200)
    assert report.counts()["accepted"] == 3
    for i, seconds in enumerate((5, 13, 30)):
        fields = sent[f"p{i}.jpg"]
        assert float(fields["heading_deg"]) == pytest.approx(90.0, abs=0.1)
        expected_lon = 13.19 + 1.5 * (seconds / 2) * deg_per_m_lon
        assert metres(55.7, expected_lon, float(fields["lat"]), float(fields["lon"])) < 0.01
    sources = report.files[0].field_sources or {}
    assert sources["heading"] == "GPX track's direction of travel"
    assert "no time zone: read as UTC" in sources["position"]


def test_the_command_line_passes_the_track_and_the_offset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gpx = write_gpx(tmp_path / "walk.gpx", [(datetime(2024, 6, 1, tzinfo=UTC), 55.7, 13.19)])
    seen: dict[str, Any] = {}

    def fake_ingest(folder: Path, map_id: int, options: IngestOptions, **_: Any) -> IngestReport:
        seen.update(vars(options), folder=folder, map_id=map_id)
        return IngestReport(url=options.url, map_id=map_id, map_name="mock")

    monkeypatch.setattr(ingest_module, "ingest_folder", fake_ingest)
    args = ["ingest", str(tmp_path), "--map", "3", "--url", "http://mock", "--gpx", str(gpx), "--time-offset", "-7200"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert (seen["map_id"], seen["gpx"], seen["time_offset_s"]) == (3, gpx, -7200.0)


@pytest.mark.parametrize(
    ("content", "fragment"), [("<gpx><trk>", "not a GPX file"), ("<gpx version='1.1'/>", "no track points")]
)
def test_an_unreadable_track_stops_the_run_before_anything_is_sent(tmp_path: Path, content: str, fragment: str) -> None:
    gpx = tmp_path / "walk.gpx"
    gpx.write_text(content)
    (tmp_path / "photos").mkdir()
    result = CliRunner().invoke(  # port 9 answers nothing: the track is read before the service is asked
        app, ["ingest", str(tmp_path / "photos"), "--map", "1", "--url", "http://127.0.0.1:9", "--gpx", str(gpx)]
    )
    assert result.exit_code == 2 and fragment in result.output, result.output
    assert "cannot reach the service" not in result.output
