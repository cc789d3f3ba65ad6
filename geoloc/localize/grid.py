"""Query geolocation: a probability map over positions x yaws and the top-N distinct poses.

Candidate positions are a regular grid (paper: 10 m, 120 yaws) outside footprints. With a position
prior (e.g. the photo's GPS) the grid covers ``PRIOR_REGION_SIGMAS`` standard deviations around it;
without one, the places that can see the identified buildings (within ``search_radius_m`` of any building
the photo's identities name), and with neither the whole map. The position and heading priors multiply
the likelihood; the answer says which priors were used and how the region was chosen.

Continuous refinement of the best poses is :mod:`geoloc.localize.refinement`'s (used by :mod:`geoloc.localize.query`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.ops import unary_union

from contracts.answers import GridSearch
from geoloc.localize.labeling import resolve_heading_prior
from geoloc.localize.likelihood import default_yaws_deg
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.posterior import (
    DEFAULT_SHARPNESS,
    PoseGrid,
    RankedPose,
    make_grid,
    pose_posterior,
    position_heatmap,
    top_poses,
)
from geoloc.maps import CityMap
from geoloc.maps.places import Place
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.vision.image_model import ImageModel

DEFAULT_QUERY_CELL_M = 10.0
DEFAULT_SEARCH_RADIUS_M = 80.0
PRIOR_REGION_SIGMAS = 3.0
"""A position prior limits the search to this many standard deviations around its centre."""
MAX_PRIOR_WIDENING_M = 160.0
"""A position prior's region with no open cell grows (doubling from one cell) by at most this much (m)."""
MIN_BUILDING_PROBABILITY = 0.05  # identity mass a building needs (max over columns) to define the search region


@dataclass(frozen=True)
class GridOptions:
    """How :func:`localize` searches: a grid of ``cell_m`` cells x ``n_yaws`` yaws over the search region.

    search_radius_m: without a position prior, the region is within this distance of the identified
    buildings. sharpness: the posterior is likelihood ** sharpness x priors. min_separation_m: between the
    top-N answers (None: the grid cell).
    """

    cell_m: float = DEFAULT_QUERY_CELL_M
    search_radius_m: float = DEFAULT_SEARCH_RADIUS_M
    n_yaws: int = 120
    sharpness: float = DEFAULT_SHARPNESS
    min_separation_m: float | None = None


@dataclass
class PositionPrior:
    """A prior on the camera position: near a point or near a shape, falling off as a Gaussian of the distance.

    Without ``shape``: a Gaussian around (x_m, y_m) with standard deviation ``sigma_m`` (m). With ``shape`` (a
    shapely geometry in local metres: a building's footprint, a street's centreline): a band, weight 1 on the
    shape and ``exp(-d^2 / 2 sigma^2)`` at distance ``d`` from it; (x_m, y_m) is then the shape's centroid.
    The API speaks of a prior *radius*, about two standard deviations (:meth:`from_radius`); inside, every
    prior (query GPS here, reference GPS in :mod:`geoloc.localize.labeling`) is a standard deviation.
    """

    x_m: float
    y_m: float
    sigma_m: float
    shape: shapely.Geometry | None = None

    @classmethod
    def from_radius(cls, x_m: float, y_m: float, radius_m: float) -> PositionPrior:
        """The prior of a position known to within ``radius_m`` (about 2 sigma, ~86 % of the mass)."""
        return cls(x_m, y_m, radius_m / 2.0)

    @classmethod
    def near(cls, shape: shapely.Geometry, radius_m: float) -> PositionPrior:
        """The prior of a position within about ``radius_m`` (2 sigma) of ``shape`` (local metres)."""
        centre = shapely.centroid(shape)
        return cls(float(shapely.get_x(centre)), float(shapely.get_y(centre)), radius_m / 2.0, shape)

    @classmethod
    def of_place(cls, place: Place, radius_m: float | None = None) -> PositionPrior:
        """The prior a named place gives: near its shape (:meth:`Place.prior_shape`), else within its disc.

        radius_m: the caller's radius (2 sigma, m) instead of the place's: the distance from the shape, or the
        disc's radius for a place without one.
        """
        shaped = place.prior_shape()
        if shaped is None:
            return cls.from_radius(place.x_m, place.y_m, radius_m or place.radius_m)
        shape, margin_m = shaped
        return cls.near(shape, radius_m or margin_m)

    @property
    def radius_m(self) -> float:
        """Two standard deviations (m)."""
        return 2.0 * self.sigma_m

    def distances_m(self, positions: np.ndarray) -> np.ndarray:
        """(P,) distance (m) of positions (P, 2) from the prior's point or shape (0 on or inside the shape)."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        if self.shape is None:
            return np.asarray(np.hypot(positions[:, 0] - self.x_m, positions[:, 1] - self.y_m))
        return np.asarray(shapely.distance(self.shape, shapely.points(positions)), dtype=float)

    def weights(self, positions: np.ndarray) -> np.ndarray:
        """(P,) prior weight (peak 1) of positions (P, 2)."""
        weights: np.ndarray = np.exp(-0.5 * (self.distances_m(positions) / self.sigma_m) ** 2)
        return weights

    def region(self, sigmas: float) -> shapely.Geometry:
        """Where the prior's weight is above ``exp(-sigmas^2 / 2)``: within ``sigmas`` sigma of its point or shape."""
        core = shapely.Point(self.x_m, self.y_m) if self.shape is None else self.shape
        return shapely.buffer(core, sigmas * self.sigma_m)


