"""A track's frames placed jointly: each frame's own answer, its priors and the motion between frames, one graph.

The graph is the reference walks' (:func:`geoloc.localize.sequence.placement.place_sequence`, gtsam
Levenberg-Marquardt on planar poses), fed with a query frame's evidence instead of a reference's label:

- the frame's own rank-1 answer (the query stage's, :func:`geoloc.localize.query.geolocate`) as the "label":
  position sigma ``uncertainty_radius_m / R90_PER_SIGMA`` (its 90 % radius as a 2D Gaussian's sigma), times
  :attr:`TrackOptions.likelihood_scale` when the likelihood (not the map anchors) answered; heading sigma
  :attr:`TrackOptions.yaw_sigmas_deg`; Cauchy loss;
- its heading prior (compass), Cauchy; its position prior (the photo's GPS, sigma the prior's, Huber loss) only
  when it has no answer of its own or its answer is set aside as an outlier's (an answer already weighed it);
- relative poses between frames 1 to 3 apart, both ways: PnP of one frame's keypoints on the other frame's
  map anchors cast from that frame's own answer (:mod:`geoloc.localize.sequence.relative`). Consecutive frames
  3-8 m apart overlap heavily; the anchors give the motion its metric scale (an essential matrix would need
  its scale from them anyway, so the PnP is used directly). Cauchy loss: a frame whose own answer is wrong
  gives wrong edges, which its neighbours overrule.

A frame with no answer of its own starts where a neighbour's edge puts it and is placed by its neighbours
(its label factor is loose). Outliers (:func:`_outliers`): a frame whose own answer lies farther from its
placed pose than :attr:`TrackOptions.outlier_min_m` and ``outlier_sigmas`` of its radius (or whose heading is
off by more than :attr:`TrackOptions.outlier_yaw_deg`), or whose placed pose lies farther from the joined frames
nearest it in frame order (one on each side) than walking allows (``max_step_m`` per frame plus both radii: its
motions were set aside), or a frame no edge joins whose answer lies that far from them. The track is then
placed again with the outliers' labels loosened, so an outlier's pose is the track's, and it cannot pull its
neighbours; a frame no edge joins keeps its own answer.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.anchors import CameraPose, MapAnchors, anchor_keypoints
from geoloc.localize.grid import PositionPrior
from geoloc.localize.query.answer import AnswerPose
from geoloc.localize.sequence.placement import (
    LOOSE_SIGMA,
    PlacedPose,
    PlacementOptions,
    SequenceFrame,
    place_sequence,
    relative_poses,
)
from geoloc.localize.sequence.relative import RelativePose
from geoloc.localize.sequence.twoview import MotionFactor, TwoViewFrame, motion_factor, two_view_motion
from geoloc.localize.track.starts import start_headings
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import PhotoEvidence
from geoloc.vision.features import Features
from geoloc.vision.ground import DEFAULT_CAMERA_HEIGHT_M

R90_PER_SIGMA = math.sqrt(-2.0 * math.log(0.1))
"""A 2D isotropic Gaussian's 90 % radius in sigmas (2.146)."""


