"""Walk-placement options side by side on walk worlds: how each places the references, and its CPU.

    .venv/bin/python benchmarks/bench_walk_placement.py --world /tmp/worlds/hw1 --world /tmp/worlds/bw1 \
        --config independent=gps_correlation_m:none --config loose=step_sigma_fraction:0.3 --json walks.json
    .venv/bin/python benchmarks/bench_walk_placement.py --world /tmp/worlds/hw2 --labels-at-truth
    .venv/bin/python benchmarks/bench_walk_placement.py --world /tmp/worlds/hw2 --truth-share 0.25 --truth-share 0.5

Each world's references are labelled alone once, as the workers' label job labels them (the evaluation's
:func:`geoloc.evaluation.references.label_world_alone`, network segmentation, the compass as heading prior);
then every walk is placed and its frames re-labelled by the workers' sequence stage
(:func:`geoloc.evaluation.walks.place_photo_walks`, as ``geoloc eval world`` runs it) under each
configuration, from the same labels alone. The first configuration is the default ``PlacementOptions()``; each
``--config NAME=FIELD:VALUE,...`` replaces fields of it (``benchmarks/config_args.py``). Printed per world and
configuration: the references' position error (within 1 / 2 m, median) and heading error (within 2 / 5 deg)
against the manifest's truth, as ``reference_labelling`` reports them, how many references moved by more than
0.5 m against the default, and the placement's process CPU as a ratio to the default's. Only the references
are measured: the queries' figures need ``geoloc eval world``.

With ``--labels-at-truth`` one more row, ``at_truth``: the default placement given perfect labels, every
reference labelled at its manifest pose instead of alone (:func:`labels_at_truth`), so what the walks' graph
itself loses (its GPS, steps and edges against right labels) shows apart from what the labels get wrong.

With ``--truth-share S`` (repeatable) rows ``truth_S#D``, D = 0..2: the default placement when a random share S of
the wrong labels (alone more than :data:`WRONG_M` off) is moved to the truth and the others are kept
(:func:`labels_partly_at_truth`, draw D), so how many labels a new cue would have to mend to reach a given share.
"""

from __future__ import annotations

import json
import math
import random
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from config_args import comparison_arguments, parse_config

from geoloc.core.geo import angle_difference_deg
from geoloc.evaluation.references import label_world_alone, relabelled_at_truth
from geoloc.evaluation.summaries import reference_heading_summary, reference_position_summary
from geoloc.evaluation.walks import place_photo_walks
from geoloc.localize.reference import LabelledReference
from geoloc.localize.sequence import PlacementOptions
from geoloc.maps import CityMap
from geoloc.photos.photo import Photo
from geoloc.sim.world import World, load_world
from workers.context import method_context

MOVED_M = 0.5
AT_TRUTH = "at_truth"
"""The row of the default placement given every reference's label at its true pose (``--labels-at-truth``)."""
WRONG_M = 2.0
"""A label alone this far (m) from its true position is wrong (issue 19's references: within 2 m)."""
TRUTH_DRAWS = 3
"""Random draws per ``--truth-share``: which wrong labels are mended changes the figure by several references."""


def labels_at_truth(
    world: World, city: CityMap, photos: dict[str, Photo], alone: dict[str, LabelledReference]
) -> dict[str, LabelledReference]:
    """Every reference of ``world`` labelled at its true pose (the manifest's) instead of alone, by name.

    Each keeps its label alone's cues and position covariance; its identities and anchors come from the true pose
    (:func:`geoloc.evaluation.references.relabelled_at_truth`, as a walk's placed frames are re-labelled).
    """
    return relabelled_at_truth(world, city, alone, {name: photo.intrinsics for name, photo in photos.items()})


def labels_partly_at_truth(
    world: World,
    alone: dict[str, LabelledReference],
    at_truth: dict[str, LabelledReference],
    share: float,
    seed: int,
) -> dict[str, LabelledReference]:
    """``alone`` with ``round(share * n)`` of its n wrong labels (over :data:`WRONG_M` off) taken from ``at_truth``.

    Which wrong labels: a uniform draw seeded by ``seed``. Right labels are always ``alone``'s, in the world's order.
    """
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"a share of the wrong labels lies in [0, 1], not {share}")
    poses = {image.name: image.pose for image in world.references}
    wrong = [
        name
        for name, ref in alone.items()
        if math.hypot(ref.label.x_m - poses[name].x_m, ref.label.y_m - poses[name].y_m) > WRONG_M
    ]
    mended = set(random.Random(seed).sample(wrong, round(share * len(wrong))))
    return {name: at_truth[name] if name in mended else ref for name, ref in alone.items()}


