"""Benchmark of the geometric core on the Helsinki map: compiled kernels next to their numpy specifications.

    .venv/bin/python benchmarks/bench_core.py [--cell-m 10] [--yaws 120] [--hfov 60] [--repeats 3]
                                              [--json core.json]

Ray-casts a panorama (0.5 deg bearings) at every cell of a regular grid over the whole map (cells inside
buildings excluded), then evaluates the pose likelihood for all cells x yaws with an image model taken from
one true pose, geometry-only and identity-aware. Each is run with the compiled kernel
(:func:`geoloc.maps.raycast.cast_panoramas`, :func:`geoloc.localize.likelihood.pose_likelihood`) and with the plain
numpy formulation it replaced (``geoloc.maps.raycast_reference.cast_tile_numpy``,
:func:`geoloc.localize.likelihood_reference.pose_likelihood_numpy`)
in the same run, alternating, ``--repeats`` times (the best time of each is reported: the machine is
shared). The likelihood's rate is in column comparisons per second: positions x yaws x column bins
evaluated per second. The results of the two must agree (identical panoramas; likelihoods within float32
rounding).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from baseline import add_baseline_option, baseline_figures

from contracts.settings import shared_path
from geoloc.core.camera import Intrinsics
from geoloc.localize.likelihood import (
    LikelihoodOptions,
    default_yaws_deg,
    image_model_from_map,
    known_building_heights,
    pose_likelihood,
)
from geoloc.localize.likelihood_reference import pose_likelihood_numpy
from geoloc.localize.posterior import make_grid
from geoloc.maps import load_map, raycast, raycast_reference
from geoloc.vision.image_model import bin_offsets_deg


def best_of(repeats: int, *functions: Callable[[], Any]) -> tuple[list[float], list[Any]]:
    """Best wall time (s) of each function over ``repeats`` alternating runs, and each one's last result."""
    times = [float("inf")] * len(functions)
    results: list[Any] = [None] * len(functions)
    for _ in range(repeats):
        for i, function in enumerate(functions):
            t0 = time.perf_counter()
            results[i] = function()
            times[i] = min(times[i], time.perf_counter() - t0)
    return times, results


def numpy_cast(city: Any, positions: np.ndarray) -> raycast.Panoramas:
    kernel = raycast._cast_tile
    raycast._cast_tile = raycast_reference.cast_tile_numpy
    try:
        return raycast.cast_panoramas(city, positions)
    finally:
        raycast._cast_tile = kernel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cell-m", type=float, default=10.0)
    parser.add_argument("--yaws", type=int, default=120)
    parser.add_argument("--hfov", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, default=Path("core.json"))
    add_baseline_option(parser)
    args = parser.parse_args()

    figures: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start",
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "numpy": np.__version__,
    }
    print(f"machine: {figures['machine']}, numpy {np.__version__}")
    t0 = time.perf_counter()
    city = load_map(shared_path("data", "osm", "helsinki.osm.pbf"))
    print(f"load map: {time.perf_counter() - t0:.2f} s ({len(city.buildings)} buildings, {len(city.facades)} facades)")
    grid = make_grid(city, city.bounds_m, args.cell_m)
    positions = grid.positions
    print(f"grid: {grid.shape[0]} x {grid.shape[1]} cells of {args.cell_m:g} m, {len(positions)} outside buildings")
    raycast.cast_panoramas(city, positions[:4])  # compile (or load the cached compiled kernels) first

    (fast_s, slow_s), (pano, reference) = best_of(
        args.repeats, lambda: raycast.cast_panoramas(city, positions), lambda: numpy_cast(city, positions)
    )
    same = np.array_equal(pano.facade_id, reference.facade_id) and np.array_equal(pano.distance_m, reference.distance_m)
    hit = np.isfinite(pano.distance_m)
    figures["raycast"] = {
        "positions": len(positions),
        "bearings": len(pano.bearings_deg),
        "kernel_s": round(fast_s, 3),
        "numpy_s": round(slow_s, 3),
        "kernel_ms_per_position": round(1e3 * fast_s / len(positions), 4),
        "speedup": round(slow_s / fast_s, 1),
        "identical": bool(same),
    }
    print(f"ray-cast panoramas, {len(positions)} positions x {len(pano.bearings_deg)} bearings "
          f"({hit.mean():.0%} of rays hit within {pano.max_range_m:g} m): kernel {fast_s:.2f} s "
          f"({1e3 * fast_s / len(positions):.3f} ms/position), numpy {slow_s:.2f} s: {slow_s / fast_s:.1f}x; "
          f"identical: {same}")  # fmt: skip

    offsets = bin_offsets_deg(Intrinsics.from_hfov(640, 480, args.hfov))
    yaws = default_yaws_deg(args.yaws)
    rng = np.random.default_rng(0)
    index = int(rng.choice(np.flatnonzero(hit.mean(axis=1) > 0.5)))
    heights = known_building_heights(city)
    figures["likelihood"] = {}
    for use_identity in (False, True):
        model = image_model_from_map(pano, index, float(yaws[7]), offsets, with_distance=True)

        def kernel(model: Any = model, use_identity: bool = use_identity) -> np.ndarray:
            return pose_likelihood(pano, model, yaws, LikelihoodOptions(use_identity=use_identity), heights)

        def plain(model: Any = model, use_identity: bool = use_identity) -> np.ndarray:
            return pose_likelihood_numpy(pano, model, yaws, LikelihoodOptions(use_identity=use_identity), heights)

        (fast_s, slow_s), (lik, lik_ref) = best_of(args.repeats, kernel, plain)
        comparisons = lik.size * len(offsets)
        label = "identity-aware" if use_identity else "geometry-only"
        best = tuple(int(i) for i in np.unravel_index(np.argmax(lik), lik.shape))
        figures["likelihood"][label] = {
            "positions": lik.shape[0],
            "yaws": lik.shape[1],
            "column_bins": len(offsets),
            "kernel_s": round(fast_s, 3),
            "numpy_s": round(slow_s, 3),
            "kernel_comparisons_per_s": round(comparisons / fast_s),
            "numpy_comparisons_per_s": round(comparisons / slow_s),
            "speedup": round(slow_s / fast_s, 1),
            "max_abs_difference": float(np.abs(lik - lik_ref).max()),
            "best_pose_is_the_true_one": bool(best == (index, 7)),
        }
        row = figures["likelihood"][label]
        print(f"likelihood {label:15s} {lik.shape[0]} positions x {lik.shape[1]} yaws x {len(offsets)} column bins: "
              f"kernel {fast_s:.2f} s ({comparisons / fast_s / 1e6:.0f} M column comparisons/s), numpy {slow_s:.2f} s "
              f"({comparisons / slow_s / 1e6:.0f} M/s): {slow_s / fast_s:.1f}x; largest difference "
              f"{row['max_abs_difference']:.1e}; best pose true: {row['best_pose_is_the_true_one']}")  # fmt: skip
    figures["load_average_end"] = round(os.getloadavg()[0], 1)
    baseline_figures(args.baseline, __file__, figures)
    args.json.write_text(json.dumps(figures, indent=2))
    print(f"figures written to {args.json}")


if __name__ == "__main__":
    main()
