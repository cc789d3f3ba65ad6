"""Diagnostic: whether the map knows where a placed walk's wrong references belong.

    .venv/bin/python research/walk_map_evidence.py --world /tmp/worlds/hw1 --world /tmp/worlds/bw1 \
        [--json evidence.json]

Each world's references are labelled alone and their walks placed as ``bench_walk_placement.py`` does (the
workers' label and sequence stages, default options). Then, for every frame, what the map itself says: the
sharpened log-likelihood (geometry only, the frame's own image model, :class:`geoloc.localize.labeling.LabelOptions`'
likelihood and sharpness, as the labels weigh poses) at its true pose minus at its placed pose. A frame off by
more than 2 m whose gain is below ``--gain`` (default 1, a factor e) cannot be told from its placed pose by the
map. And for every walk, the common shift of all its placed frames (a grid of +-16 m at 1 m, headings kept)
that the summed map score prefers, beside the true mean offset: a walk shifted by its GPS drift along a
uniform street is fixed by such a shift only where the map knows it.

A cue the likelihood does not read yet, measured on the rendered truth: where one building ends and the next
begins. Per wrong frame, the image's building boundaries (where the ground truth's per-column building id
changes, as bearings from the optical axis) and the share of them that the map's own boundaries (rays cast at
0.25 deg) match within 1 deg, at the true pose and at the placed one; per world, the colour contrast across the
boundaries between two buildings against the contrast inside one (the summed absolute difference of the median
RGB of the building pixels in the 6 columns each side); and how well the plainest detector finds them in the
photo (:func:`column_colour_boundaries`: the network's building mask, each column's mean wall colour over 6
columns either side, peaks above a contrast of 30): its precision and recall against the boundaries between two
buildings, within 3 pixels. Prints per walk and per world; writes JSON.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.evaluation.references import label_world_alone
from geoloc.evaluation.walks import place_photo_walks
from geoloc.localize.labeling import LabelOptions
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.reference import LabelledReference
from geoloc.maps import CityMap
from geoloc.maps.raycast import cast_panoramas
from geoloc.sim.world import World, WorldImage, load_world
from workers.context import method_context

WITHIN_M = 2.0
SHIFT_HALF_M = 16.0
FLOOR = 1e-30
BOUNDARY_STEP_DEG = 0.25
BOUNDARY_MATCH_DEG = 1.0
CONTRAST_COLUMNS = 6
DETECTOR_CONTRAST = 30.0
DETECTOR_MATCH_PX = 3


def sharpened_log(likelihood: np.ndarray, inside: np.ndarray, sharpness: float) -> np.ndarray:
    """``sharpness`` x log of a likelihood, floored; positions inside a building get the floor."""
    score: np.ndarray = sharpness * np.log(np.maximum(likelihood.astype(float), FLOOR))
    score[inside] = sharpness * math.log(FLOOR)
    return score


Frame = tuple[WorldImage, LabelledReference]
"""A walk frame: its image in the world (name, true pose, rendered truth) and its placed label."""


def party_walls(column_ids: np.ndarray) -> np.ndarray:
    """Columns c where one building ends and another begins at c | c + 1 ((W,) building id per column, -1 none)."""
    return np.flatnonzero((column_ids[:-1] != column_ids[1:]) & (column_ids[:-1] >= 0) & (column_ids[1:] >= 0))


def image_boundaries(world: World, image: WorldImage) -> tuple[np.ndarray, np.ndarray]:
    """The rendered truth's building boundaries: their bearings from the optical axis (deg) and their columns."""
    ids = world.gt(image.name)["column_building_id"]
    intrinsics = image.intrinsics
    columns = np.flatnonzero((ids[:-1] != ids[1:]) & ((ids[:-1] >= 0) | (ids[1:] >= 0)))
    bearings = np.degrees(np.arctan((columns + 1.0 - intrinsics.cx) / intrinsics.focal_px))
    return bearings, columns


