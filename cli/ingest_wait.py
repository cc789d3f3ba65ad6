"""``geoloc ingest --wait``: until the new references are labelled, then until the map's walks are placed.

A reference's pose is final once it is labelled (``done``) and, when it belongs to a walk, once the walk's
joint placement ran (``placement: sequence``; the map's ``walks_placing`` 0). ``--wait`` (``placed``) waits
for both; ``--wait labelled`` stops after labelling, as ``--wait`` did before, while walks may still move.

Labelling is polled per new reference (``GET /v1/references/{id}``, a bar of references labelled); placement
from the map's reference list (``GET /v1/maps/{id}/references``: ``counts``, ``walks_placing`` and this run's
references, a bar of walks placed). Walks are counted as the service groups them by a stated sequence id (the
form's ``sequence``, Mapillary's); a walk told only by one camera's capture times is waited for all the same
(``walks_placing``) but not counted, since the API does not name the camera.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from cli.photo_files import FileResult
from client import ApiError, Client, Reference, ReferenceList, ServiceUnreachableError
from client.retry import TRANSIENT_STATUSES as RETRY_STATUSES

WaitFor = Literal["placed", "labelled"]
WAIT_MODES: tuple[WaitFor, ...] = ("placed", "labelled")
"""What ``--wait`` waits for: walks placed (the default: every pose final), or labelling only."""
FINAL_REFERENCE_STATES = frozenset({"done", "failed"})
PAGE = 500
"""References per listing request while waiting for placement (the API's largest page)."""


def progress_bar(console: Console) -> Progress:
    """The bar every step of ``geoloc ingest`` shows: what, how many of how many, time, a status."""
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


def _left_s(deadline: float | None) -> float:
    """Seconds to ``deadline`` (a ``time.monotonic`` value; None: no deadline)."""
    return float("inf") if deadline is None else deadline - time.monotonic()


def wait_for_labelling(
    client: Client, results: list[FileResult], *, deadline: float | None, poll_s: float, console: Console
) -> bool:
    """Poll the new references until each is ``done`` or ``failed``; False when ``deadline`` passed first."""
    pending = {r.reference_id: r for r in results if r.outcome == "accepted" and r.reference_id is not None}
    with progress_bar(console) as progress:
        task = progress.add_task("labelling", total=len(pending), status="")
        while pending:
            for reference_id, result in list(pending.items()):
                try:
                    reference = client.get_reference(reference_id)
                    result.final_status, result.final_error = reference.status, reference.error
                except ServiceUnreachableError:
                    continue  # keep waiting: the service may come back
                except ApiError as exc:
                    if (
                        exc.status < 500 and exc.status not in RETRY_STATUSES
                    ):  # deleted meanwhile, or the key cannot read
                        result.final_status = "failed"
                        result.final_error = f"cannot read the reference: {exc.status} {exc.code}: {exc.message}"
                if result.final_status in FINAL_REFERENCE_STATES:
                    del pending[reference_id]
                    progress.update(task, advance=1)
            statuses = Counter(r.final_status for r in results if r.outcome == "accepted" and r.final_status)
            progress.update(task, status=" ".join(f"{k} {v}" for k, v in sorted(statuses.items())))
            if not pending:
                break
            if _left_s(deadline) <= 0:
                return False
            time.sleep(poll_s)
    return True


@dataclass
class Placement:
    """What the placement wait found: this run's walks, those placed, and the map's state when it ended."""

    walks: int = 0
    placed: int = 0
    walks_placing: int = 0
    labelling: int = 0
    unplaced: tuple[str, ...] = ()
    """Sequence ids of this run's walks not placed once the map had nothing left to place."""
    error: str | None = None
    """Why the map's references could not be read (deleted meanwhile, the key cannot read): the wait stopped."""

    @property
    def done(self) -> bool:
        """Whether every pose of the map was final when the wait ended."""
        return self.error is None and self.walks_placing == 0 and self.labelling == 0


def count_walks(references: Iterable[Reference]) -> tuple[int, int, tuple[str, ...]]:
    """Walks (two or more labelled references with one sequence id), those placed, and the others' ids."""
    walks: dict[str, list[Reference]] = {}
    for reference in references:
        if reference.status == "done" and reference.sequence_id:
            walks.setdefault(reference.sequence_id, []).append(reference)
    walks = {sequence: members for sequence, members in walks.items() if len(members) >= 2}
    unplaced = tuple(sorted(s for s, members in walks.items() if any(r.placement != "sequence" for r in members)))
    return len(walks), len(walks) - len(unplaced), unplaced


def read_placement(client: Client, map_id: int, reference_ids: set[int]) -> Placement:
    """The map's state (first page) and this run's references (the pages that hold them) as one reading."""
    first: ReferenceList | None = None
    mine: list[Reference] = []
    after = min(reference_ids) - 1 if reference_ids else 0
    while True:
        page = client.list_references(map_id, after_id=after, limit=PAGE if reference_ids else 1)
        first = first or page
        mine += [r for r in page.references if r.id in reference_ids]
        if page.next_after_id is None or not reference_ids or page.next_after_id >= max(reference_ids):
            break
        after = page.next_after_id
    walks, placed, unplaced = count_walks(mine)
    return Placement(walks, placed, first.walks_placing, first.labelling, unplaced)


def wait_for_placement(
    client: Client, map_id: int, results: list[FileResult], *, deadline: float | None, poll_s: float, console: Console
) -> Placement | None:
    """Poll until the map has nothing to label or place; what was found, or None when ``deadline`` passed first.

    The references read when the map is first seen placed may predate the last placement's commit, so
    they are read once more then (nothing changes after it but for new uploads).
    """
    ids = {r.reference_id for r in results if r.outcome in ("accepted", "present") and r.reference_id is not None}
    with progress_bar(console) as progress:
        task = progress.add_task("placing walks", total=None, status="")
        while True:
            try:
                found = read_placement(client, map_id, ids)
                if found.done:
                    found = read_placement(client, map_id, ids)
            except ServiceUnreachableError:
                found = None  # keep waiting: the service may come back
            except ApiError as exc:
                if exc.status < 500 and exc.status not in RETRY_STATUSES:  # the map deleted, or the key cannot read
                    return Placement(error=f"cannot read the map's references: {exc.status} {exc.code}: {exc.message}")
                found = None
            if found is not None:
                status = f"walk placements pending {found.walks_placing}"
                if found.labelling:
                    status += f", references being labelled {found.labelling}"
                progress.update(task, total=found.walks, completed=found.placed, status=status)
                if found.done:
                    return found
            if _left_s(deadline) <= 0:
                return None
            time.sleep(min(poll_s, max(_left_s(deadline), 0.0)))
