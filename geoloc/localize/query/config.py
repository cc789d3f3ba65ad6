"""The query stage's configuration: :class:`QueryConfig`, every knob, recorded with each answer."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from contracts.queries import QueryPreset
from geoloc.localize.grid import GridOptions
from geoloc.localize.posterior import DEFAULT_SHARPNESS

SPARE_POSES = 3
"""Likelihood poses asked beyond ``top_n``: ones that coincide after refinement (or with the anchored pose)
are dropped, and the spares keep the answer at ``top_n`` locations."""
PRIOR_SHORTLIST_FACTOR = 3
"""With a position prior, this many times the shortlist is ranked before far references are left out."""
CHI2_2D_90 = 4.605
"""90 % quantile of the chi-square distribution with 2 degrees of freedom (2D position regions)."""


@dataclass(frozen=True)
class QueryConfig:
    """Every knob of the query stage, recorded with each answer (``search.config``) and evaluation.

    The fields are flat (their names are those of the recorded ``search.config``); :attr:`grid` gives the
    grid search's :class:`geoloc.localize.grid.GridOptions` from them.
    """

    shortlist: int = 20
    """Retrieval: SBoW candidates re-ranked by verified inliers."""
    k: int = 4
    """Transfer: the top ``k`` re-ranked references transfer their identities (the paper's k)."""
    anchor_references: int = 6
    """Anchors: the query is matched to this many best references for the PnP."""
    use_identity: bool = True
    """Likelihood: identity-aware (False: the paper's geometry-only baseline)."""
    identity_view_m: float = 30.0
    """Likelihood: the transferred identities are trusted by how near their nearest reference stands to the
    position prior, this view distance (m) beyond its sigma (:func:`geoloc.localize.query.retrieve.identity_trust`;
    0: always trusted, as before). 30 m was the best of 30, 50 and 80 on Helsinki seed 1's walk world."""
    use_anchors: bool = True
    """Anchors: the map-anchored PnP pose (False: the paper's likelihood alone)."""
    cell_m: float = 10.0
    """Likelihood: the grid cell (m), over the prior's region, else near the identified buildings."""
    search_radius_m: float = 80.0
    """Likelihood: without a prior, the grid is within this distance (m) of the identified buildings."""
    n_yaws: int = 120
    """Likelihood: yaws of the grid over 360 deg."""
    refine_poses: int = 3
    """Likelihood: this many best poses are refined continuously."""
    sharpness: float = DEFAULT_SHARPNESS
    """Likelihood: the posterior is ``likelihood ** sharpness x priors``."""
    uncertainty_sharpness: float = 0.1
    """Uncertainty: a likelihood pose's radius holds 90 % of the posterior tempered to this power."""
    pnp_threshold_px: float = 4.0
    """Anchors: the PnP's inlier threshold (px)."""
    pnp_max_iters: int = 2000
    """Anchors: each reference group's PnP RANSAC iterations at most (a wrong reference, a few per cent of inliers,
    runs them all; 1,000 moved two Helsinki answers through the service, docs/speed.md)."""
    pnp_min_inliers: int = 20
    """Trust: at least this many PnP inliers."""
    anchor_ratio: float = 0.9
    """Anchors: Lowe ratio of the anchor matches (looser than retrieval's: the PnP's RANSAC rejects outliers)."""
    strong_inliers: int = 30
    """Trust: below this many inliers the map's likelihood at the pose must agree (``min_likelihood_ratio``)."""
    min_likelihood_ratio: float = 0.8
    """Trust: share of the grid's best likelihood the pose must reach (repeated facade elements let wrong
    references pass RANSAC with a few inliers)."""
    max_height_error_m: float = 2.0
    """Trust: the camera within this height (m) of hand height."""
    max_pitch_deg: float = 20.0
    """Trust: the camera within this pitch (deg) of level."""
    prior_sigmas: float = 3.0
    """Trust and retrieval: within this many sigmas of the position prior."""
    view_range_m: float = 100.0
    """Retrieval: with a prior, references farther than ``prior_sigmas`` sigmas plus this (m) are left out."""
    anchor_sigma_floor_m: float = 5.0
    """Uncertainty: each anchoring reference is credited at least this position sigma (m)."""
    refine_anchored: bool = True
    """Fusion: a trusted anchored pose is refined on the map."""

    def as_dict(self) -> dict[str, float | int | bool]:
        """The configuration as a JSON-ready dict."""
        return asdict(self)

    @property
    def grid(self) -> GridOptions:
        """The grid search's options (:func:`geoloc.localize.grid.localize`)."""
        return GridOptions(self.cell_m, self.search_radius_m, self.n_yaws, self.sharpness)


PRESETS: dict[QueryPreset, QueryConfig] = {
    "fast": QueryConfig(shortlist=10, anchor_references=3, n_yaws=72, refine_poses=1),
    "balanced": QueryConfig(),
    "accurate": QueryConfig(shortlist=30, anchor_references=10, cell_m=5.0, n_yaws=180, refine_poses=5),
}
"""The query presets (``preset`` of a query, ``GEOLOC_QUERY_PRESET``; names in :data:`contracts.queries.QUERY_PRESETS`).

``balanced`` is the default :class:`QueryConfig` (the answers and figures measured before presets existed).
``fast`` cuts the stage's expensive parts: 10 shortlisted references re-ranked by RANSAC (20), 3 anchor
references for the PnP (6), 72 yaws (5 deg) on the grid (120, 3 deg), 1 likelihood pose refined (3).
``accurate`` spends more: 30 shortlisted references, 10 anchor references, 5 m cells (10 m), 180 yaws (2 deg),
5 refined poses. Segmentation, facades and features (about half of a query's time) are the same in all three.
The figures are in ``docs/measurements/speed.md`` (Query presets).
"""


def preset_config(preset: QueryPreset, *, k: int | None = None) -> QueryConfig:
    """The :class:`QueryConfig` of ``preset``, with the query's own ``k`` (identity references) when given."""
    config = PRESETS[preset]
    return config if k is None else replace(config, k=k)
