"""The suite's figures: what each is, of which items, and how the items of worlds become their tables.

Three populations of items, each from a world's outcomes (:mod:`geoloc.evaluation.suite.outcomes`):
``queries`` (the single queries of walk and scattered worlds, answered with their EXIF GPS and compass),
``references`` (every world's references, labelled and their walks placed) and ``track_frames`` (the frames of the
tracks worlds' query tracks, answered by the track stage, beside the same frames answered alone). A
:class:`Figure` takes per item the values its :class:`~geoloc.evaluation.suite.bootstrap.Statistic` needs (None
leaves the item out: a query without a GPS fix has no "worse than its fix").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from geoloc.evaluation.suite.bootstrap import Statistic

__all__ = ["FIGURES", "POPULATIONS", "Figure", "figure_table", "values_table"]

POPULATIONS = {"queries": "queries", "references": "references", "track_frames": "track frames"}

Row = dict[str, Any]


@dataclass(frozen=True)
class Figure:
    """One figure: its key, population, what it says, its per-item values and the statistic over them."""

    key: str
    population: str
    label: str
    values: Callable[[Row], tuple[float, ...] | None]
    statistic: Statistic = Statistic()
    share: bool = True  # a share (0..1) or a mean of 0/1 differences, else metres or a ratio

    @property
    def name(self) -> str:
        """``population.key``, the figure's name in the reports."""
        return f"{self.population}.{self.key}"


def _median(items: np.ndarray) -> float:
    return float(np.median(items[:, 0]))


def _median_ratio(items: np.ndarray) -> float:
    denominator = float(np.median(items[:, 1]))
    return float(np.median(items[:, 0])) / denominator if denominator > 0 else float("nan")


MEDIAN, MEDIAN_RATIO = Statistic(_median), Statistic(_median_ratio)


def _within(field: str, limit: float) -> Callable[[Row], tuple[float, ...] | None]:
    return lambda row: None if row.get(field) is None else (float(row[field] <= limit),)


def _value(field: str) -> Callable[[Row], tuple[float, ...] | None]:
    return lambda row: None if row.get(field) is None else (float(row[field]),)


def _worse_than_fix(margin_m: float) -> Callable[[Row], tuple[float, ...] | None]:
    def values(row: Row) -> tuple[float, ...] | None:
        if row.get("gps_error_m") is None:
            return None
        return (float(row["error_m"] > row["gps_error_m"] + margin_m),)

    return values


def _radius_and_error(row: Row) -> tuple[float, ...]:
    """An answer's radius (inf where it states none: the outcomes keep only finite numbers) and its error."""
    radius = row.get("radius_m")
    return (float("inf") if radius is None else float(radius), float(row["error_m"]))


def _track_gain(row: Row) -> tuple[float, ...]:
    return (float(row["error_m"] <= 5.0) - float(row["alone_error_m"] <= 5.0),)


def _flag(field: str) -> Callable[[Row], tuple[float, ...]]:
    return lambda row: (float(bool(row[field])),)


FIGURES: tuple[Figure, ...] = (
    Figure("within_1m", "queries", "queries within 1 m", _within("error_m", 1.0)),
    Figure("within_5m", "queries", "queries within 5 m", _within("error_m", 5.0)),
    Figure("within_10m", "queries", "queries within 10 m", _within("error_m", 10.0)),
    Figure("median_m", "queries", "queries' median error (m)", _value("error_m"), MEDIAN, False),
    Figure("heading_within_5deg", "queries", "queries' headings within 5°", _within("heading_error_deg", 5.0)),
    Figure("worse_than_gps_5m", "queries", "answers > 5 m further than their GPS fix", _worse_than_fix(5.0)),
    Figure("radius_holds_truth", "queries", "the radius holds the truth", _flag("inside_radius")),
    Figure(
        "radius_over_error_median",
        "queries",
        "median radius / median error",
        _radius_and_error,
        MEDIAN_RATIO,
        False,
    ),
    Figure("gps_within_5m", "queries", "raw GPS within 5 m", _within("gps_error_m", 5.0)),
    Figure("gps_median_m", "queries", "raw GPS median error (m)", _value("gps_error_m"), MEDIAN, False),
    Figure("within_1m", "references", "references within 1 m", _within("error_m", 1.0)),
    Figure("within_2m", "references", "references within 2 m", _within("error_m", 2.0)),
    Figure("median_m", "references", "references' median error (m)", _value("error_m"), MEDIAN, False),
    Figure("heading_within_2deg", "references", "references' headings within 2°", _within("heading_error_deg", 2.0)),
    Figure("heading_within_5deg", "references", "references' headings within 5°", _within("heading_error_deg", 5.0)),
    Figure("worse_than_fix_1m", "references", "references > 1 m further than their fix", _worse_than_fix(1.0)),
    Figure("sigma1_holds", "references", "truth within the stated 1σ (0.39 if true)", _within("mahalanobis", 1.0)),
    Figure("sigma2_holds", "references", "truth within the stated 2σ (0.86 if true)", _within("mahalanobis", 2.0)),
    Figure("fix_within_2m", "references", "their own GPS fix within 2 m", _within("gps_error_m", 2.0)),
    Figure("fix_median_m", "references", "their own GPS fix, median (m)", _value("gps_error_m"), MEDIAN, False),
    Figure("within_1m", "track_frames", "track frames within 1 m", _within("error_m", 1.0)),
    Figure("within_5m", "track_frames", "track frames within 5 m", _within("error_m", 5.0)),
    Figure("median_m", "track_frames", "track frames' median error (m)", _value("error_m"), MEDIAN, False),
    Figure(
        "heading_within_2deg", "track_frames", "track frames' headings within 2°", _within("heading_error_deg", 2.0)
    ),
    Figure("alone_within_5m", "track_frames", "the same frames alone within 5 m", _within("alone_error_m", 5.0)),
    Figure("gain_within_5m", "track_frames", "within 5 m: track minus alone", _track_gain),
    Figure("radius_holds_truth", "track_frames", "the radius holds the truth", _flag("inside_radius")),
    Figure("gps_within_5m", "track_frames", "raw GPS within 5 m", _within("gps_error_m", 5.0)),
)


def figure_table(figure: Figure, rows: list[Row]) -> np.ndarray:
    """(n, k) float table of the items' values (items the figure leaves out are not in it)."""
    return values_table([v for v in (figure.values(row) for row in rows) if v is not None])


def values_table(values: list[tuple[float, ...]]) -> np.ndarray:
    """(n, k) float table of n items' values (k: their width; 1 when there are none)."""
    width = len(values[0]) if values else 1
    return np.array(values, dtype=float).reshape(len(values), width)
