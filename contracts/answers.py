"""The answers that workers store and the API serves: one pydantic contract for both.

The workers' handlers build these models directly (:mod:`workers.query_handlers`,
:mod:`workers.reference_labels`); a value that does not
fit (a missing or unknown field, a wrong type, a NaN) raises pydantic's ``ValidationError`` while the answer
is built, which :func:`workers.handlers.answer_checked` turns into a permanent job failure naming the field,
so nothing malformed is stored. What is stored is the model's JSON form (``model_dump(mode="json")``),
exactly what the API serves: the API's response models (:mod:`contracts.api`) embed the same classes.
Only pydantic is imported here (contracts are the bottom layer).

The models forbid unknown fields and non-finite numbers: a field added to an answer must be added
here too (the OpenAPI reference then shows it), and a NaN never reaches a client.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class _Answer(BaseModel):
    """Base of the answer models: unknown fields and NaN/infinity are errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def _absent(value: object) -> bool:
    """An optional part that was not recorded is left out of the JSON (as answers stored before it have it)."""
    return value is None


class BoundingBox(_Answer):
    """A WGS84 bounding box (degrees)."""

    min_lat: float = Field(examples=[60.1641551])
    min_lon: float = Field(examples=[24.9351773])
    max_lat: float = Field(examples=[60.1791068])
    max_lon: float = Field(examples=[24.9534066])


class LatLon(_Answer):
    """A WGS84 position (degrees)."""

    lat: float = Field(examples=[60.1699])
    lon: float = Field(examples=[24.9384])


class EstimatedPose(_Answer):
    """A reference's pose as labelling found it (WGS84 degrees, compass heading)."""

    lat: float | None = None
    lon: float | None = None
    heading_deg: float | None = Field(default=None, description="Degrees clockwise from north")


class RankedLocation(_Answer):
    """One answer: where the photo was taken and which way it looked."""

    rank: int = Field(examples=[1])
    lat: float = Field(examples=[60.16952])
    lon: float = Field(examples=[24.94117])
    heading_deg: float = Field(
        description="Compass heading of the optical axis, deg clockwise from north", examples=[93.0]
    )
    probability: float = Field(description="Probability that this answer is the right one", examples=[0.8])
    uncertainty_radius_m: float = Field(
        description="Radius (m) of the region around this position that holds the true position with 90 % "
        "probability (anchored answers: PnP and reference uncertainty; likelihood answers: the posterior's mass)",
        examples=[4.2],
    )
    source: str = Field(
        description="'anchors': PnP on reference keypoints anchored on the map's facades, refined on the map; "
        "'likelihood': the map likelihood's probability map; 'track': a track's frame placed jointly with its "
        "neighbours (docs/tracks.md)",
        examples=["anchors"],
    )
    inliers: int = Field(description="PnP inliers of an anchored answer (0 for likelihood answers)", examples=[46])


class Heatmap(_Answer):
    """The probability map on its georeferenced grid (local east-north metres of the map's frame).

    ``values[row][col]`` is the probability of the cell centred at local
    (origin_local_m.x + col * cell_m, origin_local_m.y + row * cell_m): rows run south to north, columns
    west to east. ``origin`` is that first cell's centre in WGS84; ``bounds`` the grid's outer edges.
    """

    origin: LatLon
    origin_local_m: tuple[float, float] = Field(examples=[[-120.0, 40.0]])
    cell_m: float = Field(examples=[10.0])
    shape: tuple[int, int] = Field(description="(rows, cols)", examples=[[17, 21]])
    bounds: BoundingBox
    values: list[list[float]]


class BuildingInPhoto(_Answer):
    """A building identified in the photo, with its horizontal pixel extent."""

    building_id: int = Field(examples=[212])
    osm_id: str | None = Field(examples=["way/8042381"])
    name: str | None = Field(examples=["Ateneum"])
    pixel_share: float = Field(description="Share of the photo's building pixels", examples=[0.46])
    x_start: int = Field(description="First pixel column (in the uploaded photo)", examples=[120])
    x_end: int = Field(description="Last pixel column", examples=[597])
    probability: float = Field(description="Mean identity probability over its columns", examples=[0.71])


class ReferenceUsed(_Answer):
    """A retrieved reference and how well it matched."""

    reference_id: int = Field(examples=[17])
    score: float = Field(description="Retrieval (TF-IDF) score", examples=[0.23])
    matches: int = Field(examples=[85])
    inliers: int = Field(description="Geometrically verified matches", examples=[41])


class GridSearch(_Answer):
    """How the likelihood's grid search ran (``geoloc.localize.grid.localize``): its region, grid and priors."""

    region: str = Field(
        description="How the candidate region was chosen: 'identified_buildings' (around the buildings the "
        "identities name), 'position_prior' (around the prior) or 'whole_map'",
        examples=["identified_buildings"],
    )
    buildings: list[int] = Field(description="The map's buildings that defined the region", examples=[[212, 37]])
    positions: int = Field(description="Candidate positions searched", examples=[412])
    yaws: int = Field(description="Headings searched at each position", examples=[120])
    cell_m: float = Field(description="The grid's cell (m)", examples=[10.0])
    identity: bool = Field(description="Whether the likelihood weighed building identities (else geometry only)")
    position_prior: bool = Field(description="Whether a position prior (GPS fix, place) weighed the poses")
    position_prior_shaped: bool | None = Field(
        default=None,
        exclude_if=_absent,
        description="Whether that prior had a place's shape (absent from answers stored before it was recorded)",
    )
    heading_prior: bool = Field(description="Whether a heading prior (compass) weighed the poses")


