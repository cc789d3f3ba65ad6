"""Simulated street-view worlds rendered from real OSM footprints, with full ground truth.

- :mod:`geoloc.sim.scene`: the static scene (looks, road raster, trees, cars, sky) of a map.
- :mod:`geoloc.sim.textures`, :mod:`geoloc.sim.signs`, :mod:`geoloc.sim.looks`: a building's procedural look
  (facade tiles, shop signs); :mod:`geoloc.sim.sky_trees`: clouds and tree sprites.
- :mod:`geoloc.sim.pose`: the camera pose and the upright canvas; :mod:`geoloc.sim.render`: one perspective
  photo and its ground truth (:func:`render`), with :mod:`geoloc.sim.shading` (building colours) and
  :mod:`geoloc.sim.occluders` (trees and cars).
- :mod:`geoloc.sim.world`: a world folder, written (:func:`~geoloc.sim.world.generate_world`) and read back
  (:func:`~geoloc.sim.world.load_world`), with :mod:`geoloc.sim.options` (its options and camera),
  :mod:`geoloc.sim.sampling` (the poses) and :mod:`geoloc.sim.contact_sheet`.
"""

from geoloc.sim.pose import Pose
from geoloc.sim.render import Render, render
from geoloc.sim.scene import Scene

__all__ = ["Pose", "Render", "Scene", "render"]