def map_boundaries(city: CityMap, x_m: float, y_m: float, yaw_deg: float, half_fov_deg: float) -> np.ndarray:
    """The map's building boundaries seen from a pose: bearings from its yaw (deg) within the field of view."""
    panorama = cast_panoramas(city, np.array([[x_m, y_m]]), bearing_step_deg=BOUNDARY_STEP_DEG)
    ids, after = panorama.building_id[0], np.roll(panorama.building_id[0], -1)
    relative = (panorama.bearings_deg + BOUNDARY_STEP_DEG / 2 - yaw_deg + 180.0) % 360.0 - 180.0
    boundary = (ids != after) & ((ids >= 0) | (after >= 0)) & (np.abs(relative) < half_fov_deg)
    return np.asarray(relative[boundary])


def matched_share(image_deg: np.ndarray, map_deg: np.ndarray) -> float:
    """The share of the image's boundaries with a map boundary within :data:`BOUNDARY_MATCH_DEG` (NaN: none)."""
    if not len(image_deg):
        return math.nan
    if not len(map_deg):
        return 0.0
    return float(np.mean(np.abs(image_deg[:, None] - map_deg[None, :]).min(axis=1) <= BOUNDARY_MATCH_DEG))


def boundary_contrasts(world: World, image: WorldImage, image_rgb: np.ndarray) -> tuple[list[float], list[float]]:
    """Colour contrast across the boundaries between two buildings, and across columns inside one building."""
    truth = world.gt(image.name)
    ids, pixel_ids = truth["column_building_id"], truth["building_id"]
    rgb = image_rgb.astype(float)
    width = len(ids)

    def median_colour(first: int, last: int) -> np.ndarray | None:
        pixels = rgb[:, first:last][pixel_ids[:, first:last] >= 0]
        return np.median(pixels, axis=0) if len(pixels) > 5 * CONTRAST_COLUMNS else None

    def contrast(column: int) -> float | None:
        left = median_colour(max(0, column - CONTRAST_COLUMNS + 1), column + 1)
        right = median_colour(column + 1, min(width, column + 1 + CONTRAST_COLUMNS))
        return None if left is None or right is None else float(np.abs(left - right).sum())

    across = [contrast(c) for c in party_walls(ids)]
    inside_columns = range(2 * CONTRAST_COLUMNS, width - 2 * CONTRAST_COLUMNS, 37)
    inside = [
        contrast(c)
        for c in inside_columns
        if ids[c] >= 0 and ids[c - CONTRAST_COLUMNS] == ids[c] == ids[c + CONTRAST_COLUMNS + 1]
    ]
    return [v for v in across if v is not None], [v for v in inside if v is not None]


def column_colour_boundaries(image_rgb: np.ndarray, building_mask: np.ndarray) -> np.ndarray:
    """Columns where the mean colour of the building pixels changes (the plainest boundary detector).

    For each column: the mean RGB of the building pixels in the :data:`CONTRAST_COLUMNS` columns up to it and in
    those after it (each side needs 20 building pixels a column), their summed absolute difference; peaks above
    :data:`DETECTOR_CONTRAST`, at least 5 columns apart, strongest first.
    """
    mask = building_mask.astype(float)
    sums = np.vstack([np.zeros((1, 3)), np.cumsum((image_rgb.astype(float) * mask[..., None]).sum(axis=0), axis=0)])
    counts = np.concatenate([[0.0], np.cumsum(mask.sum(axis=0))])
    half, width = CONTRAST_COLUMNS, building_mask.shape[1]
    columns = np.arange(half, width - half)
    left_n = counts[columns + 1] - counts[columns + 1 - half]
    right_n = counts[columns + 1 + half] - counts[columns + 1]
    enough = (left_n > 20 * half) & (right_n > 20 * half)
    contrast = np.zeros(width)
    kept = columns[enough]
    left = (sums[kept + 1] - sums[kept + 1 - half]) / left_n[enough, None]
    right = (sums[kept + 1 + half] - sums[kept + 1]) / right_n[enough, None]
    contrast[kept] = np.abs(left - right).sum(axis=1)
    peaks: list[int] = []
    for column in np.argsort(-contrast):
        if contrast[column] < DETECTOR_CONTRAST:
            break
        if all(abs(int(column) - peak) > 4 for peak in peaks):
            peaks.append(int(column))
    return np.array(sorted(peaks), dtype=int)