@dataclass(frozen=True)
class TrackOptions:
    """The track smoother's tuning (module docstring; the defaults are the first choice, not yet tuned).

    Every field is described beside it; all sigmas are one standard deviation.
    """

    # The shared graph's options: which edges, their sigmas, the robust losses. Each frame's GPS independent, as
    # the tracks were measured (a walk's fixes as one drifting error, issue 19, is not measured on tracks yet).
    placement: PlacementOptions = field(default_factory=lambda: PlacementOptions(gps_correlation_m=None))
    # A frame's own answer: the least position sigma (m), and how much less a likelihood answer's position is
    # trusted than its radius says.
    position_floor_m: float = 0.5
    likelihood_scale: float = 2.0
    # The heading sigma (deg) of an anchored and of a likelihood answer (a likelihood answer's heading is right
    # to half a degree or wrong by tens: with the motions' start a tight Cauchy snaps to the right ones; 3 deg
    # against 10 raised seed 1's heading within 2 deg from 0.42 to 0.66).
    yaw_sigmas_deg: tuple[float, float] = (2.0, 3.0)
    # The label of a frame with no answer, or of an outlier (position m, heading deg): weak, not absent, since a
    # frame whose edges the robust loss all sets aside must stay determined.
    weak_label: tuple[float, float] = (30.0, 90.0)
    # The outlier test: sigmas of its own radius and metres at least, heading (deg; 180: no heading test, since
    # a frame answered on the mirror view is placed by the motions, and flagging it was seed 1's false alarms);
    # the farthest a walker moves between consecutive frames (m).
    outlier_sigmas: float = 3.0
    outlier_min_m: float = 5.0
    outlier_yaw_deg: float = 180.0
    max_step_m: float = 12.0
    # Two-view motions (geoloc.localize.sequence.twoview) between frames this many apart (() for none): their
    # nominal distance per step and sigma along it (m), sigma of the direction and of the turn (deg).
    motion_steps: tuple[int, ...] = (1, 2)
    motion_step_m: float = 5.5
    motion_along_sigma_m: float = 3.0
    motion_sigmas_deg: tuple[float, float] = (3.0, 1.0)
    # Map-anchored edges only from frames the map anchors answered (a likelihood answer's anchors are cast from
    # a pose that is often metres off, and its edges pull the anchored frames).
    anchored_edges_only: bool = True
    # Start the optimiser at the headings the motions and the frames' votes agree on (geoloc.localize.track.starts).
    motion_starts: bool = True
    # A frame with no position prior is answered again near the track's anchored frames (geoloc.localize.track.stage:
    # anchored_priors): within max_step_m per frame between them plus this margin (m) of the anchor's own error.
    anchored_prior_margin_m: float = 10.0


@dataclass(frozen=True)
class FrameEvidence:
    """What the smoother knows of one frame: its photo and evidence, priors, and its own rank-1 answer (or None)."""

    photo: Photo
    evidence: PhotoEvidence
    position_prior: PositionPrior | None
    heading_prior: HeadingPrior | None
    alone: AnswerPose | None


@dataclass(frozen=True)
class SmoothedTrack:
    """The smoother's result, per frame in order: placed poses, outlier flags; the edges that joined them."""

    poses: list[PlacedPose]
    outliers: list[bool]
    edges: list[RelativePose]


def radius_90_m(covariance: np.ndarray) -> float:
    """The 90 % radius (m) of a (2, 2) position covariance (m^2), taken isotropic at its largest axis."""
    return R90_PER_SIGMA * math.sqrt(max(float(np.linalg.eigvalsh(covariance)[-1]), 0.0))


def _graph_frame(city_map: CityMap, frame: FrameEvidence, options: TrackOptions) -> SequenceFrame:
    """A frame as the shared graph's :class:`SequenceFrame`: its anchors cast from its own answer, its label."""
    alone, features = frame.alone, frame.evidence.features
    if alone is None or (options.anchored_edges_only and alone.source != "anchors"):
        n = len(features.xy)
        anchors = MapAnchors(np.full((n, 3), np.nan), np.full(n, -1), np.full(n, -1), np.full(n, np.nan))
    else:
        rotation = frame.evidence.analysis.vanishing_points.rotation_upright_from_cam
        pose = CameraPose(alone.x_m, alone.y_m, alone.yaw_deg, DEFAULT_CAMERA_HEIGHT_M, rotation)
        anchors = anchor_keypoints(city_map, pose, frame.photo.intrinsics, features.xy)
    return label_frame(
        alone, frame.position_prior, frame.heading_prior, features, anchors, frame.photo.intrinsics, options
    )