@dataclass
class Localization:
    """The answer for one query (local frame).

    grid: the candidate grid; positions: (P, 2) its valid cells; posterior: (P, Y) over positions x yaws.
    heatmap: (rows, cols) probability per grid cell (summed over yaws). poses: top-N distinct poses.
    likelihood: (P, Y) p(I | pose) before priors.
    search: how the candidate region was chosen and which priors were applied.
    """

    grid: PoseGrid
    positions: np.ndarray
    yaws_deg: np.ndarray
    posterior: np.ndarray
    heatmap: np.ndarray
    poses: list[RankedPose]
    likelihood: np.ndarray
    search: GridSearch
    timings_ms: dict[str, float] = field(default_factory=dict)


def identified_buildings(image_model: ImageModel, min_probability: float = MIN_BUILDING_PROBABILITY) -> list[int]:
    """Building ids whose identity probability reaches ``min_probability`` in some column bin."""
    prob, ids = image_model.identity_prob, image_model.identity_building_ids
    if prob is None or ids is None:
        return []
    peak = prob.max(axis=0) if prob.size else np.zeros(0)
    return [int(b) for b in np.asarray(ids)[peak >= min_probability]]


def search_grid(
    city_map: CityMap,
    building_ids: list[int],
    cell_m: float,
    search_radius_m: float,
    position_prior: PositionPrior | None,
) -> tuple[PoseGrid, str]:
    """Candidate grid and a word on how it was chosen ("identified_buildings", "position_prior", "whole_map").

    A position prior's region that holds no open cell (its fix inside a block) grows to the nearest open ones, by
    at most :data:`MAX_PRIOR_WIDENING_M`.
    """
    if position_prior is not None:
        # The prior bounds the search; identities still weigh every pose inside it through the likelihood.
        region = position_prior.region(PRIOR_REGION_SIGMAS)
        reason = "position_prior"
    elif building_ids:
        region = unary_union([city_map.buildings[b].polygon for b in building_ids]).buffer(search_radius_m)
        reason = "identified_buildings"
    else:
        region = shapely.box(*city_map.bounds_m)
        reason = "whole_map"
    grid = _grid_in(city_map, region, cell_m)
    widen_m = cell_m
    while position_prior is not None and not grid.valid.any() and widen_m <= MAX_PRIOR_WIDENING_M:
        # A fix inside a block (a phone's jump beside tall buildings) can bound a region with no open ground: it
        # grows to the nearest open cells, where the prior's own weight still falls off from the fix.
        grid = _grid_in(city_map, shapely.buffer(region, widen_m), cell_m)
        widen_m *= 2.0
    return grid, reason