def detector_counts(world: World, image: WorldImage, image_rgb: np.ndarray, building_mask: np.ndarray) -> list[int]:
    """[true, false, missed] boundaries between two buildings of :func:`column_colour_boundaries` on one photo."""
    truth = party_walls(world.gt(image.name)["column_building_id"])
    found = column_colour_boundaries(image_rgb, building_mask)
    hits = [bool(len(truth)) and bool(np.abs(truth - f).min() <= DETECTOR_MATCH_PX) for f in found]
    missed = [not len(found) or bool(np.abs(found - t).min() > DETECTOR_MATCH_PX) for t in truth]
    return [sum(hits), len(found) - sum(hits), sum(missed)]


def walk_evidence(world: World, city: CityMap, frames: list[Frame], options: LabelOptions) -> dict[str, Any]:
    """One walk's figures (the module docstring's) from its frames in walk order."""
    axis = np.arange(-SHIFT_HALF_M, SHIFT_HALF_M + 0.5, 1.0)
    shifts = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
    summed = np.zeros(len(shifts))
    offsets, rows = [], []
    for image, labelled in frames:
        label, truth = labelled.label, image.pose
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
        row: dict[str, Any] = {"name": image.name, "error_m": round(float(np.hypot(*offsets[-1])), 2)}
        row["gain"] = round(float(gain), 2)
        if row["error_m"] > WITHIN_M:
            seen, _ = image_boundaries(world, image)
            half_fov_deg = math.degrees(math.atan(image.intrinsics.cx / image.intrinsics.focal_px))
            row["boundaries"] = len(seen)
            row["boundaries_matched_at_truth"] = matched_share(
                seen, map_boundaries(city, truth.x_m, truth.y_m, truth.yaw_deg, half_fov_deg)
            )
            row["boundaries_matched_at_placed"] = matched_share(
                seen, map_boundaries(city, label.x_m, label.y_m, label.yaw_deg, half_fov_deg)
            )
        rows.append(row)
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
    photos, labelled = label_world_alone(world, city, "model", lambda _: None, method_context())
    place_photo_walks(city, photos, labelled)
    options = LabelOptions()
    walks: dict[str, list[Frame]] = {}
    across, inside = [], []
    detected = np.zeros(3, dtype=int)
    for image in world.references:
        walks.setdefault(str(image.record["walk"]["walk_id"]), []).append((image, labelled[image.name]))
        image_rgb = photos[image.name].image_rgb
        contrasts = boundary_contrasts(world, image, image_rgb)
        across += contrasts[0]
        inside += contrasts[1]
        detected += detector_counts(world, image, image_rgb, labelled[image.name].cues.building_mask)
    figures = {walk_id: walk_evidence(world, city, frames, options) for walk_id, frames in walks.items()}
    wrong = [row for walk in figures.values() for row in walk["frames"] if row["error_m"] > WITHIN_M]
    blind = [row for row in wrong if row["gain"] < gain_limit]
    with_boundary = [row for row in wrong if row["boundaries"] > 0]
    return {
        "walks": figures,
        "wrong": len(wrong),
        "wrong_map_blind": len(blind),
        "references": len(world.references),
        "wrong_showing_a_boundary": len(with_boundary),
        "boundaries_matched_at_truth": _mean(row["boundaries_matched_at_truth"] for row in with_boundary),
        "boundaries_matched_at_placed": _mean(row["boundaries_matched_at_placed"] for row in with_boundary),
        "contrast_across_boundaries_median": _median(across),
        "contrast_inside_buildings_median": _median(inside),
        "detector_precision": round(float(detected[0] / max(1, detected[0] + detected[1])), 2),
        "detector_recall": round(float(detected[0] / max(1, detected[0] + detected[2])), 2),
    }


def _mean(values: Iterable[float]) -> float | None:
    kept = list(values)
    return round(float(np.mean(kept)), 2) if kept else None


def _median(values: list[float]) -> float | None:
    return round(float(np.median(values)), 1) if values else None


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
        print(
            f"  building boundaries: {figures['wrong_showing_a_boundary']} of the {figures['wrong']} wrong references "
            f"show one; the map matches {figures['boundaries_matched_at_truth']} of them at the truth and "
            f"{figures['boundaries_matched_at_placed']} at the placed pose; colour contrast across two buildings "
            f"{figures['contrast_across_boundaries_median']} against {figures['contrast_inside_buildings_median']} "
            f"inside one (median); the plainest detector's precision {figures['detector_precision']}, "
            f"recall {figures['detector_recall']}"
        )
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
