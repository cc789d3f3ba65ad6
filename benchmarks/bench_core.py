"""Benchmark of the geometric core on the Helsinki map (prints figures; not a test).

    .venv/bin/python benchmarks/bench_core.py [--cell-m 10] [--yaws 120] [--hfov 60]

Ray-casts a panorama (0.5 deg bearings) at every cell of a regular grid over the whole map
(cells inside buildings excluded), then evaluates the pose likelihood for all cells x yaws with an
image model taken from one true pose, geometry-only and identity-aware.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from geoloc.camera import Intrinsics
from geoloc.config import shared_path
from geoloc.image_model import bin_offsets_deg
from geoloc.likelihood import default_yaws_deg, image_model_from_map, pose_likelihood
from geoloc.osm import load_map
from geoloc.posterior import make_grid
from geoloc.raycast import cast_panoramas


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cell-m", type=float, default=10.0)
    parser.add_argument("--yaws", type=int, default=120)
    parser.add_argument("--hfov", type=float, default=60.0)
    args = parser.parse_args()

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, numpy {np.__version__}")
    t0 = time.perf_counter()
    city = load_map(shared_path("data", "osm", "helsinki.osm.pbf"))
    print(f"load map: {time.perf_counter() - t0:.2f} s ({len(city.buildings)} buildings, {len(city.facades)} facades)")

    grid = make_grid(city, city.bounds_m, args.cell_m)
    positions = grid.positions
    print(f"grid: {grid.shape[0]} x {grid.shape[1]} cells of {args.cell_m:g} m, {len(positions)} outside buildings")

    t0 = time.perf_counter()
    pano = cast_panoramas(city, positions)
    cast_s = time.perf_counter() - t0
    hit = np.isfinite(pano.distance_m)
    print(
        f"ray-cast panoramas: {cast_s:.2f} s for {len(positions)} positions x {len(pano.bearings_deg)} bearings "
        f"({1e3 * cast_s / len(positions):.3f} ms/position; {hit.mean():.0%} of rays hit within {pano.max_range_m:g} m)"
    )

    offsets = bin_offsets_deg(Intrinsics.from_hfov(640, 480, args.hfov))
    yaws = default_yaws_deg(args.yaws)
    rng = np.random.default_rng(0)
    index = int(rng.choice(np.flatnonzero(hit.mean(axis=1) > 0.5)))
    model = image_model_from_map(pano, index, float(yaws[7]), offsets)
    for use_identity in (False, True):
        t0 = time.perf_counter()
        lik = pose_likelihood(pano, model, yaws, use_identity=use_identity)
        lik_s = time.perf_counter() - t0
        label = "identity-aware" if use_identity else "geometry-only "
        best = np.unravel_index(np.argmax(lik), lik.shape)
        print(
            f"likelihood {label}: {lik_s:.2f} s for {lik.shape[0]} positions x {lik.shape[1]} yaws x "
            f"{len(offsets)} column bins ({1e9 * lik_s / lik.size / len(offsets):.1f} ns per pose-bin); "
            f"best pose is the true one: {best == (index, 7)}"
        )


if __name__ == "__main__":
    main()
