"""Two-view motions between a walk's frames (geoloc.localize.sequence.twoview) on a synthetic scene."""

from __future__ import annotations

import math

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.anchors import CameraPose
from geoloc.localize.query.answer import AnswerPose
from geoloc.localize.sequence.relative import pose_in_frame
from geoloc.localize.sequence.twoview import TwoViewFrame, TwoViewMotion, motion_factor, two_view_motion
from geoloc.localize.track.smoother import place_track
from geoloc.localize.track.starts import start_headings
from geoloc.vision.features import Features
from tests.unit.localize.test_track import TRUTH, _nodes

K = Intrinsics.from_hfov(1000, 750, 60.0)
POINTS = np.column_stack(
    [
        np.random.default_rng(0).uniform(-15, 15, 500),
        np.random.default_rng(1).uniform(6, 30, 500),
        np.random.default_rng(2).uniform(0, 10, 500),
    ]
)
"""Facade-like points in front of cameras at the origin looking north (map frame: east, north, up; m)."""


def _pitch(deg: float) -> np.ndarray:
    """rotation_upright_from_cam of a camera pitched up by ``deg`` (camera axes: x right, y down, z forward)."""
    a = math.radians(deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)], [0.0, -math.sin(a), math.cos(a)]])


def _features(pose: CameraPose, descriptors: np.ndarray, noise_px: float, seed: int) -> Features:
    camera = (POINTS - pose.position) @ pose.world_from_cam()  # map -> camera axes
    xy = K.focal_px * camera[:, :2] / camera[:, 2:3] + np.array([K.cx, K.cy])
    xy += np.random.default_rng(seed).normal(0.0, noise_px, xy.shape)
    n = len(xy)
    ones = np.ones(n, np.float32)
    return Features(xy.astype(np.float32), descriptors, ones, 0 * ones, ones, (750, 1000), 1.0, "rootsift")


def _descriptors(n: int) -> np.ndarray:
    d = np.random.default_rng(3).normal(size=(n, 128)).astype(np.float32)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_the_motion_of_a_pitched_camera_is_its_direction_and_turn() -> None:
    upright_a, upright_b = _pitch(8.0), _pitch(-4.0)
    a = CameraPose(0.0, 0.0, 10.0, rotation_upright_from_cam=upright_a)
    b = CameraPose(1.0, 4.0, 25.0, rotation_upright_from_cam=upright_b)
    d = _descriptors(len(POINTS))
    motion = two_view_motion(
        TwoViewFrame(0, _features(a, d, 0.3, 4), K, upright_a), TwoViewFrame(1, _features(b, d, 0.3, 5), K, upright_b)
    )
    assert motion is not None
    forward, left, turn = pose_in_frame((0.0, 0.0), 10.0, (1.0, 4.0), 25.0)
    bearing = math.degrees(math.atan2(motion.left, motion.forward))
    assert abs(bearing - math.degrees(math.atan2(left, forward))) < 1.0, motion
    assert abs(motion.turn_deg - turn) < 0.3, motion


def test_frames_with_too_few_matches_give_no_motion() -> None:
    a, b = CameraPose(0.0, 0.0, 0.0), CameraPose(0.0, 4.0, 0.0)
    d = _descriptors(len(POINTS))
    features_a, features_b = _features(a, d, 0.3, 4), _features(b, _descriptors(len(POINTS))[::-1].copy(), 0.3, 5)
    assert two_view_motion(TwoViewFrame(0, features_a, K, np.eye(3)), TwoViewFrame(1, features_b, K, np.eye(3))) is None


def test_the_factor_is_loose_along_the_direction_and_tight_across() -> None:
    motion = TwoViewMotion(0, 1, math.cos(0.3), math.sin(0.3), 20.0, 100)
    factor = motion_factor(motion, 5.0, 3.0, 2.0, 1.0)
    assert math.isclose(math.hypot(factor.forward_m, factor.left_m), 5.0)
    values = np.linalg.eigvalsh(factor.covariance[:2, :2])
    assert np.allclose(values, sorted([(5.0 * math.radians(2.0)) ** 2, 9.0]))
    assert math.isclose(factor.covariance[2, 2], math.radians(1.0) ** 2)


def test_motions_carry_an_anchored_heading_to_likelihood_frames() -> None:
    """One anchored frame, the others answered by the likelihood 20 deg off either way: motions align them."""
    answers: list[AnswerPose | None] = [
        AnswerPose(
            1,
            x + 2.0,
            y,
            (yaw + (0.0 if i == 4 else 20.0 * (-1) ** i)) % 360.0,
            0.5,
            2.0 if i == 4 else 8.0,
            "anchors" if i == 4 else "likelihood",
        )
        for i, (x, y, yaw) in enumerate(TRUTH)
    ]
    motions = _walk_motions()
    without = place_track(_nodes(answers), answers, [])
    with_motions = place_track(_nodes(answers), answers, [], motions=motions)

    def heading_errors(poses: list) -> list[float]:
        return [abs((p.yaw_deg - t[2] + 180.0) % 360.0 - 180.0) for p, t in zip(poses, TRUTH, strict=True)]

    assert max(heading_errors(with_motions.poses)) < 5.0, heading_errors(with_motions.poses)
    assert np.mean(heading_errors(with_motions.poses)) < 0.5 * np.mean(heading_errors(without.poses))


def _walk_motions() -> list:
    """Exact two-view motions between consecutive frames of TRUTH, as the track's factors."""
    motions = []
    for i in range(len(TRUTH) - 1):
        forward, left, turn = pose_in_frame(TRUTH[i][:2], TRUTH[i][2], TRUTH[i + 1][:2], TRUTH[i + 1][2])
        norm = math.hypot(forward, left)
        motion = TwoViewMotion(i, i + 1, forward / norm, left / norm, turn, 100)
        motions.append(motion_factor(motion, 5.5, 3.0, 3.0, 1.0))
    return motions


def test_a_frame_answered_on_the_mirror_view_starts_and_ends_the_right_way() -> None:
    """Frame 3's own answer looks the opposite way: the motions' start turns it round, the placement keeps it."""
    answers: list[AnswerPose | None] = [
        AnswerPose(1, x, y, (yaw + (180.0 if i == 3 else 0.0)) % 360.0, 0.5, 6.0, "likelihood")
        for i, (x, y, yaw) in enumerate(TRUTH)
    ]
    starts = start_headings(answers, [None] * len(TRUTH), _walk_motions())
    assert starts is not None
    assert all(abs((s - t[2] + 180.0) % 360.0 - 180.0) < 1.0 for s, t in zip(starts, TRUTH, strict=True)), starts
    placed = place_track(_nodes(answers), answers, [], motions=_walk_motions())
    assert abs((placed.poses[3].yaw_deg - TRUTH[3][2] + 180.0) % 360.0 - 180.0) < 2.0
    assert not any(placed.outliers)
    assert start_headings(answers, [None] * len(TRUTH), []) is None
