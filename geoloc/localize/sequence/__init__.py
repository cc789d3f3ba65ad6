"""Sequences of reference photos (walks) placed jointly on the map (issue 19).

- :mod:`.grouping`: which references form one sequence (a stated sequence id, Mapillary's sequence id, or one
  device's consecutive captures);
- :mod:`.relative`: the relative pose of two frames of a walk from their verified matches (PnP on one frame's
  map-anchored keypoints);
- :mod:`.placement`: every frame's pose, jointly, in one robust pose graph (gtsam);
- :mod:`.pace`: the walk's pace from its capture times, the steps' distances and the edges it rules out;
- :mod:`.frames`: what the placement needs of a frame labelled alone, and that as stored arrays (the workers);
- :mod:`.stage`: the stage's entry, :func:`place_labelled_sequence`: labelled frames in, re-labelled frames out.
"""

from geoloc.localize.sequence.grouping import SequenceMember, group_sequences
from geoloc.localize.sequence.placement import PlacedPose, PlacementOptions, SequenceFrame, place_sequence
from geoloc.localize.sequence.stage import place_labelled_sequence

__all__ = [
    "PlacedPose",
    "PlacementOptions",
    "SequenceFrame",
    "SequenceMember",
    "group_sequences",
    "place_labelled_sequence",
    "place_sequence",
]
