"""The sequence stage's entry: frames labelled alone in, the same frames placed jointly and re-labelled out.

Used by the workers' sequence job and by ``geoloc eval world``: each frame was labelled alone first
(:func:`geoloc.localize.reference.label_reference_photo`, as every reference is); the walk's frames are then placed
in one pose graph (:func:`geoloc.localize.sequence.placement.place_sequence`) and each is re-labelled at its
placed pose (:func:`geoloc.localize.reference.label_at_pose`: identities and anchors from there). A frame that no
relative pose joins to the others keeps its own label unchanged (its label already weighed its GPS and compass),
so a "sequence" of photos that do not see each other (consecutive captures of scattered places) changes nothing.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime

from geoloc.localize.labeling import KnownPose
from geoloc.localize.reference import LabelledReference, label_at_pose
from geoloc.localize.sequence.frames import FrameLabel, map_position_covariance
from geoloc.localize.sequence.grouping import SequenceMember, group_sequences
from geoloc.localize.sequence.placement import (
    DEFAULT_GPS_SIGMA_M,
    PlacedPose,
    PlacementOptions,
    SequenceFrame,
    place_sequence,
    relative_poses,
)
from geoloc.maps import CityMap
from geoloc.photos.capture import photo_device
from geoloc.photos.heading_prior import HeadingPrior, heading_prior_from_compass
from geoloc.photos.photo import Photo


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

    references: the frames re-labelled at their placed poses (in order; None: a frame no relative pose joined,
    which keeps its own label); poses: those poses; n_edges: how many
    relative poses joined them (0: each frame kept what its own label, GPS and compass say).
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

    Each re-labelled reference's ``timings_ms`` gains ``sequence``: its share of the placement (ms); a frame no
    relative pose joins comes back as None (its own label stands).
    """
    t0 = time.perf_counter()
    graph_frames = [_frame(city_map, frame) for frame in frames]
    edges = relative_poses(graph_frames, options)
    poses = place_sequence(graph_frames, options, edges)
    share_ms = 1e3 * (time.perf_counter() - t0) / max(len(frames), 1)
    references: list[LabelledReference | None] = []
    for frame, pose in zip(frames, poses, strict=True):
        if pose.n_edges == 0:  # nothing joins it to the walk: its own label already weighs its GPS and compass
            references.append(None)
            continue
        known = KnownPose(pose.x_m, pose.y_m, pose.yaw_deg, pose.position_covariance)
        alone = frame.alone
        placed = label_at_pose(city_map, alone.intrinsics, alone.cues, alone.timings_ms, known, analysis=alone.analysis)
        placed.timings_ms["sequence"] = share_ms
        references.append(placed)
    return PlacedSequence(references, poses, len(edges))


def compass_prior_at(photo: Photo, city_map: CityMap, xy: tuple[float, float]) -> HeadingPrior | None:
    """The photo's compass as the service's robust prior at a local point (m), None without a compass."""
    compass = photo.capture.compass
    return None if compass is None else heading_prior_from_compass(compass, city_map.frame, xy[0], xy[1])


def place_photo_walks(
    city_map: CityMap,
    photos: dict[str, Photo],
    labelled: dict[str, LabelledReference],
    options: PlacementOptions = PlacementOptions(),
) -> list[PlacedSequence]:
    """Group geo-tagged photos labelled alone into walks by what they carry and place each walk, as the workers do.

    photos, labelled: by name, in upload order (the grouping's tie-breaker), every photo with EXIF GPS.
    ``labelled`` is updated in place with each walk's re-labelled frames; returns the placed walks. options: the
    placement's (the workers use the default; ``benchmarks/bench_walk_placement.py`` compares others).
    """
    xy_of = {name: _local_gps(city_map, photo) for name, photo in photos.items()}
    members = [
        SequenceMember(
            name,
            photo.capture.sequence_id,
            photo.capture.time,
            photo_device(photo.exif.make, photo.exif.model),
            xy_of[name],
            order,
        )
        for order, (name, photo) in enumerate(photos.items())
    ]
    walks = []
    for group in group_sequences(members):
        names = [str(name) for name in group]
        frames = [
            LabelledFrame(
                FrameLabel.of(labelled[name], photos[name].intrinsics),
                xy_of[name],
                heading_prior=compass_prior_at(photos[name], city_map, xy_of[name]),
                capture_time_s=capture_seconds(photos[name].capture.time),
            )
            for name in names
        ]
        placed = place_labelled_sequence(city_map, frames, options)
        labelled.update((name, ref) for name, ref in zip(names, placed.references, strict=True) if ref is not None)
        walks.append(placed)
    return walks


def capture_seconds(taken: datetime | None) -> float | None:
    """A capture time as POSIX seconds for a walk's steps, None when unknown.

    A naive camera time is read as UTC: only differences within one walk, on one camera's clock, are used.
    """
    if taken is None:
        return None
    return (taken if taken.tzinfo is not None else taken.replace(tzinfo=UTC)).timestamp()


def _local_gps(city_map: CityMap, photo: Photo) -> tuple[float, float]:
    """A photo's EXIF GPS in the map's local metres (ValueError without one)."""
    if photo.gps is None:
        raise ValueError("a photo of a walk needs its EXIF GPS")
    x, y = (float(v) for v in city_map.frame.to_local(*photo.gps))
    return x, y
