"""Jobs: their kinds, their statuses, the one status mapping, and the typed payloads and results.

A job is a row of the job table (:mod:`db.jobs`) with a kind, a JSON payload and, once done, a JSON result.
The API enqueues the method's two kinds with their payload models (:class:`LabelReferencePayload`,
:class:`LocalizeQueryPayload`); the payload is stored as ``json.dumps(payload.model_dump(mode="json"))``,
the same JSON as before these models existed (``{"reference_id": 3, "map_id": 1}``), so existing databases
and the distributed profile's messages (which carry only the job id) keep working. A worker reads the
payload back with the model registered for the job's kind (:func:`workers.handlers.register`), runs the
handler and stores the :class:`JobResult` it returns the same way.

A reference or a query has its own status column (written by its handler) and a job; what the API reports
for it comes from both, through :func:`reported_status`, the one mapping of job states to the statuses
clients see.
"""

from __future__ import annotations

from typing import Final, Literal, get_args

from pydantic import BaseModel, ConfigDict

JobStatus = Literal["queued", "running", "done", "failed", "cancelled"]
"""A job's state: ``queued`` -> ``running`` (claimed, leased) -> ``done`` | ``failed``, or ``cancelled``."""
JOB_STATUSES: Final[tuple[JobStatus, ...]] = get_args(JobStatus)
FINAL_STATUSES: Final[tuple[JobStatus, ...]] = ("done", "failed", "cancelled")
"""A job in one of these states will not change any more."""

WorkStatus = Literal["queued", "processing", "done", "failed"]
"""The status the API reports for a reference or a query (from its row and its job: :func:`reported_status`)."""
WORK_STATUSES: Final[tuple[WorkStatus, ...]] = get_args(WorkStatus)

LABEL_REFERENCE: Final = "label_reference"
"""Kind of the job the API enqueues for each new reference (payload :class:`LabelReferencePayload`)."""
LOCALIZE_QUERY: Final = "localize_query"
"""Kind of the job the API enqueues for each new query (payload :class:`LocalizeQueryPayload`)."""
PLACE_SEQUENCE: Final = "place_sequence"
"""Kind of the job a labelled reference of a sequence enqueues (payload :class:`PlaceSequencePayload`): the map's
walks placed jointly, in the background, while the references keep being served with their own labels."""
LOCATE_TRACK: Final = "locate_track"
"""Kind of the job the API enqueues for each new track (payload :class:`LocateTrackPayload`): its frames' photos,
which are the track's query rows, located together by the track stage."""

LOAD_MAP: Final = "load_map"
"""Kind of the job the API enqueues for each new map (payload :class:`LoadMapPayload`): the map file parsed
into buildings and facades in the workers, not in the API."""


class JobPayload(BaseModel):
    """Base of job payloads: frozen, unknown fields are errors (a payload is read back by its own model)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    def to_json(self) -> dict[str, object]:
        """The payload as stored in the job table (JSON-ready, fields in declaration order)."""
        return self.model_dump(mode="json")


class JobResult(BaseModel):
    """Base of job results: what a handler returns; stored as the job's ``result`` (its JSON form)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    def to_json(self) -> dict[str, object]:
        """The result as stored in the job table (JSON-ready, fields in declaration order)."""
        return self.model_dump(mode="json")


class LabelReferencePayload(JobPayload):
    """Label reference ``reference_id`` of map ``map_id``."""

    reference_id: int
    map_id: int


class LocalizeQueryPayload(JobPayload):
    """Answer query ``query_id`` on map ``map_id``."""

    query_id: int
    map_id: int


class PlaceSequencePayload(JobPayload):
    """Place the walks of map ``map_id`` that changed; ``reference_id``: the labelled reference that asked."""

    reference_id: int
    map_id: int


class PlaceSequenceResult(JobResult):
    """What placing a map's walks reports on its job.

    walks: the walks placed; references: their references; placed: those stored with a new label (at their jointly
    placed pose, or along a compass their walk trusts); edges: relative poses found; waiting: walks left for later (a
    reference still being labelled).
    """

    reference_id: int
    walks: int
    references: int
    placed: int
    edges: int
    waiting: int


class LoadMapPayload(JobPayload):
    """Parse the stored file of map ``map_id`` into its buildings and facades."""

    map_id: int


class LoadMapResult(JobResult):
    """What parsing a map reports on its job: its buildings and facades (0 when it was deleted meanwhile)."""

    map_id: int
    buildings: int
    facades: int


class LabelReferenceResult(JobResult):
    """What labelling a reference reports on its job: the heading found (deg from north) and buildings seen."""

    reference_id: int
    heading_deg: float
    buildings: int


class LocalizeQueryResult(JobResult):
    """What answering a query reports on its job: how many ranked locations were stored."""

    query_id: int
    locations: int


class LocateTrackPayload(JobPayload):
    """Locate track ``track_id`` of map ``map_id`` (its frames are the queries with that ``track_id``)."""

    track_id: int
    map_id: int


class LocateTrackResult(JobResult):
    """What locating a track reports on its job: its frames, how many got a pose, how many were outliers."""

    track_id: int
    frames: int
    located: int
    outliers: int


def reported_status(
    status: str, error: str | None, job_status: str | None, job_attempts: int = 0, job_error: str | None = None
) -> tuple[WorkStatus, str | None]:
    """The status and error to report for a reference or a query, from its row and its job.

    Parameters
    ----------
    status, error
        The row's own status (``queued``, ``done`` or ``failed``, written by the API and the handler) and error.
    job_status, job_attempts, job_error
        Its job's status, attempts started and last error (``job_status`` None: no job).

    Returns
    -------
    tuple[WorkStatus, str | None]
        A finished row (``done``, ``failed``) reports itself; otherwise a running job is ``processing``, a failed
        or cancelled job fails the row (with the job's error), and a job waiting for a retry shows its last
        error.
    """
    if status in ("done", "failed") or job_status is None:
        return _work_status(status), error
    if job_status == "running":
        return "processing", None
    if job_status in ("failed", "cancelled"):
        return "failed", job_error or f"job {job_status}"
    if job_status == "queued" and job_attempts > 0:
        return "queued", job_error  # waiting for a retry: show the last error
    return _work_status(status), error


_WORK_STATUS: Final[dict[str, WorkStatus]] = {status: status for status in WORK_STATUSES}


def _work_status(status: str) -> WorkStatus:
    """``status`` as a :data:`WorkStatus` (a row holds nothing else)."""
    return _WORK_STATUS[status]
