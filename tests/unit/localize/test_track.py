"""The track smoother on synthetic evidence.

A wrong frame is flagged and does not pull the others; a frame with no answer of its own is placed by its neighbours.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.anchors import MapAnchors
from geoloc.localize.grid import PositionPrior
from geoloc.localize.query.answer import AnswerPose
from geoloc.localize.sequence.placement import SequenceFrame
from geoloc.localize.sequence.relative import RelativePose, pose_in_frame
from geoloc.localize.sequence.twoview import TwoViewMotion, motion_factor
from geoloc.localize.track.smoother import R90_PER_SIGMA, TrackOptions, label_frame, place_track, radius_90_m
from geoloc.localize.track.stage import anchored_priors
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.vision.features import Features

TRUTH = [(6.0 * i, 0.5 * i, 90.0 if i % 3 else 0.0) for i in range(9)]
"""A 9-frame walk east, 6 m a frame, looking along the street and now and then at the north facades."""


def _answer(x: float, y: float, yaw: float, radius_m: float = 2.0, source: str = "anchors") -> AnswerPose:
    return AnswerPose(1, x, y, yaw, 0.5, radius_m, source)


def _nodes(answers: list[AnswerPose | None], gps_radius_m: float = 50.0) -> list[SequenceFrame]:
    anchors = MapAnchors(np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    intrinsics = Intrinsics(640, 480, 550.0, 320.0, 240.0)
    return [
        label_frame(
            a,
            PositionPrior.from_radius(t[0] + 4.0, t[1] - 3.0, gps_radius_m),  # a GPS 5 m off, as the walk's is
            HeadingPrior(t[2] + 5.0, 20.0, 0.2),
            Features.empty((480, 640)),
            anchors,
            intrinsics,
        )
        for a, t in zip(answers, TRUTH, strict=True)
    ]


def _edges(skip: int | None = None) -> list[RelativePose]:
    """Exact relative poses between frames 1 and 2 apart, both ways; none touching frame ``skip``."""
    edges = []
    for i in range(len(TRUTH)):
        for j in (i + 1, i + 2):
            if j >= len(TRUTH) or skip in (i, j):
                continue
            for a, b in ((i, j), (j, i)):
                forward, left, turn = pose_in_frame(TRUTH[a][:2], TRUTH[a][2], TRUTH[b][:2], TRUTH[b][2])
                edges.append(RelativePose(a, b, forward, left, turn, 60))
    return edges


def _own_answers(rng: np.random.Generator) -> list[AnswerPose | None]:
    """Each frame's own answer: the truth plus 1.5 m of noise along the street, heading within a degree."""
    return [_answer(x + rng.normal(0.0, 1.5), y, yaw + rng.normal(0.0, 1.0)) for x, y, yaw in TRUTH]


def _errors(track: list, truth: list = TRUTH) -> list[float]:
    return [math.hypot(p.x_m - t[0], p.y_m - t[1]) for p, t in zip(track, truth, strict=True)]


def test_the_track_is_better_than_its_frames_alone() -> None:
    answers = _own_answers(np.random.default_rng(1))
    smoothed = place_track(_nodes(answers), answers, _edges())
    alone = [math.hypot(a.x_m - t[0], a.y_m - t[1]) for a, t in zip(answers, TRUTH, strict=True) if a]
    errors = _errors(smoothed.poses)
    assert np.mean(errors) < 0.6 * np.mean(alone), (errors, alone)
    assert not any(smoothed.outliers)
    for pose in smoothed.poses:  # the marginals: tighter than a frame's own 2 m radius
        assert 0.0 < radius_90_m(pose.position_covariance) < 2.0


def test_a_frame_from_elsewhere_is_flagged_and_does_not_pull_the_track() -> None:
    answers = _own_answers(np.random.default_rng(2))
    answers[4] = _answer(180.0, -95.0, 270.0)  # a photo of another street: its answer there, no edge to it
    smoothed = place_track(_nodes(answers), answers, _edges(skip=4))
    assert smoothed.outliers == [k == 4 for k in range(len(TRUTH))]
    errors = _errors(smoothed.poses)
    assert max(errors[:4] + errors[5:]) < 1.5, errors


