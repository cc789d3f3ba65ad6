"""The method on a small simulated Helsinki world (ground-truth labels, so segmentation is not under test)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from contracts.settings import models_dir, shared_path
from geoloc.evaluation.figures import HEIGHT, WIDTH, write_world_figures
from geoloc.evaluation.queries import IDENTITY_LOSS_PARTS
from geoloc.evaluation.references import label_references, references_at_truth
from geoloc.evaluation.world import KS, EvalRun, default_runs, evaluate_world
from geoloc.localize.query import QueryConfig
from geoloc.localize.reference import label_reference_photo
from geoloc.localize.retrieval import default_vocabulary
from geoloc.localize.sbow_index import SbowIndex
from geoloc.localize.transfer import rerank_by_inliers
from geoloc.photos.photo import load_photo
from geoloc.sim.world import WorldOptions, generate_world, load_world
from geoloc.vision.evidence import analyze_photo
from workers.context import method_context

pytestmark = pytest.mark.slow  # the real method end to end: minutes


@pytest.fixture(scope="module")
def world_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("world")
    opts = WorldOptions(n_references=20, n_queries=6, seed=3, radius_m=120.0)
    generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), out, opts)
    return out


@pytest.fixture(scope="module")
def labelled(world_dir: Path) -> dict:
    world = load_world(world_dir)
    city = world.load_map()
    out = {}
    for image in world.references:
        photo = load_photo(image.path)
        evidence = analyze_photo(photo, world.gt(image.name)["labels"], context=method_context())
        gps_xy = tuple(float(v) for v in city.frame.to_local(*photo.gps))
        out[image.name] = label_reference_photo(city, photo, gps_xy, evidence=evidence, context=method_context())
    return out


def _angle(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_reference_labelling_recovers_headings(world_dir: Path, labelled: dict) -> None:
    world = load_world(world_dir)
    errors = np.array([_angle(labelled[im.name].label.yaw_deg, im.pose.yaw_deg) for im in world.references])
    # GPS is 5 m off; most references get their heading within 6 deg (a few flip across the street).
    assert np.mean(errors <= 6.0) >= 0.7, errors.round(1)
    # Their identities are mostly right on ground-truth building pixels.
    accuracy = []
    for image in world.references:
        truth = world.gt(image.name)["building_id"]
        predicted = labelled[image.name].identity.pixel_ids()
        accuracy.append(np.mean(predicted[truth >= 0] == truth[truth >= 0]))
    assert np.median(accuracy) > 0.7


def test_retrieval_finds_the_reference_sharing_most_building_area(world_dir: Path, labelled: dict) -> None:
    world = load_world(world_dir)
    vocabulary = default_vocabulary(models_dir())
    names = list(labelled)
    index = SbowIndex(vocabulary.n_words)
    for doc_id, name in enumerate(names):
        index.add_words(doc_id, vocabulary.words(labelled[name].evidence.features.descriptors))
    hits = []
    for image in world.queries:
        shares = {b["building_id"]: b["pixel_share"] for b in image.record["buildings"]}
        overlap = {
            ref.name: sum(min(s, r.get(b, 0.0)) for b, s in shares.items())
            for ref in world.references
            for r in [{b["building_id"]: b["pixel_share"] for b in ref.record["buildings"]}]
        }
        top = max(overlap.values())
        if top < 0.1:  # the query shows nothing a reference shows well ("unseen" queries)
            continue
        best = {name for name, value in overlap.items() if value >= top - 0.02}  # ties share the top
        photo = load_photo(image.path)
        evidence = analyze_photo(photo, world.gt(image.name)["labels"], context=method_context())
        shortlist = index.top(vocabulary.words(evidence.features.descriptors), 20)
        candidates = [(names[doc], score, labelled[names[doc]].evidence.features) for doc, score in shortlist]
        top4 = [m.reference_id for m in rerank_by_inliers(evidence.features, candidates, 4)]
        hits.append(bool(best & set(top4)))
    assert hits and np.mean(hits) >= 0.6, hits


def test_evaluation_writes_every_key(world_dir: Path, tmp_path: Path) -> None:
    config = QueryConfig()
    runs = [run for run in default_runs(config) if run.name == "gt_segmentation/gps"]
    runs.append(
        EvalRun(
            "paper_geometry/gps", "gps", "gt", "transferred", replace(config, use_anchors=False, use_identity=False)
        )
    )
    result = evaluate_world(world_dir, config=config, runs=runs, max_queries=3, context=method_context())
    assert result["tables_segmentation"] == "gt" and result["config"] == config.as_dict()
    labelling = result["reference_labelling"]["gt"]
    assert set(labelling["identity_accuracy"]) == {"greedy", "marginalized"}
    assert labelling["heading_error_deg"]["n"] == 20 and labelling["timing_ms"]["labeling"] > 0
    for source in ("ours", "gt_reference_labels", "ours_shown_queries"):
        assert set(result["query_identity_accuracy"][source]) == {str(k) for k in KS}
    losses = result["query_identity_losses"]
    assert set(losses) == set(IDENTITY_LOSS_PARTS)
    if losses["right"] is not None:  # some query shows a building a reference shows
        assert abs(sum(losses.values()) - 1.0) < 1e-3
        assert abs(losses["right"] - result["query_identity_accuracy"]["ours_shown_queries"]["4"]) < 1e-3
    assert result["gps_baseline"]["n"] == 3
    assert set(result["runs"]) == {"gt_segmentation/gps", "paper_geometry/gps"}
    for run in result["runs"].values():
        assert run["all"]["n"] == 3 and len(run["per_query"]) == 3
        errors = [run["top_n_error_m"][str(n)]["mean"] for n in range(1, 11)]
        assert errors == sorted(errors, reverse=True)  # best of more answers is never worse
        assert 0.0 <= run["all"]["within_5m"] <= run["all"]["within_10m"] <= 1.0
        row = run["per_query"][0]
        assert {
            "error_m",
            "heading_error_deg",
            "kind",
            "shown",
            "source",
            "uncertainty_radius_m",
            "identity_accuracy",
        } <= set(row)
    assert result["runs"]["paper_geometry/gps"]["anchored_share"] == 0.0  # the paper's method has no anchors
    assert result["runs"]["paper_geometry/gps"]["config"]["use_identity"] is False
    figures = write_world_figures(result, tmp_path / "eval.json")  # what `geoloc eval world --json` writes beside it
    assert [p.name for p in figures] == ["eval.error_cdf.png", "eval.top_n.png"]
    assert all(Image.open(p).size == (WIDTH, HEIGHT) for p in figures)


def _anchor_agreement(anchors_building_id: np.ndarray, xy: np.ndarray, truth: np.ndarray) -> float:
    """Share of anchored keypoints on a building whose anchor names the renderer's building there."""
    h, w = truth.shape
    at = truth[np.clip(np.round(xy[:, 1]).astype(int), 0, h - 1), np.clip(np.round(xy[:, 0]).astype(int), 0, w - 1)]
    used = (anchors_building_id >= 0) & (at >= 0)
    return float(np.mean(anchors_building_id[used] == at[used]))


