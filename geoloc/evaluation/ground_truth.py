"""What the simulated world's ground truth says: which references show a query, true identities, raw GPS."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from geoloc.evaluation.summaries import distance_summary
from geoloc.localize.identity import IdentityMap
from geoloc.maps import CityMap
from geoloc.sim.world import World

SHOWN_MIN_SHARE = 0.1


def shown_by_references(world: World, query_name: str, reference_names: list[str]) -> dict[str, Any]:
    """Which references show the query's buildings (building pixels shared >= 0.1 of the image).

    Returns ``building`` (bool), ``references`` (the names sharing the most, ties within 0.02; empty when
    none shares 0.1) and ``facade_share`` (the best share counted per facade instead of per building).
    """
    query_record = world.image(query_name).record
    shares = {b["building_id"]: b["pixel_share"] for b in query_record["buildings"]}
    overlap = {}
    for name in reference_names:
        ref_shares = {b["building_id"]: b["pixel_share"] for b in world.image(name).record["buildings"]}
        overlap[name] = sum(min(s, ref_shares.get(b, 0.0)) for b, s in shares.items())
    top = max(overlap.values(), default=0.0)
    best = {name for name, value in overlap.items() if value >= top - 0.02} if top >= SHOWN_MIN_SHARE else set()
    return {
        "building": bool(best),
        "references": best,
        "facade_share": facade_share(world, query_name, reference_names),
    }


def facade_share(world: World, query_name: str, reference_names: list[str]) -> float:
    """The best share of the query's image any reference shares with it, counted per facade instead of building."""

    def shares(name: str) -> dict[int, float]:
        facade = world.gt(name)["facade_id"]
        ids, counts = np.unique(facade[facade >= 0], return_counts=True)
        return dict(zip(ids.tolist(), (counts / facade.size).tolist(), strict=True))

    query = shares(query_name)
    return max((sum(min(v, shares(n).get(f, 0.0)) for f, v in query.items()) for n in reference_names), default=0.0)


def gt_keypoint_identity(xy: np.ndarray, building_id: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-hot identities of keypoints from a ground-truth building-id image."""
    h, w = building_id.shape
    ids_at = building_id[
        np.clip(np.round(xy[:, 1]).astype(int), 0, h - 1), np.clip(np.round(xy[:, 0]).astype(int), 0, w - 1)
    ]
    ids = np.unique(ids_at[ids_at >= 0])
    return (ids_at[:, None] == ids[None, :]).astype(np.float32), ids


def gt_identity_map(building_id: np.ndarray, building_mask: np.ndarray) -> IdentityMap:
    """Per-column identities from the renderer's building ids (each column: its buildings' pixel shares)."""
    ids = np.unique(building_id[building_id >= 0])
    width = building_id.shape[1]
    prob = np.zeros((width, len(ids)), np.float32)
    if len(ids):
        slot = np.searchsorted(ids, building_id)
        rows, cols = np.nonzero(building_id >= 0)
        np.add.at(prob, (cols, slot[rows, cols]), 1.0)
        prob /= np.maximum(prob.sum(axis=1, keepdims=True), 1.0)
    return IdentityMap(ids, prob, building_mask)


def gps_baseline(world: World, city: CityMap, queries: list[Any]) -> dict[str, Any]:
    """Errors (m) of the queries' raw EXIF GPS positions against their true positions, summarised."""
    errors = []
    for image in queries:
        gps = image.record.get("gps")
        if not gps:
            continue
        x, y = city.frame.to_local(gps["lat"], gps["lon"])
        errors.append(math.hypot(float(x) - image.pose.x_m, float(y) - image.pose.y_m))
    return distance_summary(errors)
