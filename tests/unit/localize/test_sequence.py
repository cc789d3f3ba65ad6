"""Walks of references: grouping, and the joint placement's pose graph on hand-made frames and edges."""

from __future__ import annotations

import math
from dataclasses import replace
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.core.camera import Intrinsics
from geoloc.localize.anchors import MapAnchors
from geoloc.localize.likelihood import image_model_from_map
from geoloc.localize.sequence import PlacementOptions, SequenceFrame, SequenceMember, group_sequences, place_sequence
from geoloc.localize.sequence.frames import MAP_SPREAD_HALF_SIZE_M, map_position_covariance
from geoloc.localize.sequence.pace import WalkPace, rules_out, walk_pace
from geoloc.localize.sequence.placement import PlacedPose
from geoloc.localize.sequence.relative import RelativePose, pose_in_frame
from geoloc.localize.sequence.stage import STEPS_OVERRULE_M, keeps_own_label
from geoloc.maps import city_map_from_footprints
from geoloc.maps.raycast import cast_panoramas
from geoloc.photos.capture import photo_device
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import load_photo
from geoloc.vision.features import Features
from geoloc.vision.image_model import bin_offsets_deg
from tests.scenes import box

T0 = datetime(2025, 6, 1, 10, 0, 0)


def _member(
    rid: int, seconds: float, x: float, *, seq: str | None = None, device: str | None = "Phone"
) -> SequenceMember:
    return SequenceMember(rid, seq, T0 + timedelta(seconds=seconds), device, (x, 0.0), rid)


def test_stated_sequence_ids_group_in_capture_order() -> None:
    members = [
        _member(1, 30, 0, seq="a"),
        _member(2, 10, 500, seq="a"),  # far and early: a stated walk is a walk whatever its gaps
        _member(3, 20, 0, seq="b"),
        _member(4, 25, 5, seq="b"),
        _member(5, 0, 0, seq="c"),  # alone: no sequence
    ]
    assert sorted(group_sequences(members)) == [[2, 1], [3, 4]]


def test_one_devices_consecutive_captures_split_at_60_s_and_50_m() -> None:
    members = [
        _member(1, 0, 0),
        _member(2, 20, 8),
        _member(3, 75, 16),  # 55 s after the previous one: same walk
        _member(4, 140, 24),  # 65 s later: a new walk
        _member(5, 150, 30),
        _member(6, 160, 90),  # 60 m away: a new walk, alone
        _member(7, 20, 8, device="Other"),  # another camera at the same time and place
        _member(8, 25, 9, device="Other"),
    ]
    assert sorted(group_sequences(members)) == [[1, 2, 3], [4, 5], [7, 8]]


def test_photos_without_time_or_with_mixed_clocks_are_not_grouped() -> None:
    aware = SequenceMember(2, None, (T0 + timedelta(seconds=5)).replace(tzinfo=UTC), "Phone", (1.0, 0.0), 2)
    untimed = SequenceMember(3, None, None, "Phone", (2.0, 0.0), 3)
    assert group_sequences([_member(1, 0, 0), aware, untimed]) == []
    # No camera named: grouped by nothing but a sequence id.
    assert group_sequences([_member(1, 0, 0, device=None), _member(2, 5, 1, device=None)]) == []
    assert group_sequences([_member(1, 0, 0, seq="s", device=None), _member(2, 5, 1, seq="s", device=None)]) == [[1, 2]]
    assert photo_device(" Apple ", "iPhone 12") == "Apple iPhone 12" and photo_device(None, " ") is None


def test_the_lund_photos_group_into_one_walk_in_capture_order() -> None:
    """29 phone photos of one walk (one Mapillary sequence id, a compass each): one walk, in capture order."""
    paths = sorted(shared_path("data", "lund", "images").glob("*.jpg"))
    photos = [load_photo(path) for path in paths]
    assert len(photos) == 29 and all(p.capture.compass is not None for p in photos)
    times = [p.capture.time for p in photos]
    assert None not in times and times == sorted(t for t in times if t is not None)
    members = [
        SequenceMember(path.name, p.capture.sequence_id, p.capture.time, None, (0.0, 0.0), i)
        for i, (path, p) in enumerate(zip(paths, photos, strict=True))
    ]
    assert group_sequences(members) == [[path.name for path in paths]]
    # Without their sequence id (and with a camera named) they are still one walk: seconds and metres apart.
    unstated = [SequenceMember(m.reference_id, None, m.capture_time, "iPhone", m.gps_xy, m.order) for m in members]
    assert group_sequences(unstated) == [[path.name for path in paths]]


