"""The suite's intervals: coverage of a known rate, paired differences, per-world draws."""

from __future__ import annotations

import numpy as np
import pytest

from geoloc.evaluation.suite.bootstrap import Statistic, cluster_interval, paired_interval

RATE = 0.4


def synthetic_worlds(rng: np.random.Generator, worlds: int = 24, queries: int = 20, spread: float = 0.1) -> list:
    """Per world, its queries' outcomes (1: within the threshold) at a world rate drawn around :data:`RATE`."""
    scale = RATE * (1 - RATE) / spread**2 - 1
    rates = rng.beta(RATE * scale, (1 - RATE) * scale, worlds)
    return [(rng.random((queries, 1)) < r).astype(float) for r in rates]


@pytest.mark.parametrize("spread", [0.03, 0.1, 0.2])
def test_the_interval_covers_a_known_rate_in_93_to_97_percent_of_draws(spread: float) -> None:
    rng = np.random.default_rng(7)
    draws = 600
    covered = 0
    for k in range(draws):
        interval = cluster_interval(synthetic_worlds(rng, spread=spread), Statistic(), replicates=500, seed=k)
        covered += interval.low <= RATE <= interval.high
    assert 0.93 <= covered / draws <= 0.97


def test_a_median_interval_holds_the_pooled_median_and_counts_worlds_and_items() -> None:
    rng = np.random.default_rng(3)
    tables = [rng.exponential(5.0, (20, 1)) for _ in range(8)]
    interval = cluster_interval(tables, Statistic(lambda items: float(np.median(items[:, 0]))))
    assert interval.value == pytest.approx(float(np.median(np.concatenate(tables))))
    assert interval.low < interval.value < interval.high
    assert (interval.worlds, interval.items) == (8, 160)


def test_one_world_draws_its_items() -> None:
    table = np.array([[1.0]] * 10 + [[0.0]] * 10)
    interval = cluster_interval([table], Statistic())
    assert interval.value == 0.5
    assert 0.2 < interval.low < 0.5 < interval.high < 0.8


def test_a_method_against_itself_differs_by_exactly_zero() -> None:
    rng = np.random.default_rng(5)
    tables = [rng.exponential(5.0, (15, 2)) for _ in range(6)]
    for statistic in (Statistic(), Statistic(lambda items: float(np.median(items[:, 0]) / np.median(items[:, 1])))):
        interval = paired_interval(tables, [t.copy() for t in tables], statistic)
        assert (interval.value, interval.low, interval.high) == (0.0, 0.0, 0.0)


def test_a_paired_difference_is_narrower_than_the_two_intervals_apart() -> None:
    rng = np.random.default_rng(11)
    baseline = [(rng.random((20, 1)) < r).astype(float) for r in rng.uniform(0.2, 0.8, 12)]
    current = [b.copy() for b in baseline]
    for table in current:  # one more query within the threshold in every world
        table[np.argmin(table[:, 0]), 0] = 1.0
    difference = paired_interval(current, baseline, Statistic())
    alone = cluster_interval(current, Statistic())
    assert difference.value == pytest.approx(sum(float(b[:, 0].min() == 0) for b in baseline) / 240)
    assert difference.low >= 0.0 and difference.high - difference.low < (alone.high - alone.low) / 3
