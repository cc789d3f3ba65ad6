"""A walk's pace: how fast its captures follow each other, measured on its own relative poses (issue 19).

The placement (:mod:`geoloc.localize.sequence.placement`) uses it twice: as the distance of each step between
consecutive captures (the speed times the time between them), and to tell the relative poses whose length it
rules out (:func:`rules_out`). Capture times are seconds on any one clock the walk shares (None:
unknown); distances are metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from geoloc.localize.sequence.relative import RelativePose


@dataclass(frozen=True)
class WalkPace:
    """How a walk's captures are spaced.

    speed_m_s: the walker's speed (m/s); spread_m: the spread (m) of a step's distance about the speed times
    the time between its two captures (1.4826 x the median absolute residual, a standard deviation's estimate).
    """

    speed_m_s: float
    spread_m: float

    def step_sigma_m(self, floor_m: float) -> float:
        """A step's sigma (m): the pace's spread, at least ``floor_m``."""
        return max(floor_m, self.spread_m)


def rules_out(
    pace: WalkPace | None, capture_times_s: Sequence[float | None], edge: RelativePose, floor_m: float, gate: float
) -> bool:
    """Whether an edge's length is more than ``gate`` step sigmas from the speed times its frames' time apart.

    The sigma is the pace's :meth:`WalkPace.step_sigma_m` times the square root of the steps the edge spans
    (their errors add). No pace, no capture time or a gate of math.inf: it rules out nothing.
    """
    apart_s = seconds_apart(capture_times_s, edge.source, edge.target)
    if pace is None or apart_s is None:
        return False
    sigma = pace.step_sigma_m(floor_m) * math.sqrt(abs(edge.target - edge.source))
    return abs(edge.distance_m - pace.speed_m_s * apart_s) > gate * sigma


def seconds_apart(capture_times_s: Sequence[float | None], i: int, j: int) -> float | None:
    """Seconds between captures i and j (None when either time is unknown)."""
    t_i, t_j = capture_times_s[i], capture_times_s[j]
    return None if t_i is None or t_j is None else abs(t_j - t_i)


def walk_pace(
    capture_times_s: Sequence[float | None], edges: Sequence[RelativePose], min_samples: int
) -> WalkPace | None:
    """The walk's pace, measured on its consecutive frames' relative poses (both ways count).

    The speed is the median of their distances over their time apart, the spread the robust spread of their
    distances about it: a walker's pauses to take each photo, and the edges' own errors, are in it. Both
    medians set the wrong edges aside while fewer than half are wrong. None with fewer than ``min_samples``
    such edges (or frames without capture times).
    """
    distances, seconds = [], []
    for edge in edges:
        if abs(edge.target - edge.source) != 1:
            continue
        apart_s = seconds_apart(capture_times_s, edge.source, edge.target)
        if apart_s is not None and apart_s > 0.0:
            distances.append(edge.distance_m)
            seconds.append(apart_s)
    if len(distances) < min_samples:
        return None
    distance_m, apart = np.asarray(distances), np.asarray(seconds)
    speed = float(np.median(distance_m / apart))
    spread = 1.4826 * float(np.median(np.abs(distance_m - speed * apart)))
    return WalkPace(speed, spread)
