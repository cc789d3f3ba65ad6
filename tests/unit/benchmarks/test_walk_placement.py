"""The walk-placement benchmark's perfect labels: each reference labelled at its manifest pose, its cues kept."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.bench_walk_placement import labels_at_truth
from contracts.settings import shared_path
from geoloc.evaluation.references import label_alone
from geoloc.sim.world import WorldOptions, generate_world, load_world
from workers.context import method_context

pytestmark = pytest.mark.slow  # a small walk world labelled alone: half a minute


def test_labels_at_truth_sit_at_the_manifest_poses_with_their_anchors_cast_from_there(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    out = tmp_path_factory.mktemp("walk_world")
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        out,
        WorldOptions(n_references=6, n_queries=1, seed=2, radius_m=120.0, capture="walk"),
    )
    world = load_world(out)
    city = world.load_map()
    photos, alone = label_alone(world, city, "gt", lambda _msg: None, method_context())
    at_truth = labels_at_truth(world, city, photos, alone)
    assert list(at_truth) == [image.name for image in world.references]
    moved = 0
    for image in world.references:
        label, truth, before = at_truth[image.name].label, image.pose, alone[image.name]
        assert (label.x_m, label.y_m, label.yaw_deg) == pytest.approx((truth.x_m, truth.y_m, truth.yaw_deg))
        np.testing.assert_array_equal(label.position_covariance, before.label.position_covariance)
        assert at_truth[image.name].cues is before.cues
        if math.hypot(before.label.x_m - truth.x_m, before.label.y_m - truth.y_m) > 0.5:
            moved += 1
            # Anchors are the keypoints' points on the map seen from the label's pose: from the truth, not alone's.
            assert not np.array_equal(at_truth[image.name].anchors.xyz, before.anchors.xyz, equal_nan=True)
    assert moved > 0  # some label alone was off, or the test shows nothing
