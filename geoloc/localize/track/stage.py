"""The track stage's entry, :func:`locate_track`: the frames of a walk of query photos, in order, to their poses.

Positions are local metres of ``city_map.frame``; yaws are local bearings (deg), as in the query stage.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from geoloc.core.context import MethodContext
from geoloc.localize.grid import PositionPrior
from geoloc.localize.query import geolocate
from geoloc.localize.query.answer import AnswerPose, QueryAnswer
from geoloc.localize.query.config import QueryConfig
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.store import ReferenceStore
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


def locate_track(
    city_map: CityMap,
    frames: Sequence[TrackFrame],
    store: ReferenceStore,
    vocabulary: Vocabulary,
    config: QueryConfig = QueryConfig(),
    *,
    top_n: int = 10,
    context: MethodContext,
) -> TrackAnswer:
    """Locate the frames of one track (in frame order) against the references of ``store``.

    Each frame is answered alone by the query stage with its own priors; the answers are returned per frame.
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
    out = [FrameAnswer(answer=a, alone=a.poses[0] if a.poses else None) for a in answers]
    return TrackAnswer(frames=out, search={"smoother": "none"}, timings_ms={"frames": 1e3 * (time.perf_counter() - t0)})