def label_frame(
    alone: AnswerPose | None,
    position_prior: PositionPrior | None,
    heading_prior: HeadingPrior | None,
    features: Features,
    anchors: MapAnchors,
    intrinsics: Intrinsics,
    options: TrackOptions = TrackOptions(),
) -> SequenceFrame:
    """A frame's node of the graph: its own answer as the label (module docstring), its priors.

    Without an answer: a weak label at its GPS (at the origin without one), which :func:`place_track` moves to
    where an edge puts it.
    """
    gps_xy = (position_prior.x_m, position_prior.y_m) if position_prior is not None else (0.0, 0.0)
    gps_sigma = position_prior.sigma_m if position_prior is not None else LOOSE_SIGMA
    if alone is None:
        x, y, yaw = (*gps_xy, 0.0)
        sigma, yaw_sigma = options.weak_label[0], options.weak_label[1]
    else:
        x, y, yaw = alone.x_m, alone.y_m, alone.yaw_deg
        anchored = alone.source == "anchors"
        sigma = max(alone.uncertainty_radius_m / R90_PER_SIGMA, options.position_floor_m)
        sigma *= 1.0 if anchored else options.likelihood_scale
        sigma = sigma if math.isfinite(sigma) else options.weak_label[0]  # a likelihood answer may say "anywhere"
        yaw_sigma = options.yaw_sigmas_deg[0 if anchored else 1]
    return SequenceFrame(
        x,
        y,
        yaw,
        np.diag([sigma**2, sigma**2]),
        gps_xy,
        gps_sigma,
        heading_prior,
        features,
        anchors,
        intrinsics,
        label_yaw_sigma_deg=yaw_sigma,
    )


def _predicted(source: SequenceFrame, edge: RelativePose) -> tuple[float, float, float]:
    """Where an edge puts its target from its source's label: (x_m, y_m, yaw_deg)."""
    yaw = math.radians(source.yaw_deg)
    x = source.x_m + edge.forward_m * math.sin(yaw) - edge.left_m * math.cos(yaw)
    y = source.y_m + edge.forward_m * math.cos(yaw) + edge.left_m * math.sin(yaw)
    return x, y, (source.yaw_deg + edge.turn_deg) % 360.0


def _start_unanswered(
    graph: Sequence[SequenceFrame], alone: Sequence[AnswerPose | None], edges: Sequence[RelativePose]
) -> list[SequenceFrame]:
    """Frames with no answer of their own start where an edge from an answered frame puts them."""
    out = list(graph)
    for edge in sorted(edges, key=lambda e: -e.n_inliers):
        if alone[edge.target] is None and alone[edge.source] is not None:
            x, y, yaw = _predicted(graph[edge.source], edge)
            if out[edge.target] is graph[edge.target]:
                out[edge.target] = replace(graph[edge.target], x_m=x, y_m=y, yaw_deg=yaw)
    return out


def _outliers(answers: Sequence[AnswerPose | None], poses: Sequence[PlacedPose], options: TrackOptions) -> list[bool]:
    """Which frames' own answers the track disagrees with (the module docstring's tests)."""
    flags = []
    for k, (alone, pose) in enumerate(zip(answers, poses, strict=True)):
        if alone is None:
            flags.append(False)
            continue
        if pose.n_edges > 0:
            off = math.hypot(alone.x_m - pose.x_m, alone.y_m - pose.y_m)
            turn = abs((alone.yaw_deg - pose.yaw_deg + 180.0) % 360.0 - 180.0)
            radius = alone.uncertainty_radius_m if math.isfinite(alone.uncertainty_radius_m) else math.inf
            limit = max(options.outlier_min_m, options.outlier_sigmas * radius / R90_PER_SIGMA)
            # A frame its motions could not hold (the robust loss set them aside) sits at its own answer, far
            # from the rest: a photo from elsewhere, whatever matches joined it.
            placed_apart = _beyond_reach(pose.x_m, pose.y_m, radius_90_m(pose.position_covariance), k, poses, options)
            flags.append(off > limit or turn > options.outlier_yaw_deg or placed_apart)
            continue
        flags.append(_beyond_reach(alone.x_m, alone.y_m, alone.uncertainty_radius_m, k, poses, options))
    return flags


