"""Diagnostic: whether the map knows where a placed walk's wrong references belong.

    .venv/bin/python benchmarks/bench_walk_map_evidence.py --world /tmp/worlds/hw1 --world /tmp/worlds/bw1 \
        [--json evidence.json]

Each world's references are labelled alone and their walks placed as ``bench_walk_placement.py`` does (the
workers' label and sequence stages, default options). Then, for every frame, what the map itself says: the
sharpened log-likelihood (geometry only, the frame's own image model, :class:`geoloc.localize.labeling.LabelOptions`'
likelihood and sharpness, as the labels weigh poses) at its true pose minus at its placed pose. A frame off by
more than 2 m whose gain is below ``--gain`` (default 1, a factor e) cannot be told from its placed pose by the
map. And for every walk, the common shift of all its placed frames (a grid of +-16 m at 1 m, headings kept)
that the summed map score prefers, beside the true mean offset: a walk shifted by its GPS drift along a
uniform street is fixed by such a shift only where the map knows it. Prints per walk and per world; writes JSON.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.evaluation.references import label_alone
from geoloc.localize.labeling import LabelOptions
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.reference import LabelledReference
from geoloc.localize.sequence.stage import place_photo_walks
from geoloc.maps import CityMap
from geoloc.sim.pose import Pose
from geoloc.sim.world import load_world
from workers.context import method_context

WITHIN_M = 2.0
SHIFT_HALF_M = 16.0
FLOOR = 1e-30


def sharpened_log(likelihood: np.ndarray, inside: np.ndarray, sharpness: float) -> np.ndarray:
    """``sharpness`` x log of a likelihood, floored; positions inside a building get the floor."""
    score: np.ndarray = sharpness * np.log(np.maximum(likelihood.astype(float), FLOOR))
    score[inside] = sharpness * math.log(FLOOR)
    return score


Frame = tuple[str, LabelledReference, Pose]
"""A walk frame: its name, its placed label (with the photo's image model) and its true pose."""


def walk_evidence(city: CityMap, frames: list[Frame], options: LabelOptions) -> dict[str, Any]:
    """One walk's figures (the module docstring's) from its frames in walk order."""
    axis = np.arange(-SHIFT_HALF_M, SHIFT_HALF_M + 0.5, 1.0)
    shifts = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
    summed = np.zeros(len(shifts))
    offsets, rows = [], []
    for name, labelled, truth in frames:
        label = labelled.label
        likelihood = MapLikelihood(city, labelled.cues.image_model.without_identity(), options.likelihood)
        placed_xy = np.array([label.x_m, label.y_m])
        shifted = shifts + placed_xy
        at_shifts = likelihood.of_poses(shifted, np.array([label.yaw_deg]))[:, 0]
        summed += sharpened_log(at_shifts, city.inside_buildings(shifted), options.sharpness)
        true_xy = np.array([[truth.x_m, truth.y_m]])
        at_truth = likelihood.of_poses(true_xy, np.array([truth.yaw_deg]))[:, 0]
        at_placed = likelihood.of_poses(placed_xy[None], np.array([label.yaw_deg]))[:, 0]
        gain = (
            sharpened_log(at_truth, city.inside_buildings(true_xy), options.sharpness)[0]
            - sharpened_log(at_placed, city.inside_buildings(placed_xy[None]), options.sharpness)[0]
        )
        offsets.append(true_xy[0] - placed_xy)
        rows.append({"name": name, "error_m": round(float(np.hypot(*offsets[-1])), 2), "gain": round(float(gain), 2)})
    offset = np.array(offsets)
    best = shifts[int(np.argmax(summed))]
    zero = int(np.argmin(np.abs(shifts).sum(axis=1)))
    after = np.hypot(*(offset - best).T)
    return {
        "frames": rows,
        "true_mean_offset_m": [round(float(v), 1) for v in offset.mean(axis=0)],
        "best_shift_m": [float(v) for v in best],
        "best_shift_score_gain": round(float(summed.max() - summed[zero]), 1),
        "within_2m": round(float(np.mean(np.hypot(*offset.T) <= WITHIN_M)), 2),
        "within_2m_after_best_shift": round(float(np.mean(after <= WITHIN_M)), 2),
    }


def world_evidence(world_dir: Path, gain_limit: float) -> dict[str, Any]:
    """Every walk of a world, and how many of its wrong references the map cannot tell from their placed poses."""
    world = load_world(world_dir)
    city = world.load_map()
    photos, labelled = label_alone(world, city, "model", lambda _: None, method_context())
    place_photo_walks(city, photos, labelled)
    options = LabelOptions()
    walks: dict[str, list[Frame]] = {}
    for image in world.references:
        walks.setdefault(str(image.record["walk"]["walk_id"]), []).append(
            (image.name, labelled[image.name], image.pose)
        )
    figures = {walk_id: walk_evidence(city, frames, options) for walk_id, frames in walks.items()}
    wrong = [row for walk in figures.values() for row in walk["frames"] if row["error_m"] > WITHIN_M]
    blind = [row for row in wrong if row["gain"] < gain_limit]
    return {"walks": figures, "wrong": len(wrong), "wrong_map_blind": len(blind), "references": len(world.references)}


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--world", type=Path, action="append", required=True)
    parser.add_argument("--gain", type=float, default=1.0, help="a wrong frame below this gain is map-blind")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    report = {}
    for world_dir in args.world:
        figures = world_evidence(world_dir, args.gain)
        report[str(world_dir)] = figures
        print(
            f"{world_dir}: {figures['wrong']} of {figures['references']} references off by more than {WITHIN_M:g} m; "
            f"the map scores the truth less than {args.gain:g} above the placed pose for {figures['wrong_map_blind']}"
        )
        for walk_id, walk in figures["walks"].items():
            print(
                f"  walk {walk_id}: within 2 m {walk['within_2m']:.2f}, "
                f"true mean offset {walk['true_mean_offset_m']} m, "
                f"the map's best shift {walk['best_shift_m']} m (+{walk['best_shift_score_gain']}), "
                f"within 2 m after it {walk['within_2m_after_best_shift']:.2f}"
            )
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
