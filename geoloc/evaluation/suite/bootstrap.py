"""95 % intervals of pooled figures from a cluster bootstrap, and of paired differences between two methods.

The items (queries, references, track frames) come in clusters, the worlds: items of one world share its map, its
walks' GPS drift and its references, so they are not independent, and an interval that resampled items alone would
be too narrow. Each replicate draws the group's worlds with replacement and pools all their items; a group of one
world (a per-world figure) draws its items with replacement instead. Drawing the items again inside each drawn
world as well (the two-stage bootstrap) counts the within-world noise twice. On the unit test's synthetic worlds
(``tests/unit/evaluation/test_suite_bootstrap.py``: 24 worlds of 20 queries, world rates spread with a standard
deviation of 0.03, 0.1 and 0.2 around a known rate) the two-stage draw covered the rate in 0.99, 0.97 and 0.95
of 150-300 draws, too wide where worlds are alike; the one-stage draw used here covers it in 0.937, 0.937 and
0.943 of 600 draws.

A figure is a :class:`Statistic` of an item table: a share or a mean (``mean`` of one per-item column: vectorised
over replicates from each world's sum and count) or any function of the pooled columns (a median, a ratio of
medians: computed per replicate). The interval is the 2.5th and 97.5th percentile of the replicates. A paired
difference uses the same draws for both methods' items (aligned by world and name), so the replicates of the
difference carry only the change.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Interval", "Statistic", "cluster_interval", "paired_interval"]

REPLICATES = 1000
SEED = 20261206
"""The draws are seeded: the same items give the same interval (and a method against itself a difference of 0)."""


@dataclass(frozen=True)
class Statistic:
    """A figure of pooled items: ``mean`` of column 0, or ``function`` of the pooled (N, k) columns."""

    function: Callable[[np.ndarray], float] | None = None  # None: the mean of column 0

    def of(self, items: np.ndarray) -> float:
        """The figure of an (N, k) item table (NaN when it has no items)."""
        if len(items) == 0:
            return float("nan")
        if self.function is None:
            return float(np.mean(items[:, 0]))
        return float(self.function(items))


@dataclass(frozen=True)
class Interval:
    """A figure's value on all items, its 95 % interval, and the numbers of worlds and items it came from."""

    value: float
    low: float
    high: float
    worlds: int
    items: int

    def as_dict(self, digits: int = 4) -> dict[str, float | int | None]:
        """JSON-ready (None for NaN)."""

        def r(v: float) -> float | None:
            return None if not np.isfinite(v) else round(float(v), digits)

        return {"value": r(self.value), "low": r(self.low), "high": r(self.high), "worlds": self.worlds,
                "items": self.items}  # fmt: skip


def _percentiles(reps: np.ndarray, clusters: int) -> tuple[float, float]:
    """The 2.5th and 97.5th percentiles of the replicates, spread by sqrt(m / (m - 1)) about their mean.

    A bootstrap over m clusters estimates the variance m - 1 over m of what it is (the plug-in variance); the
    spread undoes that, which matters for the per-form groups of three to six worlds.
    """
    reps = reps[np.isfinite(reps)]
    if not len(reps):
        return float("nan"), float("nan")
    if clusters > 1:
        centre = float(np.mean(reps))
        reps = centre + (reps - centre) * np.sqrt(clusters / (clusters - 1))
    low, high = np.percentile(reps, [2.5, 97.5])
    return float(low), float(high)


def _draws(sizes: Sequence[int], replicates: int, rng: np.random.Generator) -> np.ndarray:
    """(replicates, m) world draws for m clusters: indices of worlds (with replacement)."""
    return rng.integers(0, len(sizes), size=(replicates, len(sizes)))


def _replicates(
    tables: Sequence[np.ndarray], statistic: Statistic, replicates: int, rng: np.random.Generator
) -> np.ndarray:
    """The statistic on each bootstrap replicate of the clusters ``tables`` (each (n_i, k)): (replicates,)."""
    sizes = [len(t) for t in tables]
    if len(tables) == 1:
        (table,) = tables
        picks = rng.integers(0, len(table), size=(replicates, len(table)))
        if statistic.function is None:
            return np.asarray(table[:, 0][picks].mean(axis=1), dtype=float)
        return np.array([statistic.of(table[p]) for p in picks])
    draws = _draws(sizes, replicates, rng)
    if statistic.function is None:
        sums = np.array([t[:, 0].sum() for t in tables])
        counts = np.array(sizes, dtype=float)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.asarray(sums[draws].sum(axis=1) / counts[draws].sum(axis=1), dtype=float)
    return np.array([statistic.of(np.concatenate([tables[i] for i in row])) for row in draws])


def cluster_interval(
    tables: Sequence[np.ndarray], statistic: Statistic, replicates: int = REPLICATES, seed: int = SEED
) -> Interval:
    """The statistic of the pooled clusters ``tables`` (one (n_i, k) table per world) and its 95 % interval."""
    tables = [t for t in tables if len(t)]
    if not tables:
        return Interval(float("nan"), float("nan"), float("nan"), 0, 0)
    value = statistic.of(np.concatenate(tables))
    reps = _replicates(tables, statistic, replicates, np.random.default_rng(seed))
    reps = reps[np.isfinite(reps)]
    low, high = np.percentile(reps, [2.5, 97.5]) if len(reps) else (np.nan, np.nan)
    return Interval(value, float(low), float(high), len(tables), int(sum(len(t) for t in tables)))


def paired_interval(
    current: Sequence[np.ndarray],
    baseline: Sequence[np.ndarray],
    statistic: Statistic,
    replicates: int = REPLICATES,
    seed: int = SEED,
) -> Interval:
    """The difference current - baseline of the statistic, and its 95 % interval from shared draws.

    current, baseline: per world, the same items in the same order (rows aligned).
    """
    pairs = [(c, b) for c, b in zip(current, baseline, strict=True) if len(c)]
    if not pairs:
        return Interval(float("nan"), float("nan"), float("nan"), 0, 0)
    if statistic.function is None:  # a mean of a difference is the difference of the means: one column
        diffs = [np.column_stack([c[:, 0] - b[:, 0]]) for c, b in pairs]
        return cluster_interval(diffs, statistic, replicates, seed)
    value = statistic.of(np.concatenate([c for c, _ in pairs])) - statistic.of(np.concatenate([b for _, b in pairs]))
    rng = np.random.default_rng(seed)
    if len(pairs) == 1:
        ((c, b),) = pairs
        picks = rng.integers(0, len(c), size=(replicates, len(c)))
        reps = np.array([statistic.of(c[p]) - statistic.of(b[p]) for p in picks])
    else:
        draws = _draws([len(c) for c, _ in pairs], replicates, rng)
        reps = np.array(
            [
                statistic.of(np.concatenate([pairs[i][0] for i in row]))
                - statistic.of(np.concatenate([pairs[i][1] for i in row]))
                for row in draws
            ]
        )
    reps = reps[np.isfinite(reps)]
    low, high = np.percentile(reps, [2.5, 97.5]) if len(reps) else (np.nan, np.nan)
    return Interval(value, float(low), float(high), len(pairs), int(sum(len(c) for c, _ in pairs)))
