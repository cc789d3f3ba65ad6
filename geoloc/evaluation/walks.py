"""A world's walks as the workers place them: photos labelled alone grouped into walks, each placed jointly.

The evaluation's side of the sequence stage (:mod:`geoloc.localize.sequence.stage`): the workers group stored rows
and read their priors from the database; here a world's photos are grouped by what they carry and their compass
read from their EXIF, with the same functions (:func:`geoloc.localize.sequence.grouping.group_sequences`,
:func:`geoloc.localize.sequence.stage.place_labelled_sequence`, :func:`geoloc.localize.reference.heading_prior_at`).
"""

from __future__ import annotations

from geoloc.localize.reference import LabelledReference, heading_prior_at
from geoloc.localize.sequence.frames import FrameLabel
from geoloc.localize.sequence.grouping import SequenceMember, group_sequences
from geoloc.localize.sequence.placement import PlacementOptions
from geoloc.localize.sequence.stage import LabelledFrame, PlacedSequence, capture_seconds, place_labelled_sequence
from geoloc.maps import CityMap
from geoloc.photos.capture import photo_device
from geoloc.photos.heading_prior import HeadingPrior, compass_accuracy_deg
from geoloc.photos.photo import Photo


def compass_prior_at(photo: Photo, city_map: CityMap, xy: tuple[float, float]) -> HeadingPrior | None:
    """The photo's compass as the service's prior at a local point (m), None without a compass.

    Built as the workers build a stored reference's (:func:`geoloc.localize.reference.heading_prior_at`), from the
    heading and the accuracy the service stores (:func:`geoloc.photos.heading_prior.compass_accuracy_deg`).
    """
    compass = photo.capture.compass
    if compass is None:
        return None
    return heading_prior_at(city_map.frame, compass.heading_deg, compass_accuracy_deg(compass), xy[0], xy[1])


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


def _local_gps(city_map: CityMap, photo: Photo) -> tuple[float, float]:
    """A photo's EXIF GPS in the map's local metres (ValueError without one)."""
    if photo.gps is None:
        raise ValueError("a photo of a walk needs its EXIF GPS")
    x, y = (float(v) for v in city_map.frame.to_local(*photo.gps))
    return x, y