def _frame(x: float, y: float, yaw: float, gps: tuple[float, float], compass: float | None) -> SequenceFrame:
    return SequenceFrame(
        x,
        y,
        yaw,
        np.diag([4.0, 0.25]),
        gps,
        8.0,
        None if compass is None else HeadingPrior(compass, 20.0, 0.2),
        Features.empty((480, 640)),
        MapAnchors(np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, int), np.zeros(0)),
        Intrinsics(640, 480, 550.0, 320.0, 240.0),
    )


def _walk(n: int = 8, step_m: float = 7.0) -> list[tuple[float, float, float]]:
    """A walk east along y = 0, looking along the street (yaw 90) and at the north facades (yaw 0) in turn."""
    return [(step_m * i, 0.0, 90.0 if i % 2 == 0 else 0.0) for i in range(n)]


def _edges(truth: list[tuple[float, float, float]], steps: tuple[int, ...] = (1, 2)) -> list[RelativePose]:
    edges = []
    for i in range(len(truth)):
        for s in steps:
            j = i + s
            if j < len(truth):
                for a, b in ((i, j), (j, i)):
                    f, left, turn = pose_in_frame(truth[a][:2], truth[a][2], truth[b][:2], truth[b][2])
                    edges.append(RelativePose(a, b, f, left, turn, 50))
    return edges