def test_a_wrong_answer_with_edges_is_flagged_and_placed_by_its_neighbours() -> None:
    answers = _own_answers(np.random.default_rng(3))
    x, y, yaw = TRUTH[5]
    answers[5] = _answer(x + 3.0, y + 14.0, (yaw + 180.0) % 360.0, radius_m=1.0)  # sure of the mirror view
    smoothed = place_track(_nodes(answers), answers, _edges())
    assert smoothed.outliers == [k == 5 for k in range(len(TRUTH))]
    errors = _errors(smoothed.poses)
    assert errors[5] < 1.5 and max(errors) < 1.5, errors
    assert abs((smoothed.poses[5].yaw_deg - yaw + 180.0) % 360.0 - 180.0) < 2.0


def test_a_frame_with_no_answer_is_placed_by_its_neighbours() -> None:
    answers = _own_answers(np.random.default_rng(4))
    answers[3] = None
    smoothed = place_track(_nodes(answers), answers, _edges())
    assert not any(smoothed.outliers)
    pose, before, after = smoothed.poses[3], smoothed.poses[2], smoothed.poses[4]
    errors = _errors(smoothed.poses)
    assert pose.n_edges > 0 and errors[3] < 2.5 and errors[3] <= max(errors) + 1e-9
    # Where its neighbours put it: the true steps from frames 2 and 4, to a few decimetres.
    for near, k in ((before, 2), (after, 4)):
        step = (TRUTH[3][0] - TRUTH[k][0], TRUTH[3][1] - TRUTH[k][1])
        assert math.hypot(pose.x_m - near.x_m - step[0], pose.y_m - near.y_m - step[1]) < 0.4
    assert abs((pose.yaw_deg - TRUTH[3][2] + 180.0) % 360.0 - 180.0) < 2.0


def test_the_gps_counts_once_a_frame_with_its_own_answer_is_not_pulled_to_it_again() -> None:
    """A frame's answer already weighed its GPS prior: only a frame with no answer gets a GPS factor."""
    answers: list[AnswerPose | None] = [_answer(x, y, yaw, radius_m=4.3) for x, y, yaw in TRUTH]
    answers[3] = None
    nodes = _nodes(answers, gps_radius_m=12.0)  # a phone stating 6 m
    smoothed = place_track(nodes, answers, [])  # no edge: each frame where its answer or its GPS puts it
    errors = _errors(smoothed.poses)
    assert max(errors[:3] + errors[4:]) < 0.05, errors  # on their answers, not drawn 5 m towards the GPS
    assert math.hypot(smoothed.poses[3].x_m - TRUTH[3][0] - 4.0, smoothed.poses[3].y_m - TRUTH[3][1] + 3.0) < 0.5


def test_without_edges_every_frame_keeps_its_own_answer() -> None:
    answers = _own_answers(np.random.default_rng(5))
    smoothed = place_track(_nodes(answers), answers, [])
    assert not any(smoothed.outliers) and all(p.n_edges == 0 for p in smoothed.poses)
    for pose, answer in zip(smoothed.poses, answers, strict=True):
        assert answer is not None and math.hypot(pose.x_m - answer.x_m, pose.y_m - answer.y_m) < 0.5


def test_a_likelihood_answer_weighs_less_than_an_anchored_one() -> None:
    options = TrackOptions()
    anchored, likely = (
        _nodes([_answer(0.0, 0.0, 0.0, 4.0, source)] * len(TRUTH))[0] for source in ("anchors", "likelihood")
    )
    sigma = 4.0 / R90_PER_SIGMA
    assert anchored.position_covariance[0, 0] == sigma**2
    assert likely.position_covariance[0, 0] == (sigma * options.likelihood_scale) ** 2
    assert likely.label_yaw_sigma_deg == options.yaw_sigmas_deg[1] > anchored.label_yaw_sigma_deg


