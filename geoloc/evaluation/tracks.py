"""The evaluation of query tracks (issue 20): each track answered by the track stage, as the workers answer it.

Every track of a world (its frames: query photos with ``track`` and ``index`` in the manifest) goes through
:func:`geoloc.localize.track.locate_track` once per prior: ``gps`` (each frame's EXIF GPS, radius
:func:`contracts.queries.gps_prior_radius_m` of its stated accuracy, and its compass, as the service reads a
photo) and ``none`` (no prior at all). The stage answers each frame alone first, so the same frames answered one
by one come from the same run (a frame's ``alone`` pose) and are reported beside the track's.

Figures (per prior): per frame, for the track's rank 1 and for the frame alone, the shares within 1 / 5 / 10 m
and with heading within 2 / 5 deg, the median error, the share of the track's 90 % radius holding the truth;
the ratio of the two within-1-m shares; per track the same within 1 / 5 m; the stage's time per track; the
share of frames flagged as outliers.

Outlier injection (``inject_outliers``): each track answered again with one frame (index ``L // 2``) replaced by
a frame of another track (the next one, same index: a photo from elsewhere in the city, with its own EXIF GPS
and compass, as a wrong photo would carry them). Reported: how many of the replaced frames are flagged, the
others' flags (false alarms) and the others' figures.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np

from geoloc.core.context import MethodContext
from geoloc.core.geo import angle_difference_deg
from geoloc.evaluation.queries import photo_priors
from geoloc.evaluation.references import LabelledWorld
from geoloc.evaluation.summaries import mean_or_none
from geoloc.localize.query import QueryConfig
from geoloc.localize.query.answer import AnswerPose
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.track import TrackFrame, locate_track
from geoloc.maps import CityMap
from geoloc.sim.world import World, WorldImage

PRIORS = ("gps", "none")


def world_tracks(queries: list[WorldImage]) -> dict[int, list[WorldImage]]:
    """The world's tracks: their frames (query images with a ``track``) by track number, in index order."""
    tracks: dict[int, list[WorldImage]] = defaultdict(list)
    for image in queries:
        if "track" in image.record:
            tracks[int(image.record["track"])].append(image)
    return {t: sorted(frames, key=lambda im: int(im.record["index"])) for t, frames in sorted(tracks.items())}


def _errors(pose: AnswerPose | None, truth: WorldImage) -> tuple[float, float]:
    """(position error m, heading error deg) of a pose against an image's true pose; inf when there is none."""
    if pose is None:
        return math.inf, 180.0
    p = truth.pose
    return math.hypot(pose.x_m - p.x_m, pose.y_m - p.y_m), angle_difference_deg(pose.yaw_deg, p.yaw_deg)


def _block(rows: list[dict[str, Any]], prefix: str) -> dict[str, Any]:
    """Shares within 1 / 5 / 10 m and 2 / 5 deg, and the median, of the rows' ``<prefix>error_m``."""
    errors = np.array([r[f"{prefix}error_m"] for r in rows], dtype=float)
    heading = np.array([r[f"{prefix}heading_error_deg"] for r in rows], dtype=float)
    if not len(errors):
        return {"n": 0}
    return {
        "n": len(errors),
        "median_error_m": round(float(np.median(errors)), 2),
        **{f"within_{m}m": round(float(np.mean(errors <= m)), 4) for m in (1, 5, 10)},
        **{f"heading_within_{d}deg": round(float(np.mean(heading <= d)), 4) for d in (2, 5)},
    }


def _answer_track(
    frames: list[WorldImage],
    photos: list[WorldImage],
    city: CityMap,
    labelled: LabelledWorld,
    vocabulary: Vocabulary,
    config: QueryConfig,
    prior: str,
    context: MethodContext,
) -> tuple[list[dict[str, Any]], dict[str, float]]:
    """Answer one track whose frame k shows ``photos[k]`` (a replaced frame shows another); rows and seconds.

    seconds: the stage's ``total``, ``frames`` (answering each frame alone) and ``smoother``.
    """
    track_frames = []
    for image in photos:
        photo, evidence = labelled.queries[image.name]
        position_prior, heading_prior = photo_priors(photo, city, prior)
        track_frames.append(TrackFrame(photo, evidence, position_prior, heading_prior))
    answer = locate_track(city, track_frames, labelled.store, vocabulary, config, context=context)
    rows = []
    for k, (original, shown, frame) in enumerate(zip(frames, photos, answer.frames, strict=True)):
        # A frame's truth is the photo it shows (a replaced frame's is the other track's).
        error, heading = _errors(frame.answer.poses[0] if frame.answer.poses else None, shown)
        alone_error, alone_heading = _errors(frame.alone, shown)
        best = frame.answer.poses[0] if frame.answer.poses else None
        rows.append(
            {
                "name": shown.name,
                "track": int(frames[0].record["track"]),
                "index": k,
                "replaced": shown is not original,
                "error_m": round(error, 2),
                "heading_error_deg": round(heading, 2),
                "alone_error_m": round(alone_error, 2),
                "alone_heading_error_deg": round(alone_heading, 2),
                "source": best.source if best else None,
                "alone_source": frame.alone.source if frame.alone else None,
                "inside_radius": bool(best is not None and error <= best.uncertainty_radius_m),
                "outlier": frame.outlier,
            }
        )
    return rows, {key: answer.timings_ms[key] / 1e3 for key in ("total", "frames", "smoother")}