class AnchorsUsed(_Answer):
    """The anchored pose (PnP on map-anchored reference keypoints): whether it was trusted and why."""

    trusted: bool = Field(description="Whether the anchored pose was kept as the rank-1 answer")
    inliers: int = Field(description="Its PnP inliers (0 when no reference gave a pose)", examples=[46])
    references: list[str] = Field(description="The references its keypoints came from", examples=[["17", "23"]])
    checks: dict[str, int | float] = Field(
        description="The value of each trust check (inliers, height_m, pitch_deg, prior_distance_m, likelihood, "
        "likelihood_best)",
        examples=[{"inliers": 46, "height_m": 1.58, "pitch_deg": 2.1, "likelihood": 0.82, "likelihood_best": 0.9}],
    )


class QuerySearch(GridSearch):
    """How a query was answered: the grid search, the identities' trust, the anchored pose and the configuration.

    ``preset``, ``device`` and ``segmentation`` are the service's: None, and absent from the JSON, in the
    evaluation's answers, in a track's frames and in answers stored before they were recorded (as
    ``identity_trust`` and ``position_prior_shaped`` are in those stored before them).
    """

    identity_trust: float | None = Field(
        default=None,
        exclude_if=_absent,
        description="How far the transferred identities were trusted (0-1)",
        examples=[0.83],
    )
    anchors: AnchorsUsed
    config: dict[str, int | float | bool] = Field(
        description="The query stage's configuration (docs/method.md)", examples=[{"k": 4, "cell_m": 10.0}]
    )
    preset: str | None = Field(default=None, exclude_if=_absent, description="The preset that chose the configuration")
    device: str | None = Field(
        default=None, exclude_if=_absent, description="Where segmentation and ALIKED ran: cpu or cuda"
    )
    segmentation: str | None = Field(
        default=None,
        exclude_if=_absent,
        description="The segmentation network that labelled the photo (its input size)",
    )


class CameraUsed(_Answer):
    """The camera model used: the field of view, where the focal length came from, the uploaded photo's size."""

    hfov_deg: float = Field(description="Horizontal field of view (deg)", examples=[63.4])
    focal_source: str = Field(description="Where the focal length came from", examples=["exif_35mm"])
    width: int = Field(description="The uploaded photo's width (px)", examples=[1024])
    height: int = Field(description="The uploaded photo's height (px)", examples=[768])


class QueryResult(_Answer):
    """The answer to a query photo."""

    locations: list[RankedLocation]
    heatmap: Heatmap
    buildings: list[BuildingInPhoto]
    references: list[ReferenceUsed]
    search: QuerySearch
    camera: CameraUsed
    timings_ms: dict[str, float]


class ReferenceLabels(_Answer):
    """What labelling a reference found, as ``GET /v1/references/{id}`` serves it."""

    estimated: EstimatedPose
    buildings_seen: list[BuildingInPhoto]
    timings: dict[str, float] = Field(description="Milliseconds per step and in total")


class TrackFrameResult(_Answer):
    """One frame of a track: its photo's query and, once located, its pose in the track (the rank-1 pose).

    The pose fields are None until the track is answered (and for a frame the method found no pose for).
    """

    index: int = Field(description="The frame's place in the track, from 0", examples=[0])
    query_id: int = Field(description="The frame's query (`GET /v1/queries/{id}`: its whole answer)", examples=[41])
    original_filename: str | None = Field(default=None, examples=["IMG_0412.jpg"])
    capture_time: str | None = Field(default=None, description="When the photo was taken (ISO 8601, EXIF)")
    lat: float | None = Field(default=None, examples=[60.16952])
    lon: float | None = Field(default=None, examples=[24.94117])
    heading_deg: float | None = Field(default=None, description="Deg clockwise from north", examples=[93.0])
    uncertainty_radius_m: float | None = Field(default=None, description="90 % radius (m)", examples=[4.2])
    source: str | None = Field(
        default=None, description="The pose's source, as a query's location", examples=["anchors"]
    )
    outlier: bool = Field(default=False, description="The track disagrees with this frame's own evidence")
    hfov_deg: float | None = Field(default=None, description="The photo's horizontal field of view (deg)")
    buildings: list[BuildingInPhoto] = Field(default_factory=list, description="The buildings identified in it")


class TrackSearch(_Answer):
    """What the track stage did (``geoloc.localize.track``): the smoother, its edges and the frames it set apart."""

    smoother: str = Field(description="The smoother that placed the frames together", examples=["gtsam"])
    edges: int = Field(description="Relative poses between frames in its graph", examples=[7])
    joined: int = Field(description="Frames with at least one edge", examples=[8])
    outliers: list[int] = Field(description="Frames the track disagrees with (indices)", examples=[[3]])
    anchored_priors: list[int] = Field(description="Frames whose anchored pose was a prior (indices)")
    preset: str | None = Field(
        default=None, exclude_if=_absent, description="The preset that chose the query configuration"
    )


class TrackResult(_Answer):
    """The answer to a track: one :class:`TrackFrameResult` per frame, in order, and how it was searched."""

    frames: list[TrackFrameResult]
    search: TrackSearch = Field(description="What the track stage did")
    timings_ms: dict[str, float]
