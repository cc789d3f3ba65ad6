"""Which reference photos form one sequence (a walk), and in which order.

A sequence is, in this order of precedence:

1. the references that share a stated sequence id (the upload's ``sequence`` form field, or Mapillary's
   ``MAPSequenceUUID`` read from the photo), ordered by capture time (then by upload order);
2. otherwise, one device's consecutive captures: references without a sequence id, with a capture time and the
   same device (EXIF make and model), sorted by capture time, where each photo follows the previous one within
   :data:`MAX_GAP_S` seconds and :data:`MAX_STEP_M` metres (GPS). A photo that names no camera is grouped by
   nothing but a sequence id: without a device, "one device's captures" cannot be told from several people's
   photos that happen to be close (phones write their make and model; simulated scattered worlds do not, and stay
   as they were).

A group of one photo is no sequence; its reference is labelled alone, as before.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from datetime import datetime

MAX_GAP_S = 60.0
"""Two captures of one device further apart in time than this (s) start a new sequence."""
MAX_STEP_M = 50.0
"""Two captures of one device further apart (GPS, m) than this start a new sequence."""


@dataclass(frozen=True)
class SequenceMember:
    """What grouping needs of one reference.

    reference_id: the caller's key. sequence_id: stated or Mapillary sequence id (None: not stated).
    capture_time: when it was taken (None: unknown; aware or naive, compared as given). device: make and model.
    gps_xy: the GPS tag in the map's local frame (m). order: upload order, the tie-breaker.
    """

    reference_id: Hashable
    sequence_id: str | None
    capture_time: datetime | None
    device: str | None
    gps_xy: tuple[float, float]
    order: int


def _time_key(member: SequenceMember) -> tuple[float, int]:
    t = member.capture_time
    return (t.timestamp() if t is not None else math.inf, member.order)


def _close(a: SequenceMember, b: SequenceMember, max_gap_s: float, max_step_m: float) -> bool:
    assert a.capture_time is not None and b.capture_time is not None
    try:
        gap = abs((b.capture_time - a.capture_time).total_seconds())
    except TypeError:  # one aware, one naive: their clocks cannot be compared
        return False
    step = math.hypot(b.gps_xy[0] - a.gps_xy[0], b.gps_xy[1] - a.gps_xy[1])
    return gap <= max_gap_s and step <= max_step_m


def group_sequences(
    members: Sequence[SequenceMember], *, max_gap_s: float = MAX_GAP_S, max_step_m: float = MAX_STEP_M
) -> list[list[Hashable]]:
    """The sequences among ``members`` (rules in the module docstring): reference ids in capture order.

    Groups of one are left out; every reference appears in at most one group.
    """
    stated: dict[str, list[SequenceMember]] = {}
    by_device: dict[str, list[SequenceMember]] = {}
    for member in members:
        if member.sequence_id:
            stated.setdefault(member.sequence_id, []).append(member)
        elif member.capture_time is not None and member.device is not None:
            by_device.setdefault(member.device, []).append(member)
    groups = [sorted(group, key=_time_key) for group in stated.values()]
    for captures in by_device.values():
        captures.sort(key=_time_key)
        run = [captures[0]]
        for member in captures[1:]:
            if _close(run[-1], member, max_gap_s, max_step_m):
                run.append(member)
            else:
                groups.append(run)
                run = [member]
        groups.append(run)
    return [[m.reference_id for m in group] for group in groups if len(group) > 1]