def test_a_likelihood_answer_that_says_anywhere_gets_a_weak_finite_label() -> None:
    node = _nodes([_answer(3.0, 4.0, 10.0, math.inf, "likelihood")] * len(TRUTH))[0]
    assert np.isfinite(node.position_covariance).all()
    assert node.position_covariance[0, 0] == TrackOptions().weak_label[0] ** 2 and node.position_covariance[0, 1] == 0


def test_a_track_without_priors_is_answered_again_near_the_anchored_frames_most_agree_with() -> None:
    options = TrackOptions()  # 12 m a frame at most, 10 m of margin
    likelihood = [_answer(300.0 + 40 * i, -200.0, 0.0, 20.0, "likelihood") for i in range(len(TRUTH))]
    alone: list[AnswerPose | None] = list(likelihood)
    alone[2], alone[3] = _answer(*TRUTH[2]), _answer(TRUTH[3][0] + 1.0, TRUTH[3][1], TRUTH[3][2])
    alone[7] = _answer(500.0, 500.0, 0.0)  # anchored, but on a wrong reference far away: agrees with no other
    alone[8] = None
    priors = anchored_priors(alone, [None] * len(TRUTH), options)
    assert priors[2] is None and priors[3] is None  # the agreeing anchored frames keep their answers
    for i, prior in enumerate(priors):
        if i in (2, 3):
            continue
        assert prior is not None
        j = 2 if i <= 2 else 3  # the nearest agreeing anchored frame in frame order
        assert (prior.x_m, prior.y_m) == (alone[j].x_m, alone[j].y_m)  # type: ignore[union-attr]
        assert math.isclose(2.0 * prior.sigma_m, 12.0 * abs(i - j) + 10.0)  # its reach is the prior's radius
    # Frames that came with a prior keep it; a track nothing anchored gets no prior at all.
    gps = PositionPrior.from_radius(0.0, 0.0, 50.0)
    assert anchored_priors(alone, [gps] * len(TRUTH), options) == [None] * len(TRUTH)
    assert anchored_priors(likelihood, [None] * len(TRUTH), options) == [None] * len(TRUTH)


def test_a_frame_from_elsewhere_that_matches_its_neighbours_is_flagged_too() -> None:
    options = TrackOptions()
    answers = _own_answers(np.random.default_rng(2))
    answers[4] = _answer(180.0, -95.0, 270.0, radius_m=20.0, source="likelihood")  # answered where it was taken
    nodes = _nodes(answers)
    nodes[4] = replace(nodes[4], gps_xy=(183.0, -90.0))  # and its own GPS says so
    # Repeated shop fronts: two-view motions join it to its neighbours as if it were the next step.
    motions = []
    for a, b in ((3, 4), (4, 5)):
        forward, left, turn = pose_in_frame(TRUTH[a][:2], TRUTH[a][2], TRUTH[b][:2], TRUTH[b][2])
        direction = TwoViewMotion(a, b, forward / math.hypot(forward, left), left / math.hypot(forward, left), turn, 80)
        across, turn_sigma = options.motion_sigmas_deg
        motions.append(
            motion_factor(direction, options.motion_step_m, options.motion_along_sigma_m, across, turn_sigma)
        )
    smoothed = place_track(nodes, answers, _edges(skip=4), options, motions)
    # Joined, yet the robust loss set its motions aside: it sits at its own answer, out of walking reach.
    assert smoothed.poses[4].n_edges == 2
    assert math.hypot(smoothed.poses[4].x_m - 180.0, smoothed.poses[4].y_m + 95.0) < 20.0
    assert smoothed.outliers == [k == 4 for k in range(len(TRUTH))]
    errors = _errors(smoothed.poses)
    assert max(errors[:4] + errors[5:]) < 1.5, errors
