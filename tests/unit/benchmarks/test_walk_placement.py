"""The walk benchmark's perfect labels: each at its manifest pose, its cues kept; or a share of the wrong ones."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any, cast

import numpy as np
import pytest

from benchmarks.bench_walk_placement import labels_at_truth, labels_partly_at_truth
from contracts.settings import shared_path
from geoloc.evaluation.references import label_world_alone
from geoloc.sim.world import WorldOptions, generate_world, load_world
from workers.context import method_context


@pytest.mark.slow  # a small walk world labelled alone: half a minute
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
    photos, alone = label_world_alone(world, city, "gt", lambda _msg: None, method_context())
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


def _label_at(x_m: float) -> Any:
    return SimpleNamespace(label=SimpleNamespace(x_m=x_m, y_m=0.0))


@pytest.mark.parametrize("share", [0.0, 0.25, 0.5, 1.0])
def test_a_share_of_the_wrong_labels_only_is_taken_from_the_truth(share: float) -> None:
    # Eight references at x = 0..7 m; labels alone 0.5 m off for even ones (right), 5 m off for odd ones (wrong).
    names = [f"ref_{i}" for i in range(8)]
    poses = [SimpleNamespace(name=n, pose=SimpleNamespace(x_m=float(i), y_m=0.0)) for i, n in enumerate(names)]
    world = cast(Any, SimpleNamespace(references=poses))
    alone = {n: _label_at(i + (0.5 if i % 2 == 0 else 5.0)) for i, n in enumerate(names)}
    truth = {n: _label_at(float(i)) for i, n in enumerate(names)}
    draws = [labels_partly_at_truth(world, alone, truth, share, seed) for seed in range(6)]
    for labels in draws:
        assert list(labels) == names
        mended = {n for n in names if labels[n] is truth[n]}
        assert all(labels[n] is alone[n] for n in names if n not in mended)
        assert all(int(n.split("_")[1]) % 2 == 1 for n in mended)  # only wrong labels are mended
        assert len(mended) == round(share * 4)
    if 0.0 < share < 1.0:  # the draw differs between seeds
        assert len({frozenset(n for n in names if d[n] is truth[n]) for d in draws}) > 1
    assert labels_partly_at_truth(world, alone, truth, share, 3) == draws[3]  # and is the same for one seed


def test_a_share_outside_zero_to_one_is_refused() -> None:
    world = cast(Any, SimpleNamespace(references=[]))
    with pytest.raises(ValueError, match="lies in"):
        labels_partly_at_truth(world, {}, {}, 1.5, 0)
