"""The map's likelihood of one photo: ray casting and the pose likelihood as one object.

:class:`MapLikelihood` binds a map, a photo's image model (built once per photo and identity) and the
likelihood's :class:`geoloc.localize.likelihood.LikelihoodOptions`; the grid search
(:mod:`geoloc.localize.grid`), the reference labelling (:mod:`geoloc.localize.labeling`), the continuous
refinement (:mod:`geoloc.localize.refinement`) and the query stage's checks (:mod:`geoloc.localize.query`)
ask it for p(I | pose) instead of casting panoramas and calling the likelihood themselves. It does the same
arithmetic in the same order as those calls did (``cast_panoramas`` at the image model's bin step, then
:func:`geoloc.localize.likelihood.pose_likelihood` with the map's known building heights when the skyline
term is on): results are bit-identical.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from geoloc.localize.likelihood import LikelihoodOptions, known_building_heights, pose_likelihood
from geoloc.maps import CityMap
from geoloc.maps.raycast import Panoramas, cast_panoramas, window_indices
from geoloc.vision.image_model import ImageModel


@dataclass(frozen=True)
class MapLikelihood:
    """p(I | pose) of one photo's image model on a map, under one set of likelihood options.

    Positions are local metres of ``city_map.frame``, yaws local bearings of the optical axis (deg).
    """

    city_map: CityMap
    image_model: ImageModel
    options: LikelihoodOptions = LikelihoodOptions()

    @property
    def uses_identity(self) -> bool:
        """Whether the identity-aware likelihood is evaluated (asked for, and the model carries identities)."""
        return self.options.use_identity and self.image_model.has_identity

    def with_options(self, **changes: Any) -> MapLikelihood:
        """The same map and image model under options with ``changes`` (``self`` when nothing changes)."""
        options = replace(self.options, **changes)
        return self if options == self.options else MapLikelihood(self.city_map, self.image_model, options)

    def panoramas(self, positions: np.ndarray, yaws_deg: np.ndarray | None = None) -> Panoramas:
        """The map's panoramas at (P, 2) positions, at the image model's bin step.

        yaws_deg: cast only the bearings cameras at these (Y,) yaws see (the rest is left as no hit), for
        :meth:`of_panoramas` at the same yaws and nothing else; the likelihood is bit-identical.
        """
        step = self.image_model.bin_deg
        wanted = None
        if yaws_deg is not None:
            n_bearings = int(round(360.0 / step))
            wanted = window_indices(n_bearings, np.asarray(yaws_deg, dtype=float), self.image_model.offsets_deg)
        return cast_panoramas(self.city_map, positions, bearing_step_deg=step, bearing_indices=wanted)

    def of_panoramas(self, panoramas: Panoramas, yaws_deg: np.ndarray) -> np.ndarray:
        """(P, Y) float32 likelihood at the positions of ``panoramas`` (from :meth:`panoramas`) x (Y,) yaws."""
        heights = known_building_heights(self.city_map) if self.options.use_skyline else None
        return pose_likelihood(panoramas, self.image_model, yaws_deg, self.options, heights)

    def of_poses(self, positions: np.ndarray, yaws_deg: np.ndarray) -> np.ndarray:
        """(P, Y) float32 likelihood at (P, 2) positions x (Y,) yaws."""
        return self.of_panoramas(self.panoramas(positions, yaws_deg), yaws_deg)

    def at(self, x_m: float, y_m: float, yaw_deg: float) -> float:
        """The likelihood of one pose."""
        return float(self.of_poses(np.array([[x_m, y_m]]), np.array([yaw_deg]))[0, 0])
