"""The sequence stage's entry: frames labelled alone in, the same frames placed jointly and re-labelled out.

Used by the workers' sequence job and by ``geoloc eval world`` (through
:func:`geoloc.evaluation.walks.place_photo_walks`, which groups a world's photos as the workers group their
rows): each frame was labelled alone first (:func:`geoloc.localize.reference.label_reference_photo`, as every
reference is); the walk's frames are then placed
in one pose graph (:func:`geoloc.localize.sequence.placement.place_sequence`) and each is re-labelled at its
placed pose, its heading refined by the facades seen from there
(:func:`geoloc.localize.refinement.vanishing_point_yaw`;
:func:`geoloc.localize.reference.label_at_pose`: identities and anchors from there). A frame that
no relative pose joins to the others keeps its own label unchanged (its label already weighed its GPS and
compass) unless its steps between capture times place it more than a few metres away (:func:`keeps_own_label`),
so a "sequence" of photos that do not see each other (consecutive captures of scattered places: no relative
pose, so no pace to step by) changes nothing.

Before the graph is built, a walk whose compass agrees with most of its labels has each label that faces away
from its compass done again with the compass trusted (:func:`compass_relabelled`): the map alone turns a frame
with little facade in view to the mirror view across the street now and then, and the graph cannot overrule a
label whose neighbours were pulled the same way.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime

from geoloc.core.geo import angle_difference_deg
from geoloc.localize.label_covariance import stated_position_covariance
from geoloc.localize.labeling import KnownPose
from geoloc.localize.reference import LabelledReference, label_at_pose, label_from_cues
from geoloc.localize.refinement import vanishing_point_yaw
from geoloc.localize.sequence.frames import FrameLabel, map_position_covariance
from geoloc.localize.sequence.placement import (
    DEFAULT_GPS_SIGMA_M,
    PlacedPose,
    PlacementOptions,
    SequenceFrame,
    place_sequence,
    relative_poses,
)
from geoloc.localize.sequence.relative import RelativePose
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior


@dataclass(frozen=True)
class LabelledFrame:
    """One frame of a sequence, labelled alone.

    alone: what the placement needs of its label alone (:class:`geoloc.localize.sequence.frames.FrameLabel`:
    built from the label, or read back from the store); gps_xy, gps_sigma_m: its GPS tag (local m) and that
    tag's sigma (m); heading_prior: its compass prior (None: none); capture_time_s: its capture time (POSIX s;
    None: unknown).
    """

    alone: FrameLabel
    gps_xy: tuple[float, float]
    gps_sigma_m: float = DEFAULT_GPS_SIGMA_M
    heading_prior: HeadingPrior | None = None
    capture_time_s: float | None = None


@dataclass(frozen=True)
class PlacedSequence:
    """A sequence placed jointly.

    references: the frames re-labelled at their placed poses (in order; None: a frame that keeps its own label,
    :func:`keeps_own_label`; such a frame whose label :func:`compass_relabelled` replaced comes back with that new
    label); poses: those poses; n_edges: how many relative poses joined them.
    """

    references: list[LabelledReference | None]
    poses: list[PlacedPose]
    n_edges: int


def _frame(city_map: CityMap, frame: LabelledFrame) -> SequenceFrame:
    """The graph's frame: the label's pose with what the map alone says of its position (its GPS comes in once)."""
    alone = frame.alone
    return SequenceFrame(
        alone.x_m,
        alone.y_m,
        alone.yaw_deg,
        map_position_covariance(city_map, alone.cues.image_model, alone.x_m, alone.y_m, alone.yaw_deg),
        frame.gps_xy,
        frame.gps_sigma_m,
        frame.heading_prior,
        alone.cues.features,
        alone.anchors,
        alone.intrinsics,
        capture_time_s=frame.capture_time_s,
    )


def place_labelled_sequence(
    city_map: CityMap, frames: Sequence[LabelledFrame], options: PlacementOptions = PlacementOptions()
) -> PlacedSequence:
    """Place a walk's frames jointly and re-label each at its placed pose (module docstring).

    Each re-labelled reference's ``timings_ms`` gains ``sequence``: its share of the placement (ms); a frame that
    keeps its own label (:func:`keeps_own_label`) comes back as None unless the compass relabelled it
    (``options.compass_walk_agreement``; :func:`compass_relabelled`).
    """
    t0 = time.perf_counter()
    graph_frames = [_frame(city_map, frame) for frame in frames]
    edges = relative_poses(graph_frames, options)
    relabelled = compass_relabelled(city_map, frames, edges, options.compass_walk_agreement)
    if relabelled:
        frames = [
            replace(frame, alone=FrameLabel.of(relabelled[k], frame.alone.intrinsics)) if k in relabelled else frame
            for k, frame in enumerate(frames)
        ]
        graph_frames = [
            _frame(city_map, frame) if k in relabelled else graph_frames[k] for k, frame in enumerate(frames)
        ]
        edges = [edge for edge in edges if edge.source not in relabelled and edge.target not in relabelled]
        edges += relative_poses(graph_frames, options, touching=set(relabelled))
    poses = place_sequence(graph_frames, options, edges)
    share_ms = 1e3 * (time.perf_counter() - t0) / max(len(frames), 1)
    references: list[LabelledReference | None] = []
    for k, (frame, pose) in enumerate(zip(frames, poses, strict=True)):
        alone = frame.alone
        if keeps_own_label(pose, alone.x_m, alone.y_m):  # its own label (or its compass's) stands
            references.append(relabelled.get(k))
            continue
        stated = stated_position_covariance(pose.position_covariance, (pose.x_m, pose.y_m), frame.gps_xy)
        # The graph's heading comes from the neighbours' edges and the label's 2 deg; the facades seen from the
        # placed position say it more sharply, as they do for a label alone.
        yaw_deg, _ = vanishing_point_yaw(city_map, alone.cues.image_model, pose.x_m, pose.y_m, pose.yaw_deg)
        known = KnownPose(pose.x_m, pose.y_m, yaw_deg, stated)
        placed = label_at_pose(city_map, alone.intrinsics, alone.cues, alone.timings_ms, known, analysis=alone.analysis)
        placed.timings_ms["sequence"] = share_ms
        references.append(placed)
    return PlacedSequence(references, poses, len(edges))


STEPS_OVERRULE_M = 3.0
"""A frame its steps alone join to its walk takes the walk's pose only when that lies farther than this (m) from its
own label: three sigmas of a walker's step (docs/measurements/accuracy.md, "The walk's pace": steps scatter about
1 m)."""


def keeps_own_label(pose: PlacedPose, label_x_m: float, label_y_m: float) -> bool:
    """Whether a placed frame keeps its label alone (at local ``label_x_m``, ``label_y_m``) instead of the walk's pose.

    It does when nothing joined it to the walk (:attr:`PlacedPose.joined`), or when only its steps between capture
    times did and the walk places it within :data:`STEPS_OVERRULE_M` of its label: steps say how far a walker went,
    not where a label with the map's anchors was wrong by a metre or two, while a label the steps put farther off
    is more often on the wrong stretch of the street than the walk is (docs/measurements/accuracy.md, "Frames joined by
    their steps alone").
    """
    if not pose.joined:
        return True
    return pose.n_edges == 0 and math.hypot(pose.x_m - label_x_m, pose.y_m - label_y_m) <= STEPS_OVERRULE_M


COMPASS_AGREES_DEG = 45.0
"""A heading agrees with a compass (or with another heading) when they are within this (deg)."""
COMPASS_DISAGREES_DEG = 90.0
"""A label faces away from its compass when their headings are more than this apart (deg)."""
MIN_COMPASS_FRAMES = 3
"""The fewest frames with a compass from which a walk's agreement with its compass is judged."""


def compass_relabelled(
    city_map: CityMap, frames: Sequence[LabelledFrame], edges: Sequence[RelativePose], min_agreement: float | None
) -> dict[int, LabelledReference]:
    """The frames of a walk whose compass the walk trusts but whose label faces away from it, labelled again.

    A walk trusts its compass when at least ``min_agreement`` of its frames with one (and at least
    :data:`MIN_COMPASS_FRAMES`) were labelled within :data:`COMPASS_AGREES_DEG` of it: a magnetometer that is
    wrong is often wrong for a whole walk (the Lund walk's first 20 readings), while the map alone now and then
    turns a frame with little facade in view to the mirror view across the street. Each label more than
    :data:`COMPASS_DISAGREES_DEG` from its compass is done again with the compass as a plain Gaussian (no
    outlier floor). The new label replaces the old when it agrees with the compass and the walk's neighbours do
    not side with the old one: the headings that the edges into the frame predict from their sources' labels
    (``edges``: the walk's relative poses; sources whose own label faces away from their compass left out)
    agree with the new label at least as often as with the old (a compass that is the one wrong reading of a
    good walk is outvoted this way: Helsinki walk world 1's one wrong compass, six neighbours against it).
    Returns the new labels by frame index (none when ``min_agreement`` is None).
    """
    if min_agreement is None:
        return {}
    offsets = {
        k: angle_difference_deg(frame.alone.yaw_deg, frame.heading_prior.mean_bearing_deg)
        for k, frame in enumerate(frames)
        if frame.heading_prior is not None
    }
    if len(offsets) < MIN_COMPASS_FRAMES:
        return {}
    if sum(offset <= COMPASS_AGREES_DEG for offset in offsets.values()) < min_agreement * len(offsets):
        return {}
    relabelled = {}
    for k, offset in offsets.items():
        frame, compass = frames[k], frames[k].heading_prior
        if offset <= COMPASS_DISAGREES_DEG or compass is None:
            continue
        alone = frame.alone
        strict = HeadingPrior(compass.mean_bearing_deg, compass.sigma_deg, 0.0)
        again = label_from_cues(
            city_map,
            alone.intrinsics,
            alone.cues,
            alone.timings_ms,
            frame.gps_xy,
            heading_prior=strict,
            analysis=alone.analysis,
            timing_key="relabeling",
        )
        if angle_difference_deg(again.label.yaw_deg, compass.mean_bearing_deg) > COMPASS_AGREES_DEG:
            continue
        # A neighbour is a witness when its own label agrees with its compass (or it has none).
        witnesses = [e for e in edges if e.target == k and offsets.get(e.source, 0.0) <= COMPASS_AGREES_DEG]
        predicted = [frames[e.source].alone.yaw_deg + e.turn_deg for e in witnesses]
        for_new = sum(angle_difference_deg(yaw, again.label.yaw_deg) <= COMPASS_AGREES_DEG for yaw in predicted)
        for_old = sum(angle_difference_deg(yaw, alone.yaw_deg) <= COMPASS_AGREES_DEG for yaw in predicted)
        if for_new >= for_old:
            relabelled[k] = again
    return relabelled


def capture_seconds(taken: datetime | None) -> float | None:
    """A capture time as POSIX seconds for a walk's steps, None when unknown.

    A naive camera time is read as UTC: only differences within one walk, on one camera's clock, are used.
    """
    if taken is None:
        return None
    return (taken if taken.tzinfo is not None else taken.replace(tzinfo=UTC)).timestamp()
