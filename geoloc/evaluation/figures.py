"""The figures of ``geoloc eval world``, written beside its JSON (Pillow; no plotting library is installed).

From the result dict of :func:`geoloc.evaluation.world.evaluate_world`, one line per run:

- ``<stem>.error_cdf.png``: the share of queries whose rank-1 position error (m) is at most x, for x from 0
  to :data:`CDF_MAX_M` (errors beyond it keep their curve below 1 at the right edge);
- ``<stem>.top_n.png``: the paper's Fig. 7, the mean error (m) of the best of the top N answers for N = 1..10,
  with its 95 % confidence interval as a bar at each N.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

CDF_MAX_M = 50.0
WIDTH, HEIGHT = 800, 520
LEFT, RIGHT, TOP, BOTTOM = 70, 210, 40, 60
"""The plot area's margins (px); the legend sits in the right one."""
PALETTE = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75))
"""One colour per run, in the result's order (cycled past six runs)."""
GRID = (225, 225, 225)
INK = (30, 30, 30)


@dataclass(frozen=True)
class Series:
    """One run's line: x and y (data units), optional y intervals ``(lo, hi)`` per point."""

    name: str
    x: np.ndarray
    y: np.ndarray
    interval: np.ndarray | None = None


@dataclass(frozen=True)
class Axes:
    """Data ranges -> pixels of the plot area."""

    x_max: float
    y_max: float
    x_min: float = 0.0
    y_min: float = 0.0

    def px(self, x: np.ndarray, y: np.ndarray) -> list[tuple[float, float]]:
        """Pixel points of data points (y up)."""
        w, h = WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM
        cols = LEFT + (np.asarray(x, float) - self.x_min) / (self.x_max - self.x_min) * w
        rows = (
            TOP
            + h
            - (np.clip(np.asarray(y, float), self.y_min, self.y_max) - self.y_min) / (self.y_max - self.y_min) * h
        )
        return list(zip(cols.tolist(), rows.tolist(), strict=True))


def _ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    step = (hi - lo) / count
    magnitude = 10.0 ** np.floor(np.log10(step))
    step = min((m * magnitude for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * magnitude >= step), default=step)
    return [float(v) for v in np.arange(lo, hi + step / 2, step)]


