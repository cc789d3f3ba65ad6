"""A walk frame read back from the store places its walk bit-identically to the frame labelled in process."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from contracts.references import WalkFrameArrays
from contracts.settings import shared_path
from db.blobs import pack_arrays, unpack_arrays
from geoloc.core.geo import angle_difference_deg
from geoloc.evaluation.walks import compass_prior_at
from geoloc.localize.reference import LabelledReference, label_reference_photo
from geoloc.localize.sequence.frames import FrameLabel
from geoloc.localize.sequence.relative import RelativePose
from geoloc.localize.sequence.stage import (
    COMPASS_AGREES_DEG,
    LabelledFrame,
    capture_seconds,
    compass_relabelled,
    place_labelled_sequence,
)
from geoloc.maps import CityMap
from geoloc.photos.photo import load_photo
from geoloc.sim.world import WorldOptions, generate_world, load_world
from geoloc.vision.evidence import analyze_photo
from workers.context import method_context

pytestmark = pytest.mark.slow  # a walk world labelled by the real method: a minute

ORIGINAL_SIZE = (640, 480)  # the uploaded photo's (width, height), stored beside the frame


@pytest.fixture(scope="module")
def walk(tmp_path_factory: pytest.TempPathFactory) -> tuple[CityMap, list[LabelledFrame]]:
    out = tmp_path_factory.mktemp("walk_world")
    opts = WorldOptions(n_references=8, n_queries=1, seed=1, radius_m=120.0, capture="walk")
    generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), out, opts)
    world = load_world(out)
    city = world.load_map()
    frames = []
    for image in world.references:
        photo = load_photo(image.path)
        evidence = analyze_photo(photo, world.gt(image.name)["labels"], context=method_context())
        assert photo.gps is not None
        xy = (float(v) for v in city.frame.to_local(*photo.gps))
        gps_xy = (next(xy), next(xy))
        labelled = label_reference_photo(city, photo, gps_xy, evidence=evidence, context=method_context())
        alone = FrameLabel.of(labelled, photo.intrinsics)
        prior, taken = compass_prior_at(photo, city, gps_xy), capture_seconds(photo.capture.time)
        frames.append(LabelledFrame(alone, gps_xy, heading_prior=prior, capture_time_s=taken))
    return city, frames


def _stored(frame: LabelledFrame) -> LabelledFrame:
    """The frame as the sequence job reads it back: its arrays through the store's blob format."""
    blob = pack_arrays(frame.alone.stored(ORIGINAL_SIZE).to_arrays())
    alone = FrameLabel.from_stored(WalkFrameArrays.from_arrays(unpack_arrays(blob)))
    return replace(frame, alone=alone)


def _arrays(ref: LabelledReference) -> dict[str, np.ndarray]:
    return ref.keypoints().to_arrays() | {f"label_{k}": v for k, v in ref.label_arrays().to_arrays().items()}


def test_stored_frame_arrays_read_back_bit_identically(walk: tuple[CityMap, list[LabelledFrame]]) -> None:
    _, frames = walk
    for frame in frames:
        stored = _stored(frame).alone
        assert stored.cues.building_mask.dtype == bool
        np.testing.assert_array_equal(frame.alone.cues.building_mask, stored.cues.building_mask)
        assert (stored.intrinsics, stored.timings_ms) == (frame.alone.intrinsics, frame.alone.timings_ms)
        before = frame.alone.stored(ORIGINAL_SIZE).to_arrays()
        after = stored.stored(ORIGINAL_SIZE).to_arrays()
        assert before.keys() == after.keys()
        for name, value in before.items():
            assert value.dtype == after[name].dtype, name
            np.testing.assert_array_equal(value, after[name], err_msg=name)


def test_a_walk_frame_without_a_required_array_is_refused_by_name(walk: tuple[CityMap, list[LabelledFrame]]) -> None:
    arrays = walk[1][0].alone.stored(ORIGINAL_SIZE).to_arrays()
    assert WalkFrameArrays.from_arrays(arrays).original_size == ORIGINAL_SIZE
    del arrays["building_mask_width"]
    with pytest.raises(KeyError, match="building_mask_width"):
        WalkFrameArrays.from_arrays(arrays)


