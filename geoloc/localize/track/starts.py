"""A track's starting headings for the optimiser: one heading per run of frames its two-view motions join.

Levenberg-Marquardt only descends, and a frame whose own answer looks the opposite way (the mirror view across
the street, 180 deg off) stays there however tight its neighbours' motions are: the robust loss sets the motion
aside instead. So before the placement, the frames the motions join (:mod:`geoloc.localize.sequence.twoview`,
whose turns are accurate to well under a degree) get their headings relative to one frame of their run, and the
run's one unknown, its absolute heading, is voted on by every frame's own heading and compass: each vote is a
Gaussian bump (sigma :data:`VOTE_SIGMA_DEG`) weighted by the vote's trust. Headings are local bearings (deg).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from geoloc.localize.query.answer import AnswerPose
from geoloc.localize.sequence.twoview import MotionFactor
from geoloc.photos.heading_prior import HeadingPrior

VOTE_SIGMA_DEG = 10.0
"""Width of one heading vote (deg)."""
ANCHORED_WEIGHT = 3.0
"""An anchored answer's vote against a likelihood answer's or a compass's (1)."""


def relative_headings(n: int, motions: Sequence[MotionFactor]) -> list[float | None]:
    """Each frame's heading relative to the first frame of its run (deg; None: no motion joins it).

    The runs are the connected parts of the motions' graph; the turns are chained breadth-first from the run's
    first frame, the motion with the most direct link (smallest step) first.
    """
    out: list[float | None] = [None] * n
    neighbours: list[list[tuple[int, float, int]]] = [[] for _ in range(n)]
    for m in motions:
        step = abs(m.target - m.source)
        neighbours[m.source].append((m.target, m.turn_deg, step))
        neighbours[m.target].append((m.source, -m.turn_deg, step))
    for root in range(n):
        if out[root] is not None or not neighbours[root]:
            continue
        out[root] = 0.0
        queue = [root]
        while queue:
            k = queue.pop(0)
            for j, turn, _ in sorted(neighbours[k], key=lambda t: t[2]):
                if out[j] is None:
                    out[j] = (float(out[k] or 0.0) + turn) % 360.0
                    queue.append(j)
    return out


def start_headings(
    alone: Sequence[AnswerPose | None], compasses: Sequence[HeadingPrior | None], motions: Sequence[MotionFactor]
) -> list[float] | None:
    """Each frame's starting heading (module docstring), or None when no motion joins any frame.

    A frame no motion joins starts at its own answer's heading (0 without one).
    """
    relative = relative_headings(len(alone), motions)
    if all(r is None for r in relative):
        return None
    grid = np.arange(0.0, 360.0, 1.0)
    starts = [a.yaw_deg if a is not None else 0.0 for a in alone]
    runs: dict[int, list[int]] = {}
    for k, r in enumerate(relative):
        if r is not None:
            runs.setdefault(_root(k, relative, motions), []).append(k)
    for members in runs.values():
        score = np.zeros_like(grid)
        for k in members:
            for bearing, weight in _votes(alone[k], compasses[k]):
                offset = (bearing - float(relative[k] or 0.0) - grid + 180.0) % 360.0 - 180.0
                score += weight * np.exp(-0.5 * (offset / VOTE_SIGMA_DEG) ** 2)
        if not score.any():
            continue
        heading = float(grid[int(np.argmax(score))])
        for k in members:
            starts[k] = (heading + float(relative[k] or 0.0)) % 360.0
    return starts


def _votes(alone: AnswerPose | None, compass: HeadingPrior | None) -> list[tuple[float, float]]:
    """A frame's heading votes: (bearing deg, weight) of its own answer and its compass, where it has them."""
    votes = []
    if alone is not None:
        votes.append((alone.yaw_deg, ANCHORED_WEIGHT if alone.source == "anchors" else 1.0))
    if compass is not None:
        votes.append((compass.mean_bearing_deg, 1.0))
    return votes


def _root(k: int, relative: Sequence[float | None], motions: Sequence[MotionFactor]) -> int:
    """The first frame of ``k``'s run (the run's smallest index, which :func:`relative_headings` starts from)."""
    members, queue = {k}, [k]
    while queue:
        i = queue.pop()
        for m in motions:
            for a, b in ((m.source, m.target), (m.target, m.source)):
                if a == i and b not in members:
                    members.add(b)
                    queue.append(b)
    return min(members)
