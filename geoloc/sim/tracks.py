"""Query tracks: walks of query photos (issue 20), taken as the references' walks are (:mod:`geoloc.sim.walks`).

A track is a walk on the map's streets with a photo every ``TRACK_STEP_M`` (3-8 m) of walking: the walker,
the heading modes, the phone's GPS (an offset correlated along the walk, occasional jumps), its compass (on
``COMPASS_SHARE`` of the frames) and the capture times are drawn exactly as for a reference walk. Tracks draw
from their own generator (``[seed, 500]``), so a world without tracks is the world it was before they existed.
Tracks start a day after the reference walks, 20 min apart.
"""

from __future__ import annotations

from datetime import timedelta

import numpy as np

from geoloc.sim.options import WorldOptions
from geoloc.sim.scene import Scene
from geoloc.sim.walks import (
    FIRST_WALK_START,
    NoStreetsError,
    Shot,
    Walk,
    _centreline,
    _dense,
    _draw_walk,
    _street_graph,
    _tall_near,
    _walked_path,
    photo_indices,
    walk_shots,
)

TRACK_STEP_M = (3.0, 8.0)
"""Walking distance and straight-line distance between consecutive frames of a track (m)."""
FIRST_TRACK_START = FIRST_WALK_START + timedelta(days=1)


def sample_tracks(scene: Scene, opts: WorldOptions, centre: np.ndarray) -> tuple[list[Shot], list[Walk]]:
    """``opts.query_tracks`` tracks of ``opts.track_length`` frames: the shots in track order and their walks.

    A shot's ``walk_id`` is its track's number (from 0) and its ``index`` its place in the track. A walk that the
    buildings cut shorter than ``track_length`` is drawn again elsewhere (up to 50 tries per track).
    """
    if opts.query_tracks <= 0:
        return [], []
    nodes, adj = _street_graph(scene.map)
    if not any(adj):
        raise NoStreetsError(f"{scene.map.source}: query tracks need streets (OSM highways); this map has none")
    rng = np.random.default_rng([opts.seed, 500])
    tall = _tall_near(scene)
    shots: list[Shot] = []
    walks: list[Walk] = []
    length = opts.track_length
    for _attempt in range(50 * opts.query_tracks):
        if len(walks) >= opts.query_tracks:
            break
        walk = _draw_walk(len(walks), rng)
        line = _centreline(nodes, adj, rng, length * TRACK_STEP_M[1] + 30.0, centre, opts.radius_m)
        pts, tan = _dense(line)
        path, path_tan = _walked_path(scene, walk, pts, tan)
        if len(path) < 2:
            continue
        picked = photo_indices(path, rng, length, TRACK_STEP_M)
        if len(picked) < length:
            continue
        walks.append(walk)
        start = FIRST_TRACK_START + timedelta(minutes=20 * walk.walk_id, seconds=float(rng.uniform(0.0, 300.0)))
        shots.extend(walk_shots(walk, path[picked], path_tan[picked], start, tall, opts, rng))
    return shots, walks
