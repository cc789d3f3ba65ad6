"""The suite's reports: a markdown table per split, the error-CDF and calibration plots, the README's table.

From a split's report (:func:`geoloc.evaluation.suite.run.run_suite`) and its worlds' outcomes:
:func:`markdown` (every figure as ``value [low, high]`` per group: pooled, per capture kind, per urban form; the
dev split also per world; with a baseline the paired differences), :func:`write_plots` (``SPLIT.error_cdf.png``:
queries against their raw GPS, references against their own fixes, track frames against the same frames alone;
``SPLIT.calibration.png``: the share of truths inside k times the stated size, references' k sigma beside what a
true 2D Gaussian gives, and the answers' radius), :func:`readme_table` (the README's accuracy table: the test
split's pooled figures of both capture kinds with the raw GPS beside them) and :func:`results_accuracy`
(``docs/results.md``'s accuracy part: its command and method, the pooled figures and each capture kind's).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from geoloc.evaluation.figures import Axes, Series, line_chart
from geoloc.evaluation.suite.figures import FIGURES
from geoloc.evaluation.suite.worlds import CAPTURES

__all__ = ["README_COMMAND", "markdown", "readme_table", "results_accuracy", "write_plots"]

README_COMMAND = "geoloc eval suite --split test --out docs/accuracy"
"""The command that makes the README's accuracy table (``docs/accuracy/test.json`` is its source)."""


def _cell(interval: dict[str, Any] | None, share: bool, signed: bool = False) -> str:
    if not interval or interval.get("value") is None:
        return "–"
    digits = 2 if share else 1
    sign = "+" if signed else ""

    def fmt(v: float | None) -> str:
        return "?" if v is None else f"{v:{sign}.{digits}f}"

    return f"{fmt(interval['value'])} [{fmt(interval['low'])}, {fmt(interval['high'])}]"


def _table(groups: dict[str, dict[str, Any]], columns: list[str], signed: bool = False) -> list[str]:
    header = ["figure", *[c.replace("capture:", "").replace("form:", "").replace("world:", "") for c in columns]]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for figure in FIGURES:
        cells = [_cell(groups.get(c, {}).get(figure.name), figure.share, signed) for c in columns]
        if all(c == "–" for c in cells):
            continue
        lines.append(f"| {figure.label} | " + " | ".join(cells) + " |")
    return lines


def markdown(report: dict[str, Any]) -> str:
    """The split's figures as markdown tables (module docstring)."""
    figures: dict[str, dict[str, Any]] = report["figures"]
    split = report["split"]
    worlds = report["worlds"]
    lines = [
        f"# Accuracy suite: the {split} split",
        "",
        f"{len(worlds)} worlds (suite version {report['suite_version']}), method `{report.get('commit')}`; each "
        "figure with its 95 % interval from a cluster bootstrap over the worlds "
        "(`geoloc/evaluation/suite/bootstrap.py`). Queries carry their EXIF GPS and compass; references are "
        "labelled and their walks placed as the workers do.",
        "",
        "## Pooled and per capture kind",
        "",
    ]
    captures = [f"capture:{c}" for c in CAPTURES if f"capture:{c}" in figures]
    lines += _table(figures, ["pooled", *captures])
    lines += ["", "## Per urban form", ""]
    lines += _table(figures, [g for g in figures if g.startswith("form:")])
    worse = report.get("worlds_median_worse_than_gps", [])
    lines += ["", f"Worlds whose queries' median error exceeds their raw GPS's: {len(worse)}"
              + (f" ({', '.join(worse)})" if worse and split == "dev" else "") + "."]  # fmt: skip
    if split == "dev":
        lines += [
            "",
            "## Per world",
            "",
            "| world | form | capture | key | evaluation (s) |",
            "| --- | --- | --- | --- | --- |",
        ]
        lines += [
            f"| {w['name']} | {w['form']} | {w['capture']} | {w['key']} | {w.get('evaluation_s')} |" for w in worlds
        ]
        lines += [""]
        lines += _table(figures, [g for g in figures if g.startswith("world:")])
    if "paired" in report:
        base = report["baseline"]
        lines += ["", f"## Paired differences: this method minus `{base['ref']}` ({base['commit'][:10]})", ""]
        paired = report["paired"]
        groups = [f"capture:{c}" for c in CAPTURES if f"capture:{c}" in paired]
        groups += [g for g in paired if g.startswith("form:")]
        lines += _table(paired, ["pooled", *groups], signed=True)
    lines += ["", f"Seconds: {report['seconds']}.", ""]
    return "\n".join(lines)


