"""What ``geoloc ingest`` reports: counts per outcome, the files not accepted and why, the exit code."""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass, field
from typing import Any

from rich.console import Console
from rich.table import Table

from cli.ingest_wait import Placement, WaitFor
from cli.photo_files import OUTCOMES, FileResult


@dataclass
class IngestReport:
    """Results of a run: one :class:`FileResult` per file, plus what ``--wait`` found."""

    url: str
    map_id: int
    map_name: str | None = None
    files: list[FileResult] = field(default_factory=list)
    wait_for: WaitFor | None = None
    """What ``--wait`` waited for (``placed``, ``labelled``); None without ``--wait``."""
    wait_timed_out: bool = False
    placement: Placement | None = None
    """With ``--wait`` (``placed``): the walks found and placed, once the map had nothing left to place."""

    @property
    def waited(self) -> bool:
        """Whether the run waited (``--wait``)."""
        return self.wait_for is not None

    @property
    def unplaced_walks(self) -> int:
        """Walks of this run left unplaced (or a placement wait stopped by an error) once the map was idle."""
        if self.placement is None:
            return 0
        return len(self.placement.unplaced) + (self.placement.error is not None)

    def counts(self) -> dict[str, int]:
        """Files per outcome (every outcome present, in summary order)."""
        found = Counter(f.outcome for f in self.files)
        return {outcome: found.get(outcome, 0) for outcome in OUTCOMES}

    def labelling_counts(self) -> dict[str, int]:
        """With ``--wait``: references per final status (``done``, ``failed``, or still pending)."""
        return dict(Counter(f.final_status or "pending" for f in self.files if f.outcome == "accepted"))

    @property
    def exit_code(self) -> int:
        """1 when a photo failed (with ``--wait``: or its labelling failed, a walk was not placed, the wait ran out)."""
        failed = self.counts()["failed"] > 0
        if self.waited:
            labels = self.labelling_counts()
            failed = failed or self.wait_timed_out or labels.get("failed", 0) > 0 or self.unplaced_walks > 0
        return 1 if failed else 0

    def as_json(self) -> dict[str, Any]:
        """The ``--json`` report: summary, exit code, every file (and the labelling with ``--wait``)."""
        out: dict[str, Any] = {
            "url": self.url,
            "map_id": self.map_id,
            "map_name": self.map_name,
            "summary": self.counts(),
            "exit_code": self.exit_code,
            "files": [asdict(f) for f in self.files],
        }
        if self.waited:
            out["wait_for"] = self.wait_for
            out["labelling"] = self.labelling_counts()
            out["wait_timed_out"] = self.wait_timed_out
        if self.placement is not None:
            out["placement"] = asdict(self.placement)
        return out


def _first_line(text: str | None, limit: int = 160) -> str:
    lines = [line for line in (text or "").strip().splitlines() if line.strip()]
    line = lines[-1].strip() if lines else ""
    return line if len(line) <= limit else line[: limit - 1] + "…"


def print_summary(report: IngestReport, console: Console, *, max_rows: int = 100) -> None:
    """Print the counts per outcome, the files not accepted (or not labelled) and why, and what it means."""
    console.print(f"geoloc ingest: map {report.map_id} ({report.map_name}) at {report.url}", highlight=False)
    console.print(_outcome_table(report))
    listed = [f for f in report.files if f.outcome in ("rejected", "failed", "skipped", "duplicate")]
    if report.waited:
        listed += [f for f in report.files if f.outcome == "accepted" and f.final_status != "done"]
    if listed:
        console.print(_reasons_table(listed[:max_rows]))
        if len(listed) > max_rows:
            console.print(f"... and {len(listed) - max_rows} more (use --json for every file)")
    console.print("\n".join(_notes(report)))


def _outcome_table(report: IngestReport) -> Table:
    """Files per outcome, the HTTP status and error code behind rejections and failures, labelling."""
    counts = report.counts()
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
    if report.placement is not None:
        table.add_row("walks of these photos placed", f"{report.placement.placed} of {report.placement.walks}")
    return table


def _reasons_table(listed: list[FileResult]) -> Table:
    """One row per file that was not accepted (or not labelled), with the reason."""
    details = Table(title="files that were not accepted (or not labelled), and why", title_justify="left")
    details.add_column("file", overflow="fold")
    details.add_column("outcome")
    details.add_column("reason", overflow="fold")
    for f in listed:
        if f.outcome == "accepted":
            details.add_row(f.path, f"labelling {f.final_status or 'pending'}", _first_line(f.final_error))
        else:
            details.add_row(f.path, f.outcome, f.reason or "")
    return details


def _notes(report: IngestReport) -> list[str]:
    """What the counts mean for the user, ending with the exit code."""
    counts = report.counts()
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
    placement = report.placement
    if report.waited and report.wait_timed_out:
        what = "labelled" if report.wait_for == "labelled" else "labelled and every walk placed"
        notes.append(f"stopped waiting before every new reference was {what} (--wait-timeout).")
    elif placement is not None and placement.error is not None:
        notes.append(f"stopped waiting for the walks to be placed: {placement.error}")
    elif placement is not None and placement.unplaced:
        notes.append(
            f"{len(placement.unplaced)} walk(s) were not placed jointly (the map's walk placement job failed; "
            f"the service's log says why): {', '.join(placement.unplaced)}; their poses are their own labels'."
        )
    elif placement is not None:
        notes.append("every pose is final: the new references are labelled and the map's walks placed.")
    elif report.wait_for == "labelled":
        notes.append("labelled; poses of references in walks may still move until the map's walks_placing is 0.")
    notes.append(f"exit code {report.exit_code}")
    return notes
