"""The paired latency ratio of two services (:func:`benchmarks.answer_pairs.paired_latency`)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.answer_pairs import paired_latency


def _runs(walls_ms: np.ndarray) -> list[dict[str, float]]:
    return [{"wall_ms": float(w)} for w in walls_ms]


def test_a_constant_slowdown_is_found_inside_a_tight_interval_despite_noisy_queries() -> None:
    rng = np.random.default_rng(3)
    current = rng.uniform(300.0, 1200.0, 120)  # queries differ four-fold: the medians of two runs would too
    other = current * 1.02 * rng.lognormal(0.0, 0.01, 120)  # 2 % slower, 1 % noise per pair
    paired = paired_latency(_runs(other), _runs(current))
    assert paired["pairs"] == 120
    assert paired["ratio"] == pytest.approx(1.02, abs=0.003)
    low, high = paired["ratio_95"]
    assert low < 1.02 < high and high - low < 0.01


def test_the_same_latencies_give_one_and_unpaired_runs_are_refused() -> None:
    walls = np.array([500.0, 700.0, 600.0])
    assert paired_latency(_runs(walls), _runs(walls)) == {"pairs": 3, "ratio": 1.0, "ratio_95": [1.0, 1.0]}
    with pytest.raises(ValueError):
        paired_latency(_runs(walls), _runs(walls[:2]))
