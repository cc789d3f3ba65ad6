"""Simulated street-view worlds rendered from real OSM footprints, with full ground truth.

- :mod:`geoloc.sim.scene`: the static scene (looks, road raster, trees, cars, sky) of a map.
- :mod:`geoloc.sim.render`: one perspective photo and its ground truth (:func:`render`).
- :mod:`geoloc.sim.world`: sampling poses, writing a world to disk, loading it back.
"""

from geoloc.sim.render import Pose, Render, render
from geoloc.sim.scene import Scene

__all__ = ["Pose", "Render", "Scene", "render"]