def _beyond_reach(
    x_m: float, y_m: float, radius_m: float, k: int, poses: Sequence[PlacedPose], options: TrackOptions
) -> bool:
    """Whether frame k's position (its 90 % radius, m) is out of walking reach of the track's joined frames.

    The joined frames nearest to k in frame order, one before it and one after (those that exist), are the
    track's where k stands; out of reach: farther from each one's placed pose than ``max_step_m`` per frame
    between them plus both radii. Farther joined frames allow more walking, so they would excuse any answer.
    False when no other frame is joined.
    """
    joined = [j for j in range(len(poses)) if j != k and poses[j].n_edges > 0]
    nearest = [max((j for j in joined if j < k), default=None), min((j for j in joined if j > k), default=None)]
    gaps = [
        math.hypot(x_m - poses[j].x_m, y_m - poses[j].y_m)
        - options.max_step_m * abs(j - k)
        - radius_m
        - radius_90_m(poses[j].position_covariance)
        for j in nearest
        if j is not None
    ]
    return bool(gaps) and min(gaps) > 0.0


def smooth_track(
    city_map: CityMap, frames: Sequence[FrameEvidence], options: TrackOptions = TrackOptions()
) -> SmoothedTrack:
    """Place a track's frames jointly and flag its outlier frames (module docstring); poses in frame order."""
    graph = [_graph_frame(city_map, frame, options) for frame in frames]
    edges = relative_poses(graph, options.placement) if len(graph) > 1 else []
    return place_track(graph, [frame.alone for frame in frames], edges, options, track_motions(frames, options))


def track_motions(frames: Sequence[FrameEvidence], options: TrackOptions = TrackOptions()) -> list[MotionFactor]:
    """The two-view motions between frames ``options.motion_steps`` apart, one way, as the placement's factors."""
    out = []
    for i in range(len(frames)):
        for step in options.motion_steps:
            if i + step >= len(frames):
                continue
            a, b = frames[i], frames[i + step]
            motion = two_view_motion(
                TwoViewFrame(
                    i,
                    a.evidence.features,
                    a.photo.intrinsics,
                    a.evidence.analysis.vanishing_points.rotation_upright_from_cam,
                ),
                TwoViewFrame(
                    i + step,
                    b.evidence.features,
                    b.photo.intrinsics,
                    b.evidence.analysis.vanishing_points.rotation_upright_from_cam,
                ),
            )
            if motion is not None:
                across, turn = options.motion_sigmas_deg
                out.append(
                    motion_factor(
                        motion, options.motion_step_m * step, options.motion_along_sigma_m * step, across, turn
                    )
                )
    return out


def place_track(
    graph: Sequence[SequenceFrame],
    alone: Sequence[AnswerPose | None],
    edges: Sequence[RelativePose],
    options: TrackOptions = TrackOptions(),
    motions: Sequence[MotionFactor] = (),
) -> SmoothedTrack:
    """The graph's half of :func:`smooth_track`: nodes (:func:`label_frame`), each frame's own answer, the edges.

    gtsam failing on an indeterminate system answers every frame alone (no edges, no outliers) rather than fail.
    """
    graph = _start_unanswered(graph, alone, edges)
    yaws = start_headings(alone, [g.heading_prior for g in graph], motions) if options.motion_starts else None
    # The GPS enters once: a frame's own answer already weighed its prior (the query stage's), so a frame with an
    # answer gets no GPS factor, until its answer is set aside as an outlier's. Counted twice, fixes stated to
    # 4-11 m pulled the frames off their answers (docs/measurements/tracks.md, "The GPS's stated accuracy").
    answered = [g if a is None else replace(g, gps_sigma_m=LOOSE_SIGMA) for g, a in zip(graph, alone, strict=True)]
    try:
        poses = place_sequence(answered, options.placement, edges, motions, yaws)
        outliers = _outliers(alone, poses, options)
        if any(flag and pose.n_edges > 0 for flag, pose in zip(outliers, poses, strict=True)):
            weak = options.weak_label[0] ** 2 * np.eye(2)
            loosened = [
                replace(g, position_covariance=weak, label_yaw_sigma_deg=options.weak_label[1]) if flag else kept
                for g, kept, flag in zip(graph, answered, outliers, strict=True)
            ]
            poses = place_sequence(loosened, options.placement, edges, motions, yaws)
    except RuntimeError:  # gtsam's IndeterminateLinearSystemException
        unjoined = [PlacedPose(g.x_m, g.y_m, g.yaw_deg, g.position_covariance, 0) for g in graph]
        return SmoothedTrack(unjoined, [False] * len(graph), [])
    return SmoothedTrack(poses, outliers, list(edges))