def test_a_walk_placed_from_stored_frames_is_bit_identical(walk: tuple[CityMap, list[LabelledFrame]]) -> None:
    city, frames = walk
    live = place_labelled_sequence(city, frames)
    stored = place_labelled_sequence(city, [_stored(frame) for frame in frames])
    assert live.n_edges == stored.n_edges and live.n_edges > 0
    for a, b in zip(live.poses, stored.poses, strict=True):
        assert (a.x_m, a.y_m, a.yaw_deg, a.n_edges) == (b.x_m, b.y_m, b.yaw_deg, b.n_edges)
        np.testing.assert_array_equal(a.position_covariance, b.position_covariance)
    assert [r is None for r in live.references] == [r is None for r in stored.references]
    for ref_a, ref_b in zip(live.references, stored.references, strict=True):
        if ref_a is None or ref_b is None:
            continue
        assert ref_a.analysis is not None and ref_b.analysis is None  # the stored one never analysed the photo
        arrays_a, arrays_b = _arrays(ref_a), _arrays(ref_b)
        assert arrays_a.keys() == arrays_b.keys()
        for name, value in arrays_a.items():
            np.testing.assert_array_equal(value, arrays_b[name], err_msg=name)


def _flipped(frames: list[LabelledFrame]) -> tuple[int, list[LabelledFrame]]:
    """The walk with one frame's label turned to face away from its compass (the mirror view's 180 deg)."""
    agreeing = [
        k
        for k, frame in enumerate(frames)
        if frame.heading_prior is not None
        and angle_difference_deg(frame.alone.yaw_deg, frame.heading_prior.mean_bearing_deg) < 10
    ]
    assert len(agreeing) >= 3, "the walk world's compasses should mostly agree with the labels"
    k = agreeing[len(agreeing) // 2]
    turned = replace(frames[k], alone=replace(frames[k].alone, yaw_deg=(frames[k].alone.yaw_deg + 180.0) % 360.0))
    return k, [turned if i == k else frame for i, frame in enumerate(frames)]


def _facing_away(frames: list[LabelledFrame]) -> set[int]:
    """The frames whose label is more than 90 deg from their compass."""
    return {
        k
        for k, frame in enumerate(frames)
        if frame.heading_prior is not None
        and angle_difference_deg(frame.alone.yaw_deg, frame.heading_prior.mean_bearing_deg) > 90
    }


def _witnesses(frames: list[LabelledFrame], k: int, target_yaw_deg: float) -> list[RelativePose]:
    """Edges into frame k from every other frame that predict ``target_yaw_deg`` for it."""
    return [
        RelativePose(j, k, 5.0, 0.0, (target_yaw_deg - frame.alone.yaw_deg + 180.0) % 360.0 - 180.0, 40)
        for j, frame in enumerate(frames)
        if j != k
    ]


def test_a_label_facing_away_from_a_trusted_compass_is_done_again(walk: tuple[CityMap, list[LabelledFrame]]) -> None:
    city, frames = walk
    k, turned = _flipped(frames)
    compass = turned[k].heading_prior
    assert compass is not None
    again = compass_relabelled(city, turned, [], 0.5)
    assert set(again) == {k} | _facing_away(frames)  # the turned frame and those the map alone turned
    assert angle_difference_deg(again[k].label.yaw_deg, compass.mean_bearing_deg) <= COMPASS_AGREES_DEG
    # Back to the label before the turn:
    assert angle_difference_deg(again[k].label.yaw_deg, frames[k].alone.yaw_deg) < 10
    assert "relabeling" in again[k].timings_ms
    assert compass_relabelled(city, turned, [], None) == {}  # switched off


def test_a_walk_whose_compass_disagrees_keeps_its_labels(walk: tuple[CityMap, list[LabelledFrame]]) -> None:
    city, frames = walk
    _, turned = _flipped(frames)
    wrong = [
        replace(
            f, heading_prior=replace(f.heading_prior, mean_bearing_deg=(f.heading_prior.mean_bearing_deg + 180) % 360)
        )
        if f.heading_prior is not None
        else f
        for f in turned
    ]
    # Every label but one now faces away from its compass: the walk's magnetometer is the one that is wrong.
    assert compass_relabelled(city, wrong, [], 0.5) == {}


def test_neighbours_that_side_with_the_old_label_keep_it(walk: tuple[CityMap, list[LabelledFrame]]) -> None:
    city, frames = walk
    k, turned = _flipped(frames)
    siding_with_new = _witnesses(turned, k, frames[k].alone.yaw_deg)
    assert k in compass_relabelled(city, turned, siding_with_new, 0.5)
    siding_with_old = _witnesses(turned, k, turned[k].alone.yaw_deg)
    assert k not in compass_relabelled(city, turned, siding_with_old, 0.5)
