"""The track stage's entry, :func:`locate_track`: the frames of a walk of query photos, in order, to their poses.

Each frame is answered alone by the query stage (its own evidence and priors); a frame with no position prior is
then answered again near the frames of its track that the map anchors placed (:func:`anchored_priors`), and the
track's smoother
(:mod:`geoloc.localize.track.smoother`) places the frames jointly. A frame a relative pose joins to the track gets
the placed pose as its new rank 1 (``source="track"``; radius from the graph's marginal covariance; probability
its own rank 1's, or 1 when it had none), its own poses after it; a frame nothing joins keeps its own answer.
Positions are local metres of ``city_map.frame``; yaws are local bearings (deg), as in the query stage.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from contracts.answers import TrackSearch
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

    alone: the frame's own rank-1 pose answered alone, with its own priors only (None when it had none), before
    the track's anchored frames (:func:`anchored_priors`) or its smoother helped. outlier: the
    track disagrees with the frame's own evidence (e.g. a photo from elsewhere); its pose is then the track's.
    """

    answer: QueryAnswer
    alone: AnswerPose | None
    outlier: bool = False


@dataclass
class TrackAnswer:
    """One :class:`FrameAnswer` per frame, in the frames' order; ``search``: what the track stage did."""

    frames: list[FrameAnswer]
    search: TrackSearch
    timings_ms: dict[str, float] = field(default_factory=dict)


def _track_answer(answer: QueryAnswer, alone: AnswerPose | None, pose: PlacedPose, outlier: bool) -> FrameAnswer:
    """A frame's answer with its placed pose as rank 1 (module docstring); alone: its rank 1 answered alone."""
    if pose.n_edges == 0:
        return FrameAnswer(answer=answer, alone=alone, outlier=outlier)
    own = answer.poses[0] if answer.poses else None
    placed = AnswerPose(
        rank=1,
        x_m=pose.x_m,
        y_m=pose.y_m,
        yaw_deg=pose.yaw_deg,
        probability=own.probability if own is not None else 1.0,
        uncertainty_radius_m=radius_90_m(pose.position_covariance),
        source="track",
        likelihood=own.likelihood if own is not None else float("nan"),
        inliers=own.inliers if own is not None else 0,
    )
    others = [replace(p, rank=p.rank + 1) for p in answer.poses]
    return FrameAnswer(answer=replace(answer, poses=[placed, *others]), alone=alone, outlier=outlier)


def anchored_priors(
    alone: Sequence[AnswerPose | None], priors: Sequence[PositionPrior | None], options: TrackOptions
) -> list[PositionPrior | None]:
    """Position priors from a track's own anchored answers, for its frames that came with none.

    alone: each frame's own rank-1 pose (None: no answer); priors: each frame's own position prior. A track without
    priors is mostly answered by the likelihood over the whole map, hundreds of metres off, while a frame the map
    anchors answered (source "anchors") is metres off or wrong altogether. The anchored frames that most others
    agree with (each pair within ``options.max_step_m`` per frame between them plus
    ``options.anchored_prior_margin_m``; a tie goes to the more inliers) place the rest: frame i, nearest (in frame
    order) to agreeing anchored frame j, gets a prior around j's position with that reach as its radius. None for a
    frame with its own prior, one of the agreeing anchored frames, or every frame when no frame was anchored.
    """
    anchored = {k: pose for k, pose in enumerate(alone) if pose is not None and pose.source == "anchors"}
    out: list[PositionPrior | None] = [None] * len(alone)
    if not anchored:
        return out

    def reach_m(i: int, j: int) -> float:
        return options.max_step_m * abs(i - j) + options.anchored_prior_margin_m

    def agreeing(k: int) -> list[int]:
        a = anchored[k]
        return [j for j, b in anchored.items() if math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) <= reach_m(k, j)]

    best = max(anchored, key=lambda k: (len(agreeing(k)), anchored[k].inliers))
    cluster = agreeing(best)
    for i, prior in enumerate(priors):
        if prior is not None or i in cluster:
            continue
        j = min(cluster, key=lambda k: (abs(k - i), k))
        out[i] = PositionPrior.from_radius(anchored[j].x_m, anchored[j].y_m, reach_m(i, j))
    return out


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
    ``edges`` (relative poses kept), ``joined`` (frames an edge joins), ``outliers`` (flagged frames' indices),
    ``anchored_priors`` (frames answered again near the track's anchored frames). ``timings_ms``: ``frames``
    (answering each, again where the anchored frames give a prior), ``smoother``, ``total``.
    """
    t0 = time.perf_counter()

    def answer(frame: TrackFrame, prior: PositionPrior | None) -> QueryAnswer:
        return geolocate(
            city_map,
            frame.photo,
            frame.evidence,
            store,
            vocabulary,
            config,
            position_prior=prior,
            heading_prior=frame.heading_prior,
            top_n=top_n,
            context=context,
        )

    answers = [answer(frame, frame.position_prior) for frame in frames]
    options = options or TrackOptions()
    own = [a.poses[0] if a.poses else None for a in answers]
    near_anchors = anchored_priors(own, [f.position_prior for f in frames], options)
    for k, prior in enumerate(near_anchors):
        if prior is not None:
            answers[k] = answer(frames[k], prior)
    t1 = time.perf_counter()
    evidence = [
        FrameEvidence(f.photo, f.evidence, f.position_prior, f.heading_prior, a.poses[0] if a.poses else None)
        for f, a in zip(frames, answers, strict=True)
    ]
    smoothed = smooth_track(city_map, evidence, options)
    out = [
        _track_answer(a, alone, pose, flag)
        for a, alone, pose, flag in zip(answers, own, smoothed.poses, smoothed.outliers, strict=True)
    ]
    t2 = time.perf_counter()
    search = TrackSearch(
        smoother="gtsam",
        edges=len(smoothed.edges),
        joined=sum(pose.n_edges > 0 for pose in smoothed.poses),
        outliers=[k for k, flag in enumerate(smoothed.outliers) if flag],
        anchored_priors=[k for k, prior in enumerate(near_anchors) if prior is not None],
    )
    timings = {"frames": 1e3 * (t1 - t0), "smoother": 1e3 * (t2 - t1), "total": 1e3 * (t2 - t0)}
    return TrackAnswer(frames=out, search=search, timings_ms=timings)
