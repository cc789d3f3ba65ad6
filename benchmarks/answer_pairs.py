"""How a service's answers and latencies compare with another's on the same queries (:mod:`bench_service`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from geoloc.core.geo import angle_difference_deg


def distance_m(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Metres between two WGS84 (lat, lon) points close together (equirectangular)."""
    dy = (a[0] - b[0]) * 111_195.0
    dx = (a[1] - b[1]) * 111_195.0 * np.cos(np.radians((a[0] + b[0]) / 2))
    return float(np.hypot(dx, dy))


def _rank1_gap(a: dict[str, Any], b: dict[str, Any]) -> tuple[float, float]:
    """(m, deg) between the rank-1 poses of one query's two answers (``a`` has at least one location)."""
    (lat_a, lon_a, heading_a), (lat_b, lon_b, heading_b) = a["locations"][0], b["locations"][0]
    return distance_m((lat_a, lon_a), (lat_b, lon_b)), angle_difference_deg(heading_a, heading_b)


def compare_answers(other: list[dict[str, Any]], current: list[dict[str, Any]]) -> dict[str, Any]:
    """How far the rank-1 answers of the same queries lie apart on two services."""
    pairs = list(zip(other, current, strict=True))
    gaps = {i: _rank1_gap(a, b) for i, (a, b) in enumerate(pairs) if a["locations"]}
    different = [a["photo"] for a, b in pairs if a["locations"] != b["locations"]]  # exactly: every location
    same = sum(
        len(a["locations"]) == len(b["locations"]) and (not a["locations"] or max(gaps[i]) < 0.05)
        for i, (a, b) in enumerate(pairs)
    )
    return {
        "same_rank1_pose": f"{same}/{len(pairs)}",
        "rank1_gap_m_max": round(max((m for m, _ in gaps.values()), default=0.0), 3),
        "rank1_heading_gap_deg_max": round(max((d for _, d in gaps.values()), default=0.0), 3),
        "different": len(different),
        "different_photos": sorted(set(different)),
    }


def paired_latency(other: list[dict[str, Any]], current: list[dict[str, Any]], seed: int = 0) -> dict[str, Any]:
    """Each query's latency on ``other`` over the same query's on ``current``, paired.

    The pairs are the same photo in the same round, posted back to back; the result is their geometric mean ratio
    with a 95 % bootstrap interval, which resolves what a ratio of two medians cannot when the run-to-run noise is
    as large as the difference sought.
    """
    log_ratios = np.log([a["wall_ms"] / b["wall_ms"] for a, b in zip(other, current, strict=True)])
    rng = np.random.default_rng(seed)
    boot = log_ratios[rng.integers(0, len(log_ratios), (10_000, len(log_ratios)))].mean(axis=1)
    low, high = np.exp(np.percentile(boot, [2.5, 97.5]))
    return {
        "pairs": len(log_ratios),
        "ratio": round(float(np.exp(log_ratios.mean())), 4),
        "ratio_95": [round(float(low), 4), round(float(high), 4)],
    }
