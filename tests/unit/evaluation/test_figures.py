"""``geoloc eval world``'s figures (error CDFs per run, best of top N) on a hand-made result."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from geoloc.evaluation import figures


def _run(errors: list[float]) -> dict[str, Any]:
    best = np.minimum.accumulate(np.array([errors] * 10).T * np.linspace(1.0, 0.4, 10), axis=1)
    return {
        "per_query": [{"error_m": e} for e in errors],
        "top_n_error_m": {
            str(n): {
                "mean": float(best[:, n - 1].mean()),
                "ci95": [float(best[:, n - 1].mean()) - 1, float(best[:, n - 1].mean()) + 1],
            }
            for n in range(1, 11)
        },
    }


RESULT = {"queries": 4, "runs": {"ours/gps": _run([0.5, 0.7, 0.9, 0.8]), "ours/none": _run([20.0, 30.0, 40.0, 80.0])}}


def _pixels_of(image: np.ndarray, color: tuple[int, int, int]) -> np.ndarray:
    return np.argwhere((image == color).all(axis=2))


def test_the_eval_writes_its_figures_beside_the_json(tmp_path: Path) -> None:
    written = figures.write_world_figures(RESULT, tmp_path / "eval.json")
    assert [p.name for p in written] == ["eval.error_cdf.png", "eval.top_n.png"]
    for path in written:
        image = np.asarray(Image.open(path).convert("RGB"))
        assert image.shape == (figures.HEIGHT, figures.WIDTH, 3)
        for color in figures.PALETTE[:2]:  # both runs drawn (lines and legend)
            assert len(_pixels_of(image, color)) > 50


def test_the_cdf_of_small_errors_rises_at_once_and_large_ones_stay_low(tmp_path: Path) -> None:
    (path, _) = figures.write_world_figures(RESULT, tmp_path / "eval.json")
    image = np.asarray(Image.open(path).convert("RGB"))
    axes = figures.Axes(x_max=figures.CDF_MAX_M, y_max=1.0)
    (col_top, row_top), (col_low, row_low) = axes.px(np.array([10.0, 10.0]), np.array([1.0, 0.0]))
    column = image[:, round(col_top)]
    good = _pixels_of(column[:, None, :], figures.PALETTE[0])[:, 0]  # ours/gps: all under 1 m, at 1 by 10 m
    assert len(good) and abs(good.min() - row_top) <= 3
    bad = _pixels_of(column[:, None, :], figures.PALETTE[1])[:, 0]  # ours/none: nothing under 10 m
    assert len(bad) and abs(bad.max() - row_low) <= 3
    right = image[:, round(axes.px(np.array([figures.CDF_MAX_M - 1]), np.array([0.0]))[0][0])]
    rows = _pixels_of(right[:, None, :], figures.PALETTE[1])[:, 0]  # 3 of 4 within 50 m: at 0.75 there
    ((_, row_75),) = axes.px(np.array([0.0]), np.array([0.75]))
    assert len(rows) and abs(rows.mean() - row_75) <= 3


def test_the_top_n_figure_follows_the_means(tmp_path: Path) -> None:
    series = figures.top_n_series(RESULT)
    assert [s.name for s in series] == ["ours/gps", "ours/none"]
    assert np.all(np.diff(series[1].y) <= 0) and series[1].interval is not None
    assert series[1].interval[0].tolist() == pytest.approx([series[1].y[0] - 1, series[1].y[0] + 1])


def test_a_result_without_runs_writes_nothing(tmp_path: Path) -> None:
    assert figures.write_world_figures({"runs": {}}, tmp_path / "eval.json") == []