def test_references_at_truth_are_cast_from_their_manifest_poses(world_dir: Path) -> None:
    world = load_world(world_dir)
    city = world.load_map()
    vocabulary = default_vocabulary(models_dir())
    labelled = label_references(world, city, vocabulary, "gt", lambda _msg: None, method_context())
    stored = references_at_truth(world, city, labelled, vocabulary).load([im.name for im in world.references])
    placed, at_truth = [], []
    for image in world.references:
        ref, pose = stored[image.name], image.pose
        np.testing.assert_allclose(ref.position_xy, (pose.x_m, pose.y_m), atol=1e-6)
        valid = ref.anchors.valid
        xyz = ref.anchors.xyz[valid]
        # Each anchor lies as far from the true camera as it says: cast from there.
        np.testing.assert_allclose(
            np.hypot(xyz[:, 0] - pose.x_m, xyz[:, 1] - pose.y_m), ref.anchors.distance_m[valid], rtol=1e-4
        )
        truth = world.gt(image.name)["building_id"]
        at_truth.append(_anchor_agreement(ref.anchors.building_id, ref.features.xy, truth))
        own = labelled.labelled[image.name]
        placed.append(_anchor_agreement(own.anchors.building_id, own.cues.features.xy, truth))
    # From the true poses the anchors name the buildings the renderer drew, more often than from the labels.
    assert np.median(at_truth) >= 0.9 and np.mean(at_truth) > np.mean(placed), (at_truth, placed)
