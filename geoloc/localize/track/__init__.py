"""Tracks: a walk of query photos localised together (issue 20).

The entry is :func:`locate_track` (:mod:`.stage`): the frames of one track, in order, each with its photo's
evidence and priors, to one answer per frame. Each frame is first answered alone by the query stage
(:func:`geoloc.localize.query.geolocate`); the track's smoother then places the frames jointly.
"""

from geoloc.localize.track.stage import FrameAnswer, TrackAnswer, TrackFrame, locate_track

__all__ = ["FrameAnswer", "TrackAnswer", "TrackFrame", "locate_track"]