def readme_table(report: dict[str, Any]) -> str:
    """The README's accuracy table from the test split's report: both capture kinds, the raw GPS beside them."""
    figures = report["figures"]
    rows = [
        ("queries within 5 m", "queries.within_5m", "queries.gps_within_5m", True),
        ("queries within 10 m", "queries.within_10m", None, True),
        ("queries' median error (m)", "queries.median_m", "queries.gps_median_m", False),
        ("queries' headings within 5°", "queries.heading_within_5deg", None, True),
        ("answers > 5 m further than their GPS fix", "queries.worse_than_gps_5m", None, True),
        ("the answer's radius holds the truth", "queries.radius_holds_truth", None, True),
        ("references within 2 m", "references.within_2m", "references.fix_within_2m", True),
        ("references' median error (m)", "references.median_m", "references.fix_median_m", False),
        ("references' headings within 2°", "references.heading_within_2deg", None, True),
        ("references > 1 m further than their fix", "references.worse_than_fix_1m", None, True),
        ("a reference's stated 2σ holds its truth", "references.sigma2_holds", None, True),
        ("track frames within 5 m (alone: the same frames one by one)", "track_frames.within_5m",
         "track_frames.alone_within_5m", True),
    ]  # fmt: skip
    head = (
        "| figure (test split, pooled, 95 % interval) | walk capture | scattered capture | raw GPS / own fix / alone |"
    )
    lines = [head, "| --- | --- | --- | --- |"]
    for label, key, beside, share in rows:
        if key.startswith("track_frames"):
            walk, scattered = figures.get("capture:tracks", {}).get(key), None
            other = figures.get("capture:tracks", {}).get(beside) if beside else None
        else:
            walk = figures.get("capture:walk", {}).get(key)
            scattered = figures.get("capture:scattered", {}).get(key)
            other = figures.get("capture:walk", {}).get(beside) if beside else None
        lines.append(f"| {label} | {_cell(walk, share)} | {_cell(scattered, share)} | {_cell(other, share)} |")
    return "\n".join(lines)


def results_accuracy(report: dict[str, Any]) -> str:
    """``docs/results.md``'s accuracy part: the command and method, then the pooled and per-capture figures."""
    figures: dict[str, dict[str, Any]] = report["figures"]
    captures = [f"capture:{c}" for c in CAPTURES if f"capture:{c}" in figures]
    lines = [
        f"Command: `{README_COMMAND}` (the method of `{report.get('commit')}`; {len(report['worlds'])} worlds of the "
        f"{report['split']} split, suite version {report['suite_version']}; each figure with its 95 % interval from a "
        "cluster bootstrap over the worlds).",
        "",
        *_table(figures, ["pooled", *captures]),
    ]
    return "\n".join(lines)


CDF_MAX_M = 40.0


def _cdf(name: str, errors: list[float]) -> Series:
    values = np.sort(np.asarray(errors, dtype=float))
    x = np.linspace(0.0, CDF_MAX_M, 161)
    return Series(name, x, np.searchsorted(values, x, side="right") / max(len(values), 1))


def write_plots(report: dict[str, Any], outcomes: list[dict[str, Any]], stem: Path) -> list[Path]:
    """``STEM.error_cdf.png`` and ``STEM.calibration.png`` from the split's worlds' outcomes; the paths written."""
    queries = [row for o in outcomes for row in o.get("queries", [])]
    references = [row for o in outcomes for row in o.get("references", [])]
    frames = [row for o in outcomes for row in o.get("track_frames", [])]
    series = [
        _cdf("queries", [r["error_m"] for r in queries]),
        _cdf("queries' raw GPS", [r["gps_error_m"] for r in queries if r["gps_error_m"] is not None]),
        _cdf("references", [r["error_m"] for r in references]),
        _cdf("references' own fix", [r["gps_error_m"] for r in references if r["gps_error_m"] is not None]),
        _cdf("track frames", [r["error_m"] for r in frames]),
        _cdf("the frames alone", [r["alone_error_m"] for r in frames]),
    ]
    series = [s for s in series if np.isfinite(s.y).all()]
    split = report["split"]
    written = []
    path = stem.with_suffix(".error_cdf.png")
    line_chart(series, Axes(x_max=CDF_MAX_M, y_max=1.0), f"Position error, {split} split (pooled)",
               "position error (m)", "share within").save(path)  # fmt: skip
    written.append(path)
    k = np.linspace(0.0, 3.0, 61)
    sigmas = np.array([r["mahalanobis"] for r in references], dtype=float)
    ratio = np.array([r["error_m"] / r["radius_m"] for r in queries if r["radius_m"]], dtype=float)
    calibration = [
        Series("references within k sigma", k, np.array([np.mean(sigmas <= v) for v in k]) if len(sigmas) else k * 0),
        Series("a true 2D Gaussian", k, 1.0 - np.exp(-(k**2) / 2.0)),
        Series("answers within k radius", k, np.array([np.mean(ratio <= v) for v in k]) if len(ratio) else k * 0),
    ]
    path = stem.with_suffix(".calibration.png")
    x_label = "k (sigmas of a reference's stated covariance, or radii of an answer)"
    title = f"Calibration, {split} split (pooled)"
    line_chart(calibration, Axes(x_max=3.0, y_max=1.0), title, x_label, "share of truths inside").save(path)
    written.append(path)
    return written
