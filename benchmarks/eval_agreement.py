"""Whether the API answered as ``geoloc eval world`` did: the evaluation measures what ships only if it did.

The benchmarks that go through the API (``bench_track.py``, ``bench_service.py``) take ``--compare-eval EVAL.json``,
the evaluation's JSON of the same world, and count the photos whose rank-1 error is the evaluation's. Errors, not
poses, are compared: the evaluation's JSON keeps each answer's error against the manifest, not its pose.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable
from typing import Any

SAME_ANSWER_M = 0.25
SAME_ANSWER_SHARE = 0.02
"""Two answers of a photo are the same when their errors differ by at most the larger of these (m, share of the
error): the API's pose comes back in WGS84 and is measured there, the evaluation's in the map's local metres, which
moves an error by a few centimetres (2 % at 500 m)."""


def agreement(pairs: Iterable[tuple[Hashable, float | None, float]]) -> dict[str, Any]:
    """How many photos the API answered as the evaluation did.

    pairs: (photo, API error m or None when it answered nothing, evaluation error m). Returns ``photos`` compared,
    ``same`` (within :data:`SAME_ANSWER_M` or :data:`SAME_ANSWER_SHARE`) and ``differ``, the others' pairs.
    """
    rows = list(pairs)
    differ = [
        (key, api, theirs)
        for key, api, theirs in rows
        if not (api is not None and abs(api - theirs) <= max(SAME_ANSWER_M, SAME_ANSWER_SHARE * theirs))
    ]
    return {"photos": len(rows), "same": len(rows) - len(differ), "differ": differ}


def track_agreement(tracks: dict[str, dict[str, Any]], evaluation: dict[str, Any]) -> dict[str, Any]:
    """:func:`agreement` of ``bench_track``'s frames with the evaluation's track frames.

    tracks: ``errors_m`` per track, in frame order; the evaluation's frames answered with their GPS prior
    (``tracks.gps.per_frame``). Photos are (track, index).
    """
    theirs = {(int(r["track"]), int(r["index"])): float(r["error_m"]) for r in evaluation["tracks"]["gps"]["per_frame"]}
    return agreement(
        ((int(track), index), api, theirs[(int(track), index)])
        for track, row in sorted(tracks.items(), key=lambda item: int(item[0]))
        for index, api in enumerate(row["errors_m"])
        if (int(track), index) in theirs
    )


def query_agreement(
    errors_m: dict[str, float | None], evaluation: dict[str, Any], run: str = "ours/gps"
) -> dict[str, Any]:
    """:func:`agreement` of single queries' API errors with the evaluation's.

    errors_m: by photo name without its suffix; run: the evaluation's (``ours/gps``: each photo's EXIF GPS and
    compass, as the service reads them by default). A photo the evaluation did not answer alone is left out.
    """
    theirs = {str(r["name"]): float(r["error_m"]) for r in evaluation["runs"][run]["per_query"]}
    return agreement((name, api, theirs[name]) for name, api in sorted(errors_m.items()) if name in theirs)