def place_world(
    world_dir: Path,
    configs: dict[str, PlacementOptions],
    say: Any,
    *,
    at_truth: bool = False,
    truth_shares: tuple[float, ...] = (),
) -> dict[str, Any]:
    """Every walk of the world placed under every configuration, from one labelling alone (module docstring).

    Returns per configuration the per-reference ``errors`` (name, position error m, heading error deg), their
    ``position`` and ``heading`` summaries (the evaluation's reference summaries), and ``cpu_s``: this process's CPU
    time around the placement. at_truth: also :data:`AT_TRUTH`, the default options from labels at the truth.
    truth_shares: also ``truth_S#D``, the default options with a share S of the wrong labels at the truth, draw D.
    """
    world = load_world(world_dir)
    city = world.load_map()
    started = time.perf_counter()
    photos, alone = label_world_alone(world, city, "model", lambda _msg: None, method_context())
    say(f"{world_dir}: {len(alone)} references labelled alone in {time.perf_counter() - started:.0f} s")
    runs = [(name, options, alone) for name, options in configs.items()]
    truth = labels_at_truth(world, city, photos, alone) if at_truth or truth_shares else {}
    if at_truth:
        runs.append((AT_TRUTH, PlacementOptions(), truth))
    for share in truth_shares:
        for draw in range(TRUTH_DRAWS):
            labels = labels_partly_at_truth(world, alone, truth, share, draw)
            runs.append((f"truth_{share:g}#{draw}", PlacementOptions(), labels))
    out: dict[str, Any] = {}
    for name, options, labels in runs:
        labelled = dict(labels)
        cpu0 = time.process_time()
        place_photo_walks(city, photos, labelled, options)
        cpu_s = time.process_time() - cpu0
        rows = []
        for image in world.references:
            label, pose = labelled[image.name].label, image.pose
            error_m = math.hypot(label.x_m - pose.x_m, label.y_m - pose.y_m)
            rows.append((image.name, error_m, angle_difference_deg(label.yaw_deg, pose.yaw_deg)))
        out[name] = {
            "position": reference_position_summary([r[1] for r in rows]),
            "heading": reference_heading_summary([r[2] for r in rows]),
            "cpu_s": cpu_s,
            "errors": rows,
        }
    return out


def main() -> int:
    """Place the worlds' walks under each configuration; print the comparison and write the JSON."""
    switches = {"--labels-at-truth": "also place the default from every reference labelled at its true pose"}
    shares = {"--truth-share": "also place the default with this share of the wrong labels at the truth (repeatable)"}
    args = comparison_arguments(__doc__.split("\n")[0], "walk_placement.json", switches, shares)
    default = PlacementOptions()
    configs = {"default": default, **dict(parse_config(text, default) for text in args.config)}
    results: dict[str, Any] = {"configs": {n: asdict(c) for n, c in configs.items()}, "worlds": {}}
    for world_dir in args.world:
        placed = place_world(
            world_dir,
            configs,
            lambda msg: print(msg, flush=True),
            at_truth=args.labels_at_truth,
            truth_shares=tuple(args.truth_share),
        )
        results["worlds"][str(world_dir)] = placed
        base = {name: error for name, error, _ in placed["default"]["errors"]}
        for name in placed:
            s = placed[name]
            p, h = s["position"], s["heading"]
            moved = sum(abs(error - base[ref]) > MOVED_M for ref, error, _ in s["errors"])
            print(f"{world_dir.name:>8} {name:>12}: references within 1/2 m {p['within_1m']:.2f}/{p['within_2m']:.2f}, "
                  f"median {p['median_m']:.2f} m, headings within 2/5 deg {h['within_2deg']:.2f}/"
                  f"{h['within_5deg']:.2f}, moved > {MOVED_M} m: {moved}, CPU "
                  f"x{s['cpu_s'] / placed['default']['cpu_s']:.2f}", flush=True)  # fmt: skip
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
