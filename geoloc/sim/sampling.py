"""Camera poses of a simulated world: references along streets, queries of three kinds (deterministic for a seed).

The world is a disk of ``radius_m`` around a centre near the buildings' median (:func:`world_centre`).
References stand along streets (OSM highways; without streets, in free space 8-25 m in front of
facades), mostly facing across the street (perpendicular +- 15 deg) with at least 60 % of the view on
buildings within 60 m, at least ``min_ref_spacing_m`` apart. Queries are of three kinds: ``between`` two
nearby references, ``offset`` from one reference (moved and turned 20-70 deg), and ``unseen``: looking
at a building that no reference shows with more than 2 % of its pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoloc.maps import CityMap
from geoloc.maps.raycast import cast_panoramas, panorama_window
from geoloc.sim.options import WorldOptions
from geoloc.sim.pose import Pose
from geoloc.sim.scene import Scene

QUERY_KINDS = ("between", "offset", "unseen")


@dataclass
class _Candidates:
    xy: np.ndarray  # (N, 2)
    yaw_deg: np.ndarray  # (N,)


def world_centre(city_map: CityMap) -> np.ndarray:
    """(2,) local xy (metres) of the world's centre: the median of the building centroids."""
    cent = np.array([b.polygon.centroid.coords[0] for b in city_map.buildings])
    centre: np.ndarray = np.median(cent, axis=0)
    return centre