def _angle(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_pose_in_frame_reads_forward_left_and_turn() -> None:
    assert pose_in_frame((0.0, 0.0), 90.0, (5.0, 2.0), 80.0) == pytest.approx((5.0, 2.0, -10.0))
    assert pose_in_frame((1.0, 1.0), 0.0, (1.0, 4.0), 350.0) == pytest.approx((3.0, 0.0, -10.0))


def test_the_walk_overrules_a_mirrored_label_and_averages_the_labels_shift() -> None:
    truth = _walk()
    rng = np.random.default_rng(0)
    shifts = rng.normal(0.0, 2.0, len(truth))  # each label off along the street, as facades allow
    frames = []
    for i, (x, y, yaw) in enumerate(truth):
        label_yaw = (yaw + 180.0) % 360.0 if i == 3 else yaw + rng.normal(0, 0.3)  # frame 3: the mirror view
        frames.append(_frame(x + shifts[i], y + (6.0 if i == 3 else 0.0), label_yaw, (x + 1.0, y - 1.0), yaw))
    placed = place_sequence(frames, PlacementOptions(), _edges(truth))
    headings = [_angle(p.yaw_deg, t[2]) for p, t in zip(placed, truth, strict=True)]
    assert max(headings) < 1.0, headings  # the mirrored frame too
    errors = [math.hypot(p.x_m - t[0], p.y_m - t[1]) for p, t in zip(placed, truth, strict=True)]
    label_errors = [math.hypot(f.x_m - t[0], f.y_m - t[1]) for f, t in zip(frames, truth, strict=True)]
    assert errors[3] < 2.5 < label_errors[3]
    assert np.median(errors) < np.median(label_errors)
    n = len(truth)
    assert [p.n_edges for p in placed] == [2 * sum(0 < abs(i - j) <= 2 for j in range(n)) for i in range(n)]
    # The covariances are the graph's: positive, and tighter than a label's own along-street variance.
    for p in placed:
        eig = np.linalg.eigvalsh(p.position_covariance)
        assert eig.min() > 0 and eig.max() < 4.0


def test_without_edges_each_frame_keeps_about_its_label() -> None:
    truth = _walk(4)
    frames = [_frame(x + 1.0, y, yaw, (x + 1.0, y), None) for x, y, yaw in truth]
    placed = place_sequence(frames, PlacementOptions(), [])
    assert all(p.n_edges == 0 for p in placed)
    for p, f in zip(placed, frames, strict=True):
        assert math.hypot(p.x_m - f.x_m, p.y_m - f.y_m) < 0.1 and _angle(p.yaw_deg, f.yaw_deg) < 0.1


def test_a_wrong_edge_does_not_pull_the_walk_apart() -> None:
    truth = _walk(6)
    frames = [_frame(x, y, yaw, (x, y), yaw) for x, y, yaw in truth]
    edges = _edges(truth)
    bad = edges[0]
    edges[0] = RelativePose(bad.source, bad.target, bad.forward_m + 12.0, bad.left_m - 9.0, bad.turn_deg + 40.0, 13)
    placed = place_sequence(frames, PlacementOptions(), edges)
    errors = [math.hypot(p.x_m - t[0], p.y_m - t[1]) for p, t in zip(placed, truth, strict=True)]
    assert max(errors) < 0.5, errors


def _offset_walk(offset_m: float, corner_frames: tuple[int, ...], times: bool) -> list[SequenceFrame]:
    """A 10-frame walk whose GPS fixes are all ``offset_m`` east of the truth, as a phone's drift puts them.

    Its labels, where the map says nothing along the street, sit at the fixes with a wide along-street spread;
    the ``corner_frames`` see the end of a block and are labelled at the truth. times: a capture every 5 s.
    """
    frames = []
    for i, (x, y, yaw) in enumerate(_walk(10)):
        corner = i in corner_frames
        frame = _frame(x + (0.0 if corner else offset_m), y, yaw, (x + offset_m, y), yaw)
        spread = np.diag([1.0, 0.25]) if corner else np.diag([40.0, 0.25])
        frames.append(replace(frame, position_covariance=spread, capture_time_s=5.0 * i if times else None))
    return frames


def _split_edges(split: bool) -> list[RelativePose]:
    """The walk's edges; split: none between frames 0-4 and 5-9 (the two parts see no common facade)."""
    return [e for e in _edges(_walk(10)) if not split or (e.source < 5) == (e.target < 5)]


def _east_errors(placed: list[PlacedPose]) -> np.ndarray:
    return np.array([p.x_m - t[0] for p, t in zip(placed, _walk(10), strict=True)])


def test_fixes_off_together_do_not_pin_the_walk_the_map_places() -> None:
    frames, edges = _offset_walk(5.0, (8, 9), times=False), _split_edges(False)
    correlated = _east_errors(place_sequence(frames, PlacementOptions(), edges))
    independent = _east_errors(place_sequence(frames, PlacementOptions(gps_correlation_m=None), edges))
    # Ten fixes taken as independent outweigh the two corner frames; as one drifting error they do not.
    assert np.abs(correlated).max() < 1.0, correlated
    assert independent.min() > 3.0, independent


def test_capture_times_join_the_parts_of_a_walk_that_see_nothing_in_common() -> None:
    edges = _split_edges(True)
    with_times = _east_errors(place_sequence(_offset_walk(5.0, (8, 9), True), PlacementOptions(), edges))
    without = _east_errors(place_sequence(_offset_walk(5.0, (8, 9), False), PlacementOptions(), edges))
    # The first part sees no corner: its steps to the second part, which does, bring it nearer.
    assert np.abs(with_times[:5]).max() < np.abs(without[:5]).min() - 0.5, (with_times, without)
    assert np.abs(with_times[5:]).max() < 1.0


def test_a_frame_its_steps_alone_join_is_joined_to_its_walk() -> None:
    edges = [e for e in _split_edges(False) if 2 not in (e.source, e.target)]
    stepped = place_sequence(_offset_walk(5.0, (8, 9), True), PlacementOptions(), edges)
    unstepped = place_sequence(_offset_walk(5.0, (8, 9), False), PlacementOptions(), edges)
    assert (stepped[2].n_edges, stepped[2].n_steps, stepped[2].joined) == (0, 2, True)
    assert (unstepped[2].n_edges, unstepped[2].n_steps, unstepped[2].joined) == (0, 0, False)
    assert [p.n_steps for p in stepped] == [1] + [2] * 8 + [1]
    # Its steps bring it along with its neighbours, nearer the truth than its label at the drifted fix.
    assert abs(_east_errors(stepped)[2]) < abs(_east_errors(unstepped)[2]) - 0.5


def test_steps_alone_overrule_a_label_only_from_farther_than_a_few_metres() -> None:
    def pose(x_m: float, n_edges: int, n_steps: int) -> PlacedPose:
        return PlacedPose(x_m, 0.0, 90.0, np.eye(2), n_edges, n_steps)

    assert keeps_own_label(pose(9.0, 0, 0), 0.0, 0.0)  # nothing joins it
    assert keeps_own_label(pose(STEPS_OVERRULE_M - 0.5, 0, 2), 0.0, 0.0)  # its steps agree with its label
    assert not keeps_own_label(pose(STEPS_OVERRULE_M + 0.5, 0, 1), 0.0, 0.0)  # its steps put it elsewhere
    assert not keeps_own_label(pose(0.5, 1, 0), 0.0, 0.0)  # a relative pose joins it: the walk's pose, however near


def test_walk_pace_is_the_median_speed_and_the_robust_spread_of_the_steps_about_it() -> None:
    times = [f.capture_time_s for f in _offset_walk(0.0, (), times=True)]  # 7 m every 5 s
    edges = _edges(_walk(10), steps=(1, 2))
    exact = walk_pace(times, edges, 3)
    assert exact is not None and exact.speed_m_s == pytest.approx(1.4) and exact.spread_m == pytest.approx(0.0)
    # Steps 1 m longer and shorter than 7 m in turn, and one edge a facade's repeated windows put 6 m short:
    # the spread is the steps' (1.48 x their median absolute residual of 1 m), the wrong edge set aside.
    step_m = [7.0 + (1.0 if i % 2 else -1.0) for i in range(9)]
    uneven = [RelativePose(a, b, step_m[i], 0.0, 0.0, 50) for i in range(9) for a, b in ((i, i + 1), (i + 1, i))]
    uneven[8] = replace(uneven[8], forward_m=1.0)  # frame 4 to 5
    pace = walk_pace(times, uneven, 3)
    assert pace is not None and pace.speed_m_s == pytest.approx(1.4, abs=0.25)
    assert pace.spread_m == pytest.approx(1.4826, abs=0.3), pace
    assert walk_pace(times, edges[:4], 3) is None  # frames 0-1 both ways, 0-2 both ways: 2 samples
    assert walk_pace([None] * len(times), edges, 3) is None  # no capture times


def test_the_pace_rules_out_an_edge_three_step_sigmas_off_speed_times_time() -> None:
    pace, times = WalkPace(speed_m_s=1.4, spread_m=1.0), [0.0, 5.0, 10.0, None]  # 7 m a step, sigma 1 m

    def edge(source: int, target: int, distance_m: float) -> RelativePose:
        return RelativePose(source, target, distance_m, 0.0, 0.0, 50)

    assert not rules_out(pace, times, edge(0, 1, 7.0 + 2.9), 0.5, 3.0)
    assert rules_out(pace, times, edge(1, 0, 7.0 - 3.1), 0.5, 3.0)
    assert rules_out(pace, times, edge(0, 1, 0.2), 0.5, 3.0)  # a facade's repeated windows: on the source
    assert not rules_out(pace, times, edge(0, 2, 14.0 - 4.0), 0.5, 3.0)  # two steps: sigma x sqrt(2)
    assert rules_out(pace, times, edge(0, 2, 14.0 - 4.5), 0.5, 3.0)
    assert not rules_out(WalkPace(1.4, 0.1), times, edge(0, 1, 6.0), 0.5, 3.0)  # the floor: 0.5 m, not 0.1
    assert not rules_out(pace, times, edge(0, 1, 0.2), 0.5, math.inf)  # no gate
    assert not rules_out(None, times, edge(0, 1, 0.2), 0.5, 3.0)  # no pace measured
    assert not rules_out(pace, times, edge(2, 3, 0.2), 0.5, 3.0)  # no capture time


def test_an_edge_the_pace_rules_out_keeps_only_its_turn() -> None:
    """A frame whose every edge puts it one step back (a facade's repeated windows) is placed by the rest."""
    truth = _walk(8)  # 7 m every 5 s
    frames = [replace(_frame(x, y, yaw, (x, y), yaw), capture_time_s=5.0 * i) for i, (x, y, yaw) in enumerate(truth)]
    aliased = [*truth[:7], (truth[6][0], 0.0, truth[7][2])]  # frame 7 seen where frame 6 stands
    edges = [e for e in _edges(truth) if 7 not in (e.source, e.target)]
    edges += [e for e in _edges(aliased) if 7 in (e.source, e.target)]
    gated = place_sequence(frames, PlacementOptions(), edges)[7]
    trusted = place_sequence(frames, PlacementOptions(edge_pace_gate=math.inf), edges)[7]
    assert abs(trusted.x_m - truth[7][0]) > 3.0, trusted  # the four wrong edges outweigh its label and step
    assert abs(gated.x_m - truth[7][0]) < 1.0 and _angle(gated.yaw_deg, truth[7][2]) < 1.0, gated
    assert gated.n_edges == trusted.n_edges == 4  # still joined: the edges' turns stand


def test_the_maps_spread_is_wide_along_a_uniform_wall_and_narrow_where_it_ends() -> None:
    wall = city_map_from_footprints([box(-100, 10, 100, 30)], heights_m=[15.0])  # 200 m long, 10 m north
    offsets = bin_offsets_deg(Intrinsics.from_hfov(640, 480, 60.0))

    def east_sigma_m(x_m: float, yaw_deg: float) -> float:
        model = image_model_from_map(cast_panoramas(wall, np.array([[x_m, 0.0]])), 0, yaw_deg, offsets, False)
        return math.sqrt(map_position_covariance(wall, model, x_m, 0.0, yaw_deg)[0, 0])

    assert east_sigma_m(0.0, 0.0) > 5.0  # the middle of the wall: anywhere along it looks the same
    assert east_sigma_m(100.0, 0.0) < 2.5  # its east end ahead, the wall half the view
    # Its end at the edge of a view it fills a tenth of: too little facade to weigh (labeling.says_little).
    assert east_sigma_m(96.0, 45.0) == MAP_SPREAD_HALF_SIZE_M
