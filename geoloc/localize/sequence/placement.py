"""Every frame of a sequence placed jointly: one robust pose graph on gtsam (Levenberg-Marquardt).

One planar pose per frame (position east/north in m, heading), with these factors:

- the frame's own label (:func:`geoloc.localize.labeling.label_reference`: the map likelihood around its GPS):
  its position with the covariance of what the map alone says there (the caller's
  :attr:`SequenceFrame.position_covariance`, floored) and its heading with
  :attr:`PlacementOptions.label_yaw_sigma_deg`, under a Cauchy loss: a label on the mirror view across the
  street is an outlier the neighbours overrule;
- its GPS tag: the tag is the frame's position plus an error that a walk's fixes share, one AR(1) process along
  the walk (each fix's error its predecessor's times ``exp(-distance / gps_correlation_m)`` plus fresh noise, a
  stationary sigma of the tag's stated accuracy; gtsam's Point2 variables), plus
  :attr:`PlacementOptions.gps_white_sigma_m` of each fix's own, under a Huber loss (a jump beside tall
  buildings). A phone's error drifts with the satellites it sees and the walls around it, so fixes a few metres
  apart are off the same way: taken as independent, fifteen of them would pin the walk to their common error;
- the step between consecutive captures, when both have a capture time and the walk's pace can be measured
  (:mod:`geoloc.localize.sequence.pace`): its distance is the speed times the time between them, with the
  pace's measured spread as sigma, Cauchy (a pause). Such a step joins the parts of a walk that see no common
  facade, so a part whose position the map fixes (a corner, a gap) places the rest;
- its compass, when it has one (:class:`geoloc.photos.heading_prior.HeadingPrior`'s mean and sigma), Cauchy;
- relative poses to the frames 1 to ``max(steps)`` further along the walk, both ways
  (:mod:`geoloc.localize.sequence.relative`), sigma ``edge_sigma_m + edge_sigma_per_m * distance`` and
  ``edge_yaw_sigma_deg``, Cauchy: a wrong source label gives a wrong edge. An edge whose length the walk's pace
  rules out keeps only its turn (:attr:`PlacementOptions.edge_pace_gate`): a facade's repeated windows match
  a frame to its neighbour one window or one step along the wall, which turns the camera right and puts it in
  the wrong place.

gtsam was measured against the alternatives the issue names (pycolmap's bundle adjustment needs 3D tracks
this problem does not have; pyceres would need every residual written by hand): its Pose2 factors, robust
noise models and marginal covariances are exactly this problem. The graph's heading is gtsam's theta, the
angle from east counter-clockwise: theta = 90 deg - bearing.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from functools import partial

import gtsam
import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.anchors import MapAnchors
from geoloc.localize.sequence.pace import WalkPace, rules_out, seconds_apart, walk_pace
from geoloc.localize.sequence.relative import DEFAULT_MIN_ANCHORED, DEFAULT_RATIO, RelativePose, relative_pose
from geoloc.localize.sequence.twoview import MotionFactor
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.vision.features import Features

DEFAULT_GPS_SIGMA_M = 8.0
"""GPS sigma (m) of a frame whose photo states no accuracy (a phone's typical stated 5-10 m)."""
START_AGREEMENT_M = 3.0
START_AGREEMENT_DEG = 10.0
"""Two predictions of a frame's starting pose agree within these (m, deg) (:func:`_consensus_start`)."""
LOOSE_SIGMA = 1e4
"""Sigma of a factor's components it does not constrain (a compass says nothing of position)."""
GPS_ERROR_KEY = 1_000_000
"""gtsam key of frame k's GPS error is ``GPS_ERROR_KEY + k`` (frame k's pose is key k)."""


@dataclass(frozen=True)
class PlacementOptions:
    """The placement's tuning (defaults measured on Helsinki seed 1's walk world; docs/measurements/accuracy.md).

    steps: edges join each frame to the frames this many further along the walk. ratio, min_anchored: the
    relative poses' matching (:func:`geoloc.localize.sequence.relative.relative_pose`); min_inliers,
    max_disagreement_m: which of them are kept (:func:`relative_poses`; on seed 1's walks a third of the edges
    are more than 2 m off, yet gating them by 20-40 inliers or a 1-2 m two-way disagreement placed the
    references no better, 0.50-0.52 within 2 m against 0.52, or worse: the robust loss already sets them
    aside). edge_sigma_m, edge_sigma_per_m, edge_yaw_sigma_deg: an edge's sigmas. label_yaw_sigma_deg,
    label_position_floor_m: a label's heading sigma and the floor of its position sigma (2 deg and 0.5 m were
    the best of 2-10 deg and 0.25-2 m on seed 1). cauchy_k, huber_k: the robust losses' scales (in sigmas).
    max_iterations: Levenberg-Marquardt's. gps_correlation_m (None: each fix independent, as tracks have it),
    gps_white_sigma_m: the GPS model (module docstring). step_sigma_m, step_sigma_fraction: a step's sigma is
    the larger of step_sigma_m and the pace's spread, plus this fraction of the step. min_speed_samples: the
    consecutive edges a pace needs (:mod:`geoloc.localize.sequence.pace`). compass_walk_agreement: the share
    of a walk's compass frames whose labels must agree with their compass before the labels facing away from it
    are done again with the compass trusted (None: never; :func:`geoloc.localize.sequence.stage.compass_relabelled`).
    edge_pace_gate: an edge whose length is more than this many step sigmas (the pace's, times the square root
    of the steps it spans) from the walk's speed times the time between its frames keeps its turn and loses its
    translation (math.inf: never; :func:`geoloc.localize.sequence.pace.rules_out`).
    """

    steps: tuple[int, ...] = (1, 2, 3)
    ratio: float = DEFAULT_RATIO
    min_anchored: int = DEFAULT_MIN_ANCHORED
    min_inliers: int = 12
    max_disagreement_m: float = math.inf
    edge_sigma_m: float = 0.3
    edge_sigma_per_m: float = 0.03
    edge_yaw_sigma_deg: float = 0.5
    label_yaw_sigma_deg: float = 2.0
    label_position_floor_m: float = 0.5
    cauchy_k: float = 1.0
    huber_k: float = 1.5
    max_iterations: int = 100
    gps_correlation_m: float | None = 80.0
    gps_white_sigma_m: float = 1.5
    step_sigma_m: float = 0.5
    step_sigma_fraction: float = 0.0
    min_speed_samples: int = 3
    compass_walk_agreement: float | None = 0.5
    edge_pace_gate: float = 3.0


@dataclass(frozen=True)
class SequenceFrame:
    """One frame of a sequence as the placement sees it (local frame of the map: metres, bearings in deg).

    x_m, y_m, yaw_deg, position_covariance: its label's pose and (2, 2) m^2 covariance (a walk's: what the map
    alone says, :func:`geoloc.localize.sequence.frames.map_position_covariance`). gps_xy, gps_sigma_m:
    its GPS tag and that tag's sigma. heading_prior: its compass (None: none). features, anchors, intrinsics:
    its keypoints, their 3D points on the map seen from the label's pose, and its camera. label_yaw_sigma_deg:
    its label's heading sigma (deg; None: :attr:`PlacementOptions.label_yaw_sigma_deg`; a track's query frames
    answered by the likelihood alone are less sure of their heading than an anchored one). capture_time_s: when
    it was taken (s on any one clock the walk shares; None: unknown, no step factor to or from it).
    """

    x_m: float
    y_m: float
    yaw_deg: float
    position_covariance: np.ndarray
    gps_xy: tuple[float, float]
    gps_sigma_m: float
    heading_prior: HeadingPrior | None
    features: Features
    anchors: MapAnchors
    intrinsics: Intrinsics
    label_yaw_sigma_deg: float | None = None
    capture_time_s: float | None = None


@dataclass(frozen=True)
class PlacedPose:
    """A frame's jointly placed pose.

    x_m, y_m, yaw_deg: the pose; position_covariance: (2, 2) m^2 (gtsam's marginal); n_edges: relative poses
    that joined it to other frames; n_steps: steps between capture times that joined it to the frames taken
    just before and after it (0 to 2). With neither it was placed by its own label, GPS and compass alone.
    """

    x_m: float
    y_m: float
    yaw_deg: float
    position_covariance: np.ndarray
    n_edges: int
    n_steps: int = 0

    @property
    def joined(self) -> bool:
        """Whether a relative pose or a step joined it to the rest of its walk."""
        return self.n_edges > 0 or self.n_steps > 0


def _pose2(x_m: float, y_m: float, yaw_deg: float) -> gtsam.Pose2:
    return gtsam.Pose2(x_m, y_m, math.radians(90.0 - yaw_deg))


def _bearing_deg(pose: gtsam.Pose2) -> float:
    return (90.0 - math.degrees(pose.theta())) % 360.0


def _local(covariance_xy: np.ndarray, yaw_deg: float, yaw_sigma_deg: float) -> np.ndarray:
    """(3, 3) covariance in a pose's own axes (gtsam's tangent space) of a map-frame (2, 2) one and a yaw sigma."""
    theta = math.radians(90.0 - yaw_deg)
    rotation = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    out = np.zeros((3, 3))
    out[:2, :2] = rotation.T @ covariance_xy @ rotation
    out[2, 2] = math.radians(yaw_sigma_deg) ** 2
    return out


def _robust(loss: str, k: float, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    estimator = (
        gtsam.noiseModel.mEstimator.Cauchy.Create(k)
        if loss == "cauchy"
        else (gtsam.noiseModel.mEstimator.Huber.Create(k))
    )
    return gtsam.noiseModel.Robust.Create(estimator, base)


def relative_poses(
    frames: Sequence[SequenceFrame], options: PlacementOptions, touching: Collection[int] | None = None
) -> list[RelativePose]:
    """Every edge of the graph: frame i to i + s for s in ``options.steps``, both ways, where PnP finds one.

    touching: only the pairs with one of these frames (indices; None: every pair).

    An edge needs ``options.min_inliers`` PnP inliers, and when both ways were found, the two must agree
    (within ``options.max_disagreement_m``, the source's centre as seen through the two): two PnPs on two
    frames' anchors that disagree mean one label's anchors are wrong, and neither way is kept.
    """
    edges = []
    for i in range(len(frames)):
        for step in options.steps:
            j = i + step
            if j >= len(frames) or (touching is not None and i not in touching and j not in touching):
                continue
            pair = [_edge(frames, source, target, options) for source, target in ((i, j), (j, i))]
            found = [edge for edge in pair if edge is not None and edge.n_inliers >= options.min_inliers]
            if len(found) == 2 and _disagreement_m(found[0], found[1]) > options.max_disagreement_m:
                continue
            edges.extend(found)
    return edges


def _edge(frames: Sequence[SequenceFrame], source: int, target: int, options: PlacementOptions) -> RelativePose | None:
    a, b = frames[source], frames[target]
    return relative_pose(
        source,
        target,
        (a.x_m, a.y_m, a.yaw_deg),
        a.features,
        a.anchors,
        b.features,
        b.intrinsics,
        ratio=options.ratio,
        min_anchored=options.min_anchored,
    )


def _disagreement_m(forward: RelativePose, backward: RelativePose) -> float:
    """How far apart (m) the source lands, seen through an edge and through its reverse's inverse."""
    inverse = _measured(backward).inverse()
    return math.hypot(inverse.x() - forward.forward_m, inverse.y() - forward.left_m)


def _consensus_start(
    labels: list[gtsam.Pose2], edges: Sequence[RelativePose], options: PlacementOptions
) -> list[gtsam.Pose2]:
    """Each frame's starting pose for the optimiser: its label, or what its neighbours predict, by agreement.

    The candidates are the frame's own label and what each neighbour's label and edge predict for it; the one
    most others agree with starts (a tie keeps the label; agreement: within :data:`START_AGREEMENT_M` and
    :data:`START_AGREEMENT_DEG`). Why: Levenberg-Marquardt only descends, and a frame started on the mirror
    view across the street (heading 180 deg off) stays there however its neighbours pull.
    """
    predictions: list[list[gtsam.Pose2]] = [[label] for label in labels]
    for edge in edges:
        measured = _measured(edge)
        predictions[edge.target].append(labels[edge.source].compose(measured))
        predictions[edge.source].append(labels[edge.target].compose(measured.inverse()))
    start = []
    for candidates in predictions:
        scores = [_support(pose, candidates) for pose in candidates]
        best = max(range(len(candidates)), key=lambda i: (scores[i], i == 0))
        start.append(candidates[best])
    return start


def _support(pose: gtsam.Pose2, candidates: list[gtsam.Pose2]) -> int:
    """How many candidates agree with ``pose`` (within the START_AGREEMENT thresholds, itself included)."""
    return sum(
        math.hypot(pose.x() - other.x(), pose.y() - other.y()) < START_AGREEMENT_M
        and abs(math.degrees(pose.between(other).theta())) < START_AGREEMENT_DEG
        for other in candidates
    )


def _measured(edge: RelativePose) -> gtsam.Pose2:
    """An edge as gtsam's relative pose (the target in the source's axes; theta counter-clockwise)."""
    return gtsam.Pose2(edge.forward_m, edge.left_m, math.radians(-edge.turn_deg))


def place_sequence(
    frames: Sequence[SequenceFrame],
    options: PlacementOptions = PlacementOptions(),
    edges: Sequence[RelativePose] | None = None,
    motions: Sequence[MotionFactor] = (),
    start_yaws_deg: Sequence[float] | None = None,
) -> list[PlacedPose]:
    """Each frame's pose placed jointly (the module docstring's graph), in the frames' order.

    edges: the relative poses when already computed (:func:`relative_poses`), else they are computed here.
    motions: relative poses with their own covariance (a track's two-view motions,
    :mod:`geoloc.localize.sequence.twoview`), Cauchy; they count among a frame's edges. start_yaws_deg: each
    frame's starting heading for the optimiser, replacing the consensus start's (a track's, from its motions).
    """
    edges = list(edges) if edges is not None else relative_poses(frames, options)
    noise = gtsam.noiseModel
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    floor = options.label_position_floor_m**2 * np.eye(2)
    labels = [_pose2(frame.x_m, frame.y_m, frame.yaw_deg) for frame in frames]
    for k, start in enumerate(_consensus_start(labels, edges, options)):
        yaw = _bearing_deg(start) if start_yaws_deg is None else start_yaws_deg[k]
        initial.insert(k, _pose2(start.x(), start.y(), yaw))
    for k, frame in enumerate(frames):
        label = labels[k]
        yaw_sigma = options.label_yaw_sigma_deg if frame.label_yaw_sigma_deg is None else frame.label_yaw_sigma_deg
        covariance = _local(frame.position_covariance + floor, frame.yaw_deg, yaw_sigma)
        label_noise = _robust("cauchy", options.cauchy_k, noise.Gaussian.Covariance(covariance))
        graph.add(gtsam.PriorFactorPose2(k, label, label_noise))
        if options.gps_correlation_m is None:
            gps_sigmas = np.array([frame.gps_sigma_m, frame.gps_sigma_m, LOOSE_SIGMA])
            gps_noise = _robust("huber", options.huber_k, noise.Diagonal.Sigmas(gps_sigmas))
            graph.add(gtsam.PriorFactorPose2(k, gtsam.Pose2(frame.gps_xy[0], frame.gps_xy[1], 0.0), gps_noise))
        prior = frame.heading_prior
        if prior is not None:
            compass_sigmas = np.array([LOOSE_SIGMA, LOOSE_SIGMA, math.radians(prior.sigma_deg)])
            compass_noise = _robust("cauchy", options.cauchy_k, noise.Diagonal.Sigmas(compass_sigmas))
            graph.add(gtsam.PriorFactorPose2(k, _pose2(frame.x_m, frame.y_m, prior.mean_bearing_deg), compass_noise))
    n_edges = np.zeros(len(frames), dtype=int)
    times = [frame.capture_time_s for frame in frames]
    pace = walk_pace(times, edges, options.min_speed_samples)
    for edge in edges:
        sigma = options.edge_sigma_m + options.edge_sigma_per_m * edge.distance_m
        if rules_out(pace, times, edge, options.step_sigma_m, options.edge_pace_gate):
            sigma = LOOSE_SIGMA  # its turn stands, its translation does not (module docstring)
        sigmas = np.array([sigma, sigma, math.radians(options.edge_yaw_sigma_deg)])
        measured = _measured(edge)
        graph.add(
            gtsam.BetweenFactorPose2(
                edge.source, edge.target, measured, _robust("cauchy", options.cauchy_k, noise.Diagonal.Sigmas(sigmas))
            )
        )
        n_edges[[edge.source, edge.target]] += 1
    for motion in motions:
        motion_noise = _robust("cauchy", options.cauchy_k, noise.Gaussian.Covariance(motion.covariance))
        measured = gtsam.Pose2(motion.forward_m, motion.left_m, math.radians(-motion.turn_deg))
        graph.add(gtsam.BetweenFactorPose2(motion.source, motion.target, measured, motion_noise))
        n_edges[[motion.source, motion.target]] += 1
    if options.gps_correlation_m is not None:
        _add_correlated_gps(graph, initial, frames, options, options.gps_correlation_m)
    n_steps = _add_steps(graph, times, pace, options)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(options.max_iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    marginals = gtsam.Marginals(graph, result)
    placed = []
    for k in range(len(frames)):
        pose = result.atPose2(k)
        # The marginal is in the pose's own axes; rotate its position block back to east/north.
        theta = pose.theta()
        rotation = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
        covariance = rotation @ np.asarray(marginals.marginalCovariance(k))[:2, :2] @ rotation.T
        placed.append(PlacedPose(pose.x(), pose.y(), _bearing_deg(pose), covariance, int(n_edges[k]), int(n_steps[k])))
    return placed


def _gps_residual(
    tag_xy: np.ndarray, this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[np.ndarray] | None
) -> np.ndarray:
    """A fix minus (the frame's position + its GPS error); d/d pose is minus the pose's rotation (gtsam's tangent)."""
    pose, error = values.atPose2(this.keys()[0]), values.atPoint2(this.keys()[1])
    if jacobians is not None:
        jacobians[0] = np.hstack([-pose.rotation().matrix(), np.zeros((2, 1))])
        jacobians[1] = -np.eye(2)
    return np.asarray(tag_xy - np.array([pose.x(), pose.y()]) - error)


def _ar1_residual(
    rho: float, this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[np.ndarray] | None
) -> np.ndarray:
    """A GPS error minus ``rho`` times its predecessor's: the AR(1) process's fresh noise."""
    before, after = values.atPoint2(this.keys()[0]), values.atPoint2(this.keys()[1])
    if jacobians is not None:
        jacobians[0] = -rho * np.eye(2)
        jacobians[1] = np.eye(2)
    return np.asarray(after - rho * before)


def _add_correlated_gps(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    frames: Sequence[SequenceFrame],
    options: PlacementOptions,
    correlation_m: float,
) -> None:
    """Each fix as the frame's position plus a shared AR(1) error along the walk (the module docstring)."""
    noise = gtsam.noiseModel
    fix_noise = _robust("huber", options.huber_k, noise.Isotropic.Sigma(2, options.gps_white_sigma_m))
    for k, frame in enumerate(frames):
        tag = np.asarray(frame.gps_xy, dtype=float)
        initial.insert(GPS_ERROR_KEY + k, np.zeros(2))
        graph.add(gtsam.CustomFactor(fix_noise, [k, GPS_ERROR_KEY + k], partial(_gps_residual, tag)))
        if k == 0:
            graph.add(gtsam.PriorFactorPoint2(GPS_ERROR_KEY, np.zeros(2), noise.Isotropic.Sigma(2, frame.gps_sigma_m)))
            continue
        rho = math.exp(-math.dist(frame.gps_xy, frames[k - 1].gps_xy) / correlation_m)
        fresh_sigma = max(frame.gps_sigma_m * math.sqrt(1.0 - rho**2), 0.05)  # two fixes at one spot: nearly equal
        graph.add(
            gtsam.CustomFactor(
                noise.Isotropic.Sigma(2, fresh_sigma),
                [GPS_ERROR_KEY + k - 1, GPS_ERROR_KEY + k],
                partial(_ar1_residual, rho),
            )
        )


def _add_steps(
    graph: gtsam.NonlinearFactorGraph,
    capture_times_s: Sequence[float | None],
    pace: WalkPace | None,
    options: PlacementOptions,
) -> np.ndarray:
    """Consecutive frames' distance from their capture times and the walk's pace (the module docstring).

    Returns the number of steps added at each frame ((N,) int, 0 to 2).
    """
    n_steps = np.zeros(len(capture_times_s), dtype=int)
    if pace is None:
        return n_steps
    for k in range(len(capture_times_s) - 1):
        apart_s = seconds_apart(capture_times_s, k, k + 1)
        if apart_s is None:
            continue
        step_m = pace.speed_m_s * apart_s
        sigma = pace.step_sigma_m(options.step_sigma_m) + options.step_sigma_fraction * step_m
        step_noise = _robust("cauchy", options.cauchy_k, gtsam.noiseModel.Isotropic.Sigma(1, sigma))
        graph.add(gtsam.RangeFactorPose2(k, k + 1, step_m, step_noise))
        n_steps[[k, k + 1]] += 1
    return n_steps
