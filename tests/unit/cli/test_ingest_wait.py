"""``geoloc ingest --wait [placed|labelled]`` against a mock service: what it waits for, reports and exits with.

The same wait against a real service and real workers on a simulated walk is in ``tests/e2e/test_ingest_wait.py``.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import httpx
import pytest
from rich.console import Console
from typer.testing import CliRunner

from cli import ingest as ingest_module
from cli.ingest import IngestOptions, ingest_folder
from cli.ingest_report import IngestReport, print_summary
from cli.ingest_wait import WaitFor
from cli.main import app
from tests.unit.cli.test_ingest_retries import INSIDE_HELSINKI, MOCK_MAP, photo

WALK = "WALK-1"
NAMES = ("a.jpg", "b.jpg", "c.jpg")


def _reference(reference_id: int, status: str, placement: str, sequence_id: str | None = WALK) -> dict[str, Any]:
    """``GET /v1/references/{id}``'s answer, as the service's ``ReferenceOut`` has it."""
    return {
        "id": reference_id,
        "map_id": 1,
        "status": status,
        "sha256": f"{reference_id:064x}",
        "width": 320,
        "height": 240,
        "position": {"lat": 60.17, "lon": 24.94, "source": "exif"},
        "sequence_id": sequence_id,
        "placement": placement,
        "attribution": "© OSM",
        "created_at": "2025-01-01T12:00:00Z",
        "updated_at": "2025-01-01T12:00:00Z",
    }


class MockService:
    """A service whose three uploaded photos (ids 11-13; 11 and 12 one walk) are labelled, then placed.

    Each reference is ``processing`` on its first read and ``done`` after. The map's walk placement is
    pending (``walks_placing`` 1) for ``placing_reads`` listings after labelling, then the walk is placed,
    unless ``job_fails``: then nothing is pending and the walk stays ``alone``.
    """

    def __init__(self, placing_reads: int = 2, *, job_fails: bool = False) -> None:
        self.placing_reads, self.job_fails = placing_reads, job_fails
        self.reads: dict[int, int] = {}
        self.listings: list[dict[str, str]] = []

    def placed(self) -> bool:
        return not self.job_fails and len(self.listings) > self.placing_reads

    def listing(self, params: dict[str, str]) -> dict[str, Any]:
        self.listings.append(params)
        labelled = all(self.reads.get(i, 0) >= 2 for i in (11, 12, 13))
        placement = "sequence" if self.placed() else "alone"
        references = [_reference(11, "done", placement), _reference(12, "done", placement)]
        references.append(_reference(13, "done", "alone", sequence_id=None))
        references = [r for r in references if r["id"] > int(params["after_id"])][: int(params["limit"])]
        pending = labelled and not self.job_fails and not self.placed()
        return {
            "map_id": 1,
            "references": references,
            "total": 3,
            "counts": {"queued": 0, "processing": 0 if labelled else 1, "done": 3 if labelled else 2, "failed": 0},
            "walks_placing": 1 if pending else 0,
            "next_after_id": None,
            "attribution": "© OSM",
        }

    def __call__(self, request: httpx.Request) -> httpx.Response:
        path = request.url.path
        if request.method == "POST":
            reference_id = next(11 + i for i, n in enumerate(NAMES) if f'filename="{n}"'.encode() in request.content)
            accepted = {"id": reference_id, "map_id": 1, "job_id": reference_id, "status": "queued", "sha256": "ab"}
            return httpx.Response(202, json=accepted)
        if path == "/v1/maps/1":
            return httpx.Response(200, json=MOCK_MAP)
        if path == "/v1/maps/1/references":
            return httpx.Response(200, json=self.listing(dict(request.url.params)))
        reference_id = int(path.rsplit("/", 1)[1])
        self.reads[reference_id] = self.reads.get(reference_id, 0) + 1
        status = "done" if self.reads[reference_id] >= 2 else "processing"
        return httpx.Response(200, json=_reference(reference_id, status, "alone"))


def _ingest(folder: Path, service: MockService, wait: WaitFor, poll_s: float = 0.0, **options: Any) -> IngestReport:
    for i, name in enumerate(NAMES):
        photo(folder / name, INSIDE_HELSINKI[i], seed=20 + i)
    return ingest_folder(
        folder,
        1,
        IngestOptions(url="http://mock", api_key=None, wait=wait, poll_s=poll_s, **options),
        transport=httpx.MockTransport(service),
        console=Console(file=io.StringIO()),
    )


def test_wait_returns_once_the_walks_are_placed(tmp_path: Path) -> None:
    service = MockService(placing_reads=2)
    report = _ingest(tmp_path, service, "placed")
    assert report.placement is not None and report.placement.done
    assert (report.placement.walks, report.placement.placed, report.placement.unplaced) == (1, 1, ())
    # Read until walks_placing was 0, then once more for the poses as they stand after it.
    assert len(service.listings) == service.placing_reads + 2
    assert all(p["after_id"] == "10" and p["limit"] == "500" for p in service.listings)
    assert report.exit_code == 0 and report.as_json()["placement"]["walks_placing"] == 0
    out = io.StringIO()
    print_summary(report, Console(file=out, width=200))
    assert "walks of these photos placed" in out.getvalue() and "every pose is final" in out.getvalue()


def test_wait_labelled_returns_before_placement(tmp_path: Path) -> None:
    service = MockService()
    report = _ingest(tmp_path, service, "labelled")
    assert report.labelling_counts() == {"done": 3} and report.placement is None
    assert service.listings == [] and report.exit_code == 0
    out = io.StringIO()
    print_summary(report, Console(file=out, width=200))
    assert "may still move" in out.getvalue()


def test_a_walk_left_unplaced_fails_the_run(tmp_path: Path) -> None:
    report = _ingest(tmp_path, MockService(job_fails=True), "placed")
    assert report.placement is not None and report.placement.unplaced == (WALK,)
    assert report.exit_code == 1
    out = io.StringIO()
    print_summary(report, Console(file=out, width=200))
    assert "1 walk(s) were not placed jointly" in out.getvalue() and WALK in out.getvalue()


def test_the_wait_timeout_covers_placement(tmp_path: Path) -> None:
    report = _ingest(tmp_path, MockService(placing_reads=10**9), "placed", poll_s=0.05, wait_timeout_s=0.5)
    assert report.wait_timed_out and report.placement is None and report.exit_code == 1
    assert json.loads(json.dumps(report.as_json()))["wait_for"] == "placed"


@pytest.mark.parametrize(
    ("args", "expected"),
    [([], None), (["--wait"], "placed"), (["--wait", "labelled"], "labelled"), (["--wait", "placed"], "placed")],
)
def test_the_command_line_reads_the_wait_mode(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], expected: str | None
) -> None:
    seen: dict[str, Any] = {}

    def fake_ingest(folder: Path, map_id: int, options: IngestOptions, **_: Any) -> IngestReport:
        seen.update(vars(options))
        return IngestReport(url=options.url, map_id=map_id, map_name="mock")

    monkeypatch.setattr(ingest_module, "ingest_folder", fake_ingest)
    result = CliRunner().invoke(app, ["ingest", str(tmp_path), "--map", "1", *args, "--url", "http://mock"])
    assert result.exit_code == 0, result.output
    assert seen["wait"] == expected


@pytest.mark.parametrize("args", [["--wait", "soon"], ["labelled"], ["--wait", "labelled", "placed"]])
def test_a_wrong_wait_mode_is_a_usage_error(tmp_path: Path, args: list[str]) -> None:
    result = CliRunner().invoke(app, ["ingest", str(tmp_path), "--map", "1", *args, "--url", "http://127.0.0.1:9"])
    assert result.exit_code == 2 and "--wait" in result.output, result.output
    assert "cannot reach the service" not in result.output  # refused before anything is sent
