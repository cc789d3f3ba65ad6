"""What :mod:`bench_track` reads of a world and how it sums up its tracks (pure: importable by the tests)."""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Any

from geoloc.evaluation.tracks import world_tracks as tracks_of
from geoloc.sim.world import World

MUST_HOLD_S = 6.0
"""Issue 20: a 10-frame track answered within this many seconds end to end on the 2-core machine."""


def world_tracks(world: World) -> dict[int, list[tuple[Path, tuple[float, float]]]]:
    """Per query track, its frames in order as (photo, true (lat, lon)).

    The tracks are the evaluation's (:func:`geoloc.evaluation.tracks.world_tracks`).
    """
    return {
        track: [(image.path, (image.record["pose"]["lat"], image.record["pose"]["lon"])) for image in frames]
        for track, frames in tracks_of(world.queries).items()
    }


def track_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The tracks' wall seconds and their frames' errors summed up.

    rows: per track ``wall_s`` and ``errors_m`` (None: a frame without a pose, counted as outside). Returns the
    median and largest wall time, ``passes`` (the median within :data:`MUST_HOLD_S`), and the frames' shares within
    1 / 5 / 10 m.
    """
    walls = [row["wall_s"] for row in rows]
    errors = [e for row in rows for e in row["errors_m"]]
    located = [e for e in errors if e is not None]
    return {
        "wall_s_median": round(statistics.median(walls), 2),
        "wall_s_max": round(max(walls), 2),
        "passes": statistics.median(walls) <= MUST_HOLD_S,
        "frames": len(errors),
        **{f"within_{d}m": round(sum(e <= d for e in located) / len(errors), 3) for d in (1, 5, 10)},
    }


SAME_ANSWER_M = 0.25
SAME_ANSWER_SHARE = 0.02
"""Two answers of a frame are the same when their errors differ by at most the larger of these (m, share of the
error): the API's pose comes back in WGS84 and is measured there, the evaluation's in the map's local metres, which
moves an error by a few centimetres (2 % at 500 m)."""


def agreement_with_evaluation(tracks: dict[str, dict[str, Any]], evaluation: dict[str, Any]) -> dict[str, Any]:
    """How many frames the API answered as ``geoloc eval world`` did (its JSON), both with each frame's GPS prior.

    tracks: the benchmark's per-track rows (``errors_m`` in frame order) by track number; evaluation: the JSON of
    ``geoloc eval world`` on the same world (``tracks.gps.per_frame``). Returns ``frames`` compared, ``same`` (the
    errors within :data:`SAME_ANSWER_M` or :data:`SAME_ANSWER_SHARE`) and ``differ``: (track, index, API error,
    evaluation error) of the others.
    """
    by_frame = {
        (int(r["track"]), int(r["index"])): float(r["error_m"]) for r in evaluation["tracks"]["gps"]["per_frame"]
    }
    differ = []
    frames = 0
    for track, row in sorted(tracks.items(), key=lambda item: int(item[0])):
        for index, api in enumerate(row["errors_m"]):
            theirs = by_frame.get((int(track), index))
            if theirs is None:
                continue
            frames += 1
            mine = math.inf if api is None else float(api)
            if not (mine == theirs or abs(mine - theirs) <= max(SAME_ANSWER_M, SAME_ANSWER_SHARE * theirs)):
                differ.append((int(track), index, api, theirs))
    return {"frames": frames, "same": frames - len(differ), "differ": differ}