def line_chart(
    series: list[Series], axes: Axes, title: str, x_label: str, y_label: str, x_ticks: list[float] | None = None
) -> Image.Image:
    """A chart (RGB image) of ``series`` on ``axes``: grid, ticks (``x_ticks``, else round steps), title, legend."""
    image = Image.new("RGB", (WIDTH, HEIGHT), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    font, small = ImageFont.load_default(size=15), ImageFont.load_default(size=12)
    x_right, y_bottom = WIDTH - RIGHT, HEIGHT - BOTTOM
    for value in x_ticks if x_ticks is not None else _ticks(axes.x_min, axes.x_max):
        ((col, _),) = axes.px(np.array([value]), np.array([axes.y_min]))
        draw.line((col, TOP, col, y_bottom), fill=GRID)
        draw.text((col, y_bottom + 6), f"{value:g}", fill=INK, font=small, anchor="mt")
    for value in _ticks(axes.y_min, axes.y_max):
        ((_, row),) = axes.px(np.array([axes.x_min]), np.array([value]))
        draw.line((LEFT, row, x_right, row), fill=GRID)
        draw.text((LEFT - 6, row), f"{value:g}", fill=INK, font=small, anchor="rm")
    draw.rectangle((LEFT, TOP, x_right, y_bottom), outline=INK)
    for i, line in enumerate(series):
        color = PALETTE[i % len(PALETTE)]
        if line.interval is not None:
            for (col, lo_row), (_, hi_row) in zip(
                axes.px(line.x, line.interval[:, 0]), axes.px(line.x, line.interval[:, 1]), strict=True
            ):
                draw.line((col, lo_row, col, hi_row), fill=color, width=1)
                draw.line((col - 4, lo_row, col + 4, lo_row), fill=color)
                draw.line((col - 4, hi_row, col + 4, hi_row), fill=color)
        points = axes.px(line.x, line.y)
        if len(points) > 1:
            draw.line(points, fill=color, width=3, joint="curve")
        elif points:
            col, row = points[0]
            draw.ellipse((col - 3, row - 3, col + 3, row + 3), fill=color)
        legend_y = TOP + 10 + 22 * i
        draw.line((x_right + 14, legend_y, x_right + 40, legend_y), fill=color, width=3)
        draw.text((x_right + 46, legend_y), line.name, fill=INK, font=small, anchor="lm")
    draw.text((WIDTH / 2, 12), title, fill=INK, font=font, anchor="mt")
    draw.text(((LEFT + x_right) / 2, HEIGHT - 22), x_label, fill=INK, font=small, anchor="mt")
    label = Image.new("RGB", (y_bottom - TOP, 18), (255, 255, 255))
    ImageDraw.Draw(label).text((label.width / 2, 2), y_label, fill=INK, font=small, anchor="mt")
    image.paste(label.rotate(90, expand=True), (6, TOP))
    return image


def error_cdf_series(result: dict[str, Any]) -> list[Series]:
    """Per run: the share of queries whose rank-1 error (m) is at most x, a step line from 0 to :data:`CDF_MAX_M`."""
    out = []
    for name, run in result.get("runs", {}).items():
        errors = np.sort([float(row["error_m"]) for row in run.get("per_query", [])])
        if not len(errors):
            continue
        inside = errors[errors <= CDF_MAX_M]
        share = np.arange(1, len(inside) + 1) / len(errors)
        before = np.concatenate([[0.0], share[:-1]])
        x = np.concatenate([[0.0], np.repeat(inside, 2), [CDF_MAX_M]])
        y = np.concatenate([[0.0], np.column_stack([before, share]).ravel(), [share[-1] if len(share) else 0.0]])
        out.append(Series(name, x, y))
    return out


def top_n_series(result: dict[str, Any]) -> list[Series]:
    """Per run: N and the mean error (m) of the best of the top N, with its confidence interval."""
    out = []
    for name, run in result.get("runs", {}).items():
        table = run.get("top_n_error_m", {})
        ns = sorted(int(n) for n, v in table.items() if v.get("mean") is not None)
        if not ns:
            continue
        mean = np.array([table[str(n)]["mean"] for n in ns], dtype=float)
        ci = np.array([table[str(n)].get("ci95", [table[str(n)]["mean"]] * 2) for n in ns], dtype=float)
        out.append(Series(name, np.array(ns, dtype=float), mean, ci))
    return out


def write_world_figures(result: dict[str, Any], json_path: Path) -> list[Path]:
    """Write the error CDF and the top-N figure beside ``json_path``; returns the paths written (none if no run)."""
    written = []
    cdf = error_cdf_series(result)
    if cdf:
        axes = Axes(x_max=CDF_MAX_M, y_max=1.0)
        title = f"Rank-1 position error, {result.get('queries', '?')} queries"
        path = json_path.with_suffix(".error_cdf.png")
        line_chart(cdf, axes, title, "position error (m)", "share of queries").save(path)
        written.append(path)
    top = top_n_series(result)
    if top:
        peak = max(float(np.max(s.interval if s.interval is not None else s.y)) for s in top)
        axes = Axes(x_max=max(float(s.x.max()) for s in top) + 0.5, y_max=max(peak * 1.1, 1.0), x_min=0.5)
        path = json_path.with_suffix(".top_n.png")
        ticks = sorted({float(n) for s in top for n in s.x})
        line_chart(top, axes, "Best of the top N answers (Fig. 7)", "N", "mean error (m)", ticks).save(path)
        written.append(path)
    return written
