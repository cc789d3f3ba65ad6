"""The track stage's entry, :func:`locate_track`: the frames of a walk of query photos, in order, to their poses.

Each frame is answered alone by the query stage (its own evidence and priors), then the track's smoother
(:mod:`geoloc.localize.track.smoother`) places the frames jointly. A frame a relative pose joins to the track gets
the placed pose as its new rank 1 (``source="track"``; radius from the graph's marginal covariance; probability
its own rank 1's, or 1 when it had none), its own poses after it; a frame nothing joins keeps its own answer.
Positions are local metres of ``city_map.frame``; yaws are local bearings (deg), as in the query stage.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from geoloc.core.context import MethodContext
from geoloc.localize.grid import PositionPrior
from geoloc.localize.query import geolocate
from geoloc.localize.query.answer import AnswerPose, QueryAnswer
from geoloc.localize.query.config import QueryConfig
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.sequence.placement import PlacedPose
from geoloc.localize.store import ReferenceStore
from geoloc.localize.track.smoother import FrameEvidence, TrackOptions, radius_90_m, smooth_track
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import PhotoEvidence


@dataclass(frozen=True)
class TrackFrame:
    """One photo of a track with what a query carries: its analysed evidence and optional priors.

    capture_time_s: seconds since the epoch from the photo's EXIF, None when unknown.
    """

    photo: Photo
    evidence: PhotoEvidence
    position_prior: PositionPrior | None = None
    heading_prior: HeadingPrior | None = None
    capture_time_s: float | None = None


@dataclass
class FrameAnswer:
    """A frame's answer: ``answer.poses[0]`` is its pose in the track.

    alone: the frame's own rank-1 pose before the track joined it (None when it had none). outlier: the
    track disagrees with the frame's own evidence (e.g. a photo from elsewhere); its pose is then the track's.
    """

    answer: QueryAnswer
    alone: AnswerPose | None
    outlier: bool = False


@dataclass
class TrackAnswer:
    """One :class:`FrameAnswer` per frame, in the frames' order; ``search``: what the track stage did."""

    frames: list[FrameAnswer]
    search: dict[str, Any] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)


def _track_answer(answer: QueryAnswer, pose: PlacedPose, outlier: bool) -> FrameAnswer:
    """A frame's answer with its placed pose as rank 1 (module docstring)."""
    alone = answer.poses[0] if answer.poses else None
    if pose.n_edges == 0:
        return FrameAnswer(answer=answer, alone=alone, outlier=outlier)
    placed = AnswerPose(
        rank=1,
        x_m=pose.x_m,
        y_m=pose.y_m,
        yaw_deg=pose.yaw_deg,
        probability=alone.probability if alone is not None else 1.0,
        uncertainty_radius_m=radius_90_m(pose.position_covariance),
        source="track",
        likelihood=alone.likelihood if alone is not None else float("nan"),
        inliers=alone.inliers if alone is not None else 0,
    )
    others = [replace(p, rank=p.rank + 1) for p in answer.poses]
    return FrameAnswer(answer=replace(answer, poses=[placed, *others]), alone=alone, outlier=outlier)


def locate_track(
    city_map: CityMap,
    frames: Sequence[TrackFrame],
    store: ReferenceStore,
    vocabulary: Vocabulary,
    config: QueryConfig = QueryConfig(),
    *,
    top_n: int = 10,
    context: MethodContext,
    options: TrackOptions | None = None,
) -> TrackAnswer:
    """Locate the frames of one track (in frame order) against the references of ``store`` (module docstring).

    options: the smoother's tuning (default :class:`TrackOptions`). ``search``: ``smoother`` ("gtsam"),
    ``edges`` (relative poses kept), ``joined`` (frames an edge joins), ``outliers`` (flagged frames' indices).
    ``timings_ms``: ``frames`` (answering each alone), ``smoother``, ``total``.
    """
    t0 = time.perf_counter()
    answers = [
        geolocate(
            city_map,
            frame.photo,
            frame.evidence,
            store,
            vocabulary,
            config,
            position_prior=frame.position_prior,
            heading_prior=frame.heading_prior,
            top_n=top_n,
            context=context,
        )
        for frame in frames
    ]
    t1 = time.perf_counter()
    evidence = [
        FrameEvidence(f.photo, f.evidence, f.position_prior, f.heading_prior, a.poses[0] if a.poses else None)
        for f, a in zip(frames, answers, strict=True)
    ]
    smoothed = smooth_track(city_map, evidence, options or TrackOptions())
    out = [
        _track_answer(a, pose, flag) for a, pose, flag in zip(answers, smoothed.poses, smoothed.outliers, strict=True)
    ]
    t2 = time.perf_counter()
    search = {
        "smoother": "gtsam",
        "edges": len(smoothed.edges),
        "joined": sum(pose.n_edges > 0 for pose in smoothed.poses),
        "outliers": [k for k, flag in enumerate(smoothed.outliers) if flag],
    }
    timings = {"frames": 1e3 * (t1 - t0), "smoother": 1e3 * (t2 - t1), "total": 1e3 * (t2 - t0)}
    return TrackAnswer(frames=out, search=search, timings_ms=timings)