def _grid_in(city_map: CityMap, region: shapely.Geometry, cell_m: float) -> PoseGrid:
    """The grid of ``cell_m`` cells over ``region``'s bounds, valid where open (not in a building) and inside it."""
    min_x, min_y, max_x, max_y = (float(v) for v in shapely.bounds(region))
    # Snap the grid to multiples of the cell so that grids of different queries share positions.
    origin = np.floor(np.array([min_x, min_y]) / cell_m) * cell_m
    grid = make_grid(city_map, (origin[0], origin[1], max_x, max_y), cell_m)
    inside_region = shapely.contains_xy(region, *grid.positions.T)
    grid.valid[grid.valid] = inside_region
    return grid


def localize(
    likelihood: MapLikelihood,
    options: GridOptions = GridOptions(),
    *,
    candidate_buildings: list[int] | None = None,
    position_prior: PositionPrior | None = None,
    prior_yaw_deg: float | None = None,
    heading_prior: HeadingPrior | None = None,
    top_n: int = 10,
) -> Localization:
    """Localise a photo from its map likelihood (its image model with identities, from transfer) on the map.

    candidate_buildings: the buildings that define the search region (default: those the image model's
    identities name). With ``likelihood.options.use_identity`` False the same region is searched with the
    geometry-only likelihood (the paper's baseline). prior_yaw_deg: a stated heading (local bearing, deg),
    today's Gaussian; or heading_prior: a :class:`HeadingPrior` (the compass's robust prior), not both.
    """
    city_map, image_model = likelihood.city_map, likelihood.image_model
    yaw_prior = resolve_heading_prior(prior_yaw_deg, heading_prior)
    cell_m, n_yaws = options.cell_m, options.n_yaws
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    buildings = identified_buildings(image_model) if candidate_buildings is None else list(candidate_buildings)
    grid, reason = search_grid(city_map, buildings, cell_m, options.search_radius_m, position_prior)
    positions = grid.positions
    yaws = default_yaws_deg(n_yaws)
    has_identity = image_model.identity_prob is not None and float(image_model.identity_prob.sum()) > 0
    # Without any identity evidence the identity-aware likelihood is zero everywhere: use geometry.
    identity_likelihood = bool(likelihood.options.use_identity and has_identity)
    search = GridSearch(
        region=reason,
        buildings=buildings,
        positions=int(len(positions)),
        yaws=n_yaws,
        cell_m=cell_m,
        identity=identity_likelihood,
        position_prior=position_prior is not None,
        position_prior_shaped=position_prior is not None and position_prior.shape is not None,  # a place's
        heading_prior=yaw_prior is not None,
    )
    if len(positions) == 0:
        raise ValueError("no candidate positions: the search region lies entirely inside buildings")
    timings["grid"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    panoramas = likelihood.panoramas(positions)
    timings["raycast"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    likelihood_table = likelihood.with_options(use_identity=identity_likelihood).of_panoramas(panoramas, yaws)
    timings["likelihood"] = 1e3 * (time.perf_counter() - t0)

    prior = _prior(positions, yaws, position_prior, yaw_prior)
    posterior = pose_posterior(likelihood_table, prior, options.sharpness)
    separation = cell_m if options.min_separation_m is None else options.min_separation_m
    poses = top_poses(positions, posterior, yaws, n=top_n, min_separation_m=separation, likelihood=likelihood_table)
    heatmap = grid.to_image(position_heatmap(posterior))
    return Localization(grid, positions, yaws, posterior, heatmap, poses, likelihood_table, search, timings)


def _prior(
    positions: np.ndarray, yaws: np.ndarray, position_prior: PositionPrior | None, yaw_prior: HeadingPrior | None
) -> np.ndarray | None:
    if position_prior is None and yaw_prior is None:
        return None
    prior = np.ones((len(positions), len(yaws)))
    if position_prior is not None:
        prior *= position_prior.weights(positions)[:, None]
    if yaw_prior is not None:
        prior *= yaw_prior.weights(yaws)[None, :]
    return prior