def _street_points(
    city_map: CityMap, rng: np.random.Generator, n: int, centre: np.ndarray, radius_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random points on streets inside the disk (uniform by length): (n, 2) xy, (n, 2) unit directions."""
    segs_a, segs_b = [], []
    for line in city_map.streets:
        if len(line) >= 2:
            segs_a.append(line[:-1])
            segs_b.append(line[1:])
    if not segs_a:
        return np.zeros((0, 2)), np.zeros((0, 2))
    a, b = np.concatenate(segs_a), np.concatenate(segs_b)
    mid = (a + b) / 2
    if radius_m > 0:
        keep = np.hypot(*(mid - centre).T) <= radius_m
        a, b = a[keep], b[keep]
    length = np.hypot(*(b - a).T)
    ok = length > 0.5
    a, b, length = a[ok], b[ok], length[ok]
    if len(a) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    k = rng.choice(len(a), n, p=length / length.sum())
    t = rng.random(n)[:, None]
    return a[k] + t * (b[k] - a[k]), (b[k] - a[k]) / length[k, None]


def _facade_points(
    city_map: CityMap, rng: np.random.Generator, n: int, centre: np.ndarray, radius_m: float
) -> _Candidates:
    """Free-space fallback: points 8-25 m in front of random facades, looking at them."""
    fac = city_map.facades
    mid = (fac.start + fac.end) / 2
    ok = fac.length_m > 3.0
    if radius_m > 0:
        ok &= np.hypot(*(mid - centre).T) <= radius_m
    idx = np.flatnonzero(ok) if ok.any() else np.arange(len(fac))
    k = rng.choice(idx, n, p=fac.length_m[idx] / fac.length_m[idx].sum())
    along = (fac.end[k] - fac.start[k]) * rng.uniform(0.1, 0.9, (n, 1))
    xy = fac.start[k] + along + fac.normal[k] * rng.uniform(8.0, 25.0, (n, 1))
    yaw = (fac.normal_bearing_deg[k] + 180.0 + rng.normal(0, 20.0, n)) % 360.0
    return _Candidates(xy, yaw)


def _street_candidates(
    city_map: CityMap, rng: np.random.Generator, n: int, centre: np.ndarray, radius_m: float
) -> _Candidates:
    """Street positions (on the road or the pavement) looking across the street, either side."""
    xy, d = _street_points(city_map, rng, n, centre, radius_m)
    if len(xy) == 0:
        return _facade_points(city_map, rng, n, centre, radius_m)
    normal = np.column_stack([d[:, 1], -d[:, 0]])
    side = rng.choice([-1.0, 1.0], len(xy))[:, None]
    xy = xy + normal * side * rng.uniform(-2.0, 7.0, (len(xy), 1))  # mostly on the far side of the street
    look = -normal * side  # mostly across the street
    yaw = (np.degrees(np.arctan2(look[:, 0], look[:, 1])) + rng.normal(0, 15.0, len(xy))) % 360.0
    return _Candidates(xy, yaw)


@dataclass
class _View:
    """Cheap view statistics from the ray-cast panorama: building coverage, median distance, main building."""

    coverage: np.ndarray
    median_dist_m: np.ndarray
    main_building: np.ndarray


def _views(scene: Scene, xy: np.ndarray, yaw_deg: np.ndarray, hfov_deg: float, near_m: float = 60.0) -> _View:
    pano = cast_panoramas(scene.map, xy, bearing_step_deg=1.0, max_range_m=near_m * 2, index=scene.index)
    offsets = np.arange(-hfov_deg / 2 + 0.5, hfov_deg / 2, 1.0)
    win = panorama_window(pano, yaw_deg, offsets)  # (N, K)
    rows = np.arange(len(xy))[:, None]
    dist = pano.distance_m[rows, win]
    bid = pano.building_id[rows, win]
    near = dist <= near_m
    coverage = near.mean(axis=1)
    masked = np.where(near, dist, np.inf)
    med = np.where(
        near.any(axis=1), np.sort(masked, axis=1)[np.arange(len(xy)), np.maximum(near.sum(1) // 2, 0)], np.inf
    )
    main = np.full(len(xy), -1)
    for i in range(len(xy)):
        ids = bid[i][near[i]]
        if len(ids):
            main[i] = np.bincount(ids).argmax()
    return _View(coverage, med, main)


def _valid_positions(scene: Scene, xy: np.ndarray, margin_m: float = 1.5) -> np.ndarray:
    return scene._clear_of_buildings(xy, margin_m)


def _pitch_roll(rng: np.random.Generator, opts: WorldOptions) -> tuple[float, float]:
    pitch = float(np.clip(rng.normal(0, opts.pitch_std_deg), -3 * opts.pitch_std_deg, 3 * opts.pitch_std_deg))
    roll = float(np.clip(rng.normal(0, opts.roll_std_deg), -3 * opts.roll_std_deg, 3 * opts.roll_std_deg))
    return round(pitch, 3), round(roll, 3)


def sample_references(scene: Scene, opts: WorldOptions, rng: np.random.Generator, centre: np.ndarray) -> list[Pose]:
    """Reference poses along streets facing buildings (see module docstring)."""
    chosen: list[np.ndarray] = []
    yaws: list[float] = []
    spacing = opts.min_ref_spacing_m
    for _attempt in range(6):
        cand = _street_candidates(scene.map, rng, max(200, 40 * opts.n_references), centre, opts.radius_m)
        ok = _valid_positions(scene, cand.xy)
        view = _views(scene, cand.xy, cand.yaw_deg, opts.hfov_deg)
        ok &= (view.coverage >= 0.6) & (view.median_dist_m >= 8.0) & (view.median_dist_m <= 45.0)
        for i in np.flatnonzero(ok):
            if len(chosen) >= opts.n_references:
                break
            if chosen and np.min(np.hypot(*(np.array(chosen) - cand.xy[i]).T)) < spacing:
                continue
            chosen.append(cand.xy[i])
            yaws.append(float(cand.yaw_deg[i]))
        if len(chosen) >= opts.n_references:
            break
        spacing *= 0.7  # a small area: allow denser references
    poses = []
    for xy, yaw in zip(chosen, yaws, strict=True):
        pitch, roll = _pitch_roll(rng, opts)
        poses.append(Pose(round(float(xy[0]), 3), round(float(xy[1]), 3), round(yaw % 360.0, 3), pitch, roll))
    return poses


def sample_queries(
    scene: Scene,
    opts: WorldOptions,
    rng: np.random.Generator,
    centre: np.ndarray,
    refs: list[Pose],
    ref_seen: dict[int, float],
) -> list[tuple[str, Pose]]:
    """Query poses: ``between`` / ``offset`` references and ``unseen`` buildings (module docstring).

    ref_seen: building id -> largest pixel share it has in any reference.
    """
    n = opts.n_queries
    quotas = {"between": int(round(n * 0.4)), "offset": int(round(n * 0.3))}
    quotas["unseen"] = n - quotas["between"] - quotas["offset"]
    ref_xy = np.array([[p.x_m, p.y_m] for p in refs]).reshape(-1, 2)
    ref_yaw = np.array([p.yaw_deg for p in refs])
    out: list[tuple[str, np.ndarray, float]] = []
    m = max(100, 30 * n)
    for kind in QUERY_KINDS:
        want = quotas[kind]
        got = 0
        for _attempt in range(6):
            if want == 0:
                break
            cand, far = _query_candidates(kind, scene, opts, rng, centre, ref_xy, ref_yaw, m)
            ok = _valid_positions(scene, cand.xy) & ~far
            view = _views(scene, cand.xy, cand.yaw_deg, opts.hfov_deg)
            ok &= (view.coverage >= 0.45) & (view.median_dist_m >= 5.0) & (view.median_dist_m <= 60.0)
            if kind == "unseen":
                seen = np.array([ref_seen.get(int(b), 0.0) for b in view.main_building])
                ok &= (seen < 0.02) & (view.main_building >= 0)
            got += _accept_queries(out, kind, cand, ok, want - got)
            if got >= want:
                break
        if got < want:  # not enough of this kind (e.g. every building is seen): top up with the next kind
            nxt = QUERY_KINDS[(QUERY_KINDS.index(kind) + 1) % 3]
            if nxt != "between":
                quotas[nxt] += want - got
    result = []
    for kind, xy, yaw in out:
        pitch, roll = _pitch_roll(rng, opts)
        result.append((kind, Pose(round(float(xy[0]), 3), round(float(xy[1]), 3), round(yaw, 3), pitch, roll)))
    return result


def _query_candidates(
    kind: str,
    scene: Scene,
    opts: WorldOptions,
    rng: np.random.Generator,
    centre: np.ndarray,
    ref_xy: np.ndarray,
    ref_yaw: np.ndarray,
    m: int,
) -> tuple[_Candidates, np.ndarray]:
    """``m`` candidate query poses of one kind (local metres, yaw degrees) and (m,) bool: too far to use.

    ``between``: on the segment between a reference and one of its 3 nearest (too far beyond 80 m apart);
    ``offset``: 4-15 m from a reference, turned 20-70 deg; otherwise (``unseen``, or too few references)
    anywhere along the streets.
    """
    if kind == "between" and len(ref_xy) >= 2:
        i = rng.integers(len(ref_xy), size=m)
        d = np.hypot(*(ref_xy[:, None] - ref_xy[None]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        nn = np.argsort(d, axis=1)[:, :3]
        j = nn[i, rng.integers(0, min(3, len(ref_xy) - 1), m)]
        t = rng.uniform(0.3, 0.7, (m, 1))
        xy = ref_xy[i] * (1 - t) + ref_xy[j] * t + rng.normal(0, 2.0, (m, 2))
        diff = ((ref_yaw[j] - ref_yaw[i] + 180.0) % 360.0) - 180.0
        yaw = (ref_yaw[i] + diff * t[:, 0] + rng.normal(0, 25.0, m)) % 360.0
        return _Candidates(xy, yaw), d[i, j] > 80.0
    if kind == "offset" and len(ref_xy):
        i = rng.integers(len(ref_xy), size=m)
        ang = rng.uniform(0, 2 * np.pi, m)
        r = rng.uniform(4.0, 15.0, m)
        xy = ref_xy[i] + np.column_stack([np.cos(ang), np.sin(ang)]) * r[:, None]
        turn = rng.uniform(20.0, 70.0, m) * rng.choice([-1.0, 1.0], m)
        return _Candidates(xy, (ref_yaw[i] + turn) % 360.0), np.zeros(m, bool)
    cand = _street_candidates(scene.map, rng, m, centre, opts.radius_m)
    cand.yaw_deg = (cand.yaw_deg + rng.normal(0, 20.0, m)) % 360.0
    return cand, np.zeros(m, bool)


def _accept_queries(
    out: list[tuple[str, np.ndarray, float]], kind: str, cand: _Candidates, ok: np.ndarray, n_wanted: int
) -> int:
    """Append up to ``n_wanted`` of the ``ok`` candidates to ``out``; returns how many were appended.

    Candidates are taken in order, each at least 2 m from the queries already in ``out``.
    """
    taken = 0
    for q in np.flatnonzero(ok):
        if taken >= n_wanted:
            break
        if out and np.min(np.hypot(*(np.array([o[1] for o in out]) - cand.xy[q]).T)) < 2.0:
            continue
        out.append((kind, cand.xy[q], float(cand.yaw_deg[q])))
        taken += 1
    return taken
