"""What :mod:`bench_track` reads of a world and how it sums up its tracks (pure: importable by the tests)."""

from __future__ import annotations

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
