"""The specification of the ray-casting kernel: :func:`cast_tile_numpy`, ``geoloc.maps.raycast._cast_tile`` in numpy.

Not used by the runtime: the tests check the compiled kernel against it (results identical) and
``benchmarks/bench_core.py`` times the two side by side.
"""

from __future__ import annotations

import numpy as np

from geoloc.maps import Facades
from geoloc.maps.raycast import _DIST_SCALE, _FACADE_BITS


def cast_tile_numpy(
    positions: np.ndarray,
    members: np.ndarray,
    facades: Facades,
    near: np.ndarray,
    n_bearings: int,
    max_range_m: float,
    best: np.ndarray,
) -> None:
    """:func:`geoloc.maps.raycast._cast_tile` in vectorised numpy (the specification the tests hold the kernel to)."""
    step = 360.0 / n_bearings
    origin = positions[members][:, None, :]  # (p, 1, 2)
    a = facades.start[near][None] - origin  # (p, f, 2) endpoints relative to the camera
    b = facades.end[near][None] - origin
    normal = facades.normal[near][None]
    # Facing test: the camera is on the outer side of the facade's line.
    facing = np.einsum("pfk,pfk->pf", -a, np.broadcast_to(normal, a.shape)) > 1e-6
    # Distance from the camera to the segment, to drop far facades early.
    ab = b - a
    t = np.clip(-np.einsum("pfk,pfk->pf", a, ab) / np.einsum("pfk,pfk->pf", ab, ab), 0.0, 1.0)
    closest = a + t[..., None] * ab
    within = facing & (np.hypot(closest[..., 0], closest[..., 1]) <= max_range_m)
    p_idx, f_idx = np.nonzero(within)
    if len(p_idx) == 0:
        return
    a, b = a[p_idx, f_idx], b[p_idx, f_idx]
    # Bearings of the two endpoints; the facade spans the short arc between them (it faces the camera).
    bear_a = np.degrees(np.arctan2(a[:, 0], a[:, 1])) % 360.0
    bear_b = np.degrees(np.arctan2(b[:, 0], b[:, 1])) % 360.0
    lo = np.minimum(bear_a, bear_b)
    hi = np.maximum(bear_a, bear_b)
    wraps = hi - lo > 180.0
    lo, hi = np.where(wraps, hi, lo), np.where(wraps, lo + 360.0, hi)
    first = np.ceil(lo / step - 1e-9).astype(np.int64)
    last = np.floor(hi / step + 1e-9).astype(np.int64)
    count = np.maximum(last - first + 1, 0)
    total = int(count.sum())
    if total == 0:
        return
    pair = np.repeat(np.arange(len(p_idx)), count)
    k = first[pair] + (np.arange(total) - np.repeat(np.cumsum(count) - count, count))
    theta = np.radians(k * step)
    ray = np.column_stack([np.sin(theta), np.cos(theta)])
    # Ray r(s) = s * ray hits segment a + u (b - a): solve with 2D cross products.
    a_s, ab_s = a[pair], (b - a)[pair]
    denom = ray[:, 0] * ab_s[:, 1] - ray[:, 1] * ab_s[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (a_s[:, 0] * ab_s[:, 1] - a_s[:, 1] * ab_s[:, 0]) / denom
    ok = np.isfinite(s) & (s > 0.0) & (s <= max_range_m)
    dist_cm = np.round(s[ok] * _DIST_SCALE).astype(np.int64)
    key = (dist_cm << _FACADE_BITS) | near[f_idx[pair[ok]]].astype(np.int64)
    cell = members[p_idx[pair[ok]]].astype(np.int64) * n_bearings + (k[ok] % n_bearings)
    np.minimum.at(best, cell, key)