def evaluate_tracks(
    world: World,
    city: CityMap,
    labelled: LabelledWorld,
    vocabulary: Vocabulary,
    config: QueryConfig,
    say: Callable[[str], None],
    context: MethodContext,
    *,
    inject_outliers: bool = False,
    priors: tuple[str, ...] = PRIORS,
) -> dict[str, Any]:
    """The module docstring's figures for every track of ``world`` (its frames analysed in ``labelled.queries``).

    priors: which of :data:`PRIORS` to answer the tracks with (each a key of the result).
    """
    tracks = world_tracks(world.queries)
    result: dict[str, Any] = {"n_tracks": len(tracks), "frames": sum(len(f) for f in tracks.values())}
    numbers = list(tracks)
    for prior in priors:
        rows, seconds = [], []
        for t, frames in tracks.items():
            track_rows, s = _answer_track(frames, frames, city, labelled, vocabulary, config, prior, context)
            rows += track_rows
            seconds.append(s)
            figures = f"{_block(track_rows, '')} alone {_block(track_rows, 'alone_')}"
            say(f"  track {t} [{prior}]: {figures} ({s['total']:.1f} s)")
        result[prior] = _summary(rows, seconds)
    if inject_outliers and len(tracks) > 1:
        rows = []
        for i, t in enumerate(numbers):
            frames, other = tracks[t], tracks[numbers[(i + 1) % len(numbers)]]
            k = len(frames) // 2
            photos = [*frames[:k], other[min(k, len(other) - 1)], *frames[k + 1 :]]
            rows += _answer_track(frames, photos, city, labelled, vocabulary, config, "gps", context)[0]
        replaced = [r for r in rows if r["replaced"]]
        kept = [r for r in rows if not r["replaced"]]
        result["outlier_injection"] = {
            "prior": "gps",
            "replaced_flagged": mean_or_none([float(r["outlier"]) for r in replaced]),
            "others_flagged": mean_or_none([float(r["outlier"]) for r in kept]),
            "others": _block(kept, ""),
            "per_frame": rows,
        }
    return result


def _summary(rows: list[dict[str, Any]], seconds: list[dict[str, float]]) -> dict[str, Any]:
    """One prior's figures (module docstring) from its per-frame rows and the stage's seconds per track.

    ``seconds_per_track``: the median and max of the total, and the medians of its split (``frames_median``:
    answering each frame alone, evidence already analysed; ``smoother_median``: motions, edges and the graph).
    """
    totals = [s["total"] for s in seconds]
    track, alone = _block(rows, ""), _block(rows, "alone_")
    by_track: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_track[row["track"]].append(row)
    return {
        "track": track,
        "alone": alone,
        "within_1m_ratio": (
            round(track["within_1m"] / alone["within_1m"], 3) if rows and alone["within_1m"] > 0 else None
        ),
        "radius_holds_truth": mean_or_none([float(r["inside_radius"]) for r in rows]),
        "outlier_share": mean_or_none([float(r["outlier"]) for r in rows]),
        "per_track": {
            str(t): {"track": _block(r, ""), "alone": _block(r, "alone_")} for t, r in sorted(by_track.items())
        },
        "seconds_per_track": {
            "median": round(float(np.median(totals)), 2) if seconds else None,
            "max": round(float(np.max(totals)), 2) if seconds else None,
            **{
                f"{key}_median": round(float(np.median([s[key] for s in seconds])), 2) if seconds else None
                for key in ("frames", "smoother")
            },
        },
        "per_frame": rows,
    }


def track_summary_lines(tracks: dict[str, Any]) -> list[str]:
    """The lines ``geoloc eval world`` prints of :func:`evaluate_tracks`'s result."""
    lines = [f"tracks: {tracks['n_tracks']} tracks, {tracks['frames']} frames"]
    for prior in PRIORS:
        if prior not in tracks:
            continue
        run = tracks[prior]
        for name in ("track", "alone"):
            b = run[name]
            lines.append(
                f"  [{prior}] {name:5s}: within 1/5/10 m {b.get('within_1m')}/{b.get('within_5m')}/"
                f"{b.get('within_10m')}, heading within 2/5 deg {b.get('heading_within_2deg')}/"
                f"{b.get('heading_within_5deg')}, median {b.get('median_error_m')} m"
            )
        lines.append(
            f"  [{prior}] within-1 m ratio track/alone {run['within_1m_ratio']}; outliers flagged "
            f"{run['outlier_share']}; radius holds truth {run['radius_holds_truth']}; s per track "
            f"{run['seconds_per_track']}"
        )
    injection = tracks.get("outlier_injection")
    if injection:
        b = injection["others"]
        lines.append(
            f"  outlier injection: replaced frames flagged {injection['replaced_flagged']}, others flagged "
            f"{injection['others_flagged']}; others within 1/5 m {b.get('within_1m')}/{b.get('within_5m')}, "
            f"heading within 2 deg {b.get('heading_within_2deg')}"
        )
    return lines
