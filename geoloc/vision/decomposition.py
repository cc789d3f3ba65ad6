"""Piecewise-planar facade decomposition of a photo's building regions.

The paper's "Decomposition of Building Facades".

Pipeline on one image (all pixel coordinates in the input image; columns are pixel columns):

1. Keep the line segments that lie on building pixels (at least ``min_overlap`` of points sampled
   along the segment fall on the building mask dilated by a few pixels, so roof and corner edges
   at the building boundary count) and give each the connected building component it lies on.
2. For every connected building component and every column ``x`` it covers, ``v(x)`` is the
   horizontal vanishing point with the most support from the component's segments whose
   x-extent crosses ``x`` (support = summed segment length, px; interval counting with
   cumulative sums). The support is smoothed along x (box filter) and, unlike the paper's purely
   local vote, biased towards the component's dominant VPs (``component_prior`` times each VP's
   mean support over the component: a few lines of a minor direction such as dormers or roof
   edges then do not cut a facade where its own lines are sparse). Columns without support are
   filled from the nearest supported column of the same component, pieces narrower than
   ``min_piece_frac`` of the width are merged into a neighbour.
3. Cutting lines are where ``v(x)`` changes, where a run of one VP crosses that VP's own column
   (a wall's image lies on one side of its vanishing line, so such a run is two walls, e.g. the
   two sides of a street), or where the component starts/ends. Each piece is
   ``[x_start, x_end)`` with the orientation ``theta_deg`` of its VP (see :mod:`geoloc.core.camera`).
4. Per column, theta_hat is the mean (as doubled angles, modulo 180) of the pieces covering it,
   one per connected component, weighted by the component's pixel count in that column.
   Confidence (``facade_present``) is ``coverage * support`` with ``coverage`` =
   clip(building fraction of the column / ``full_coverage_frac``, 0, 1) (0 below
   ``min_coverage_frac``) and ``support`` = 1 where the column's orientation is backed by a line
   crossing it (its VP has the most direct support there), 0.5 where it was filled or smoothed
   in from neighbouring columns. Building columns of components without any usable lines get no
   hypothesis (0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from geoloc.core.camera import Intrinsics, wrap_orientation_deg
from geoloc.core.labels import BUILDING
from geoloc.vision.lines import sample_points_along, segment_lengths_px
from geoloc.vision.vanishing import VanishingPoints


@dataclass
class FacadePiece:
    """One planar facade hypothesis.

    x_start, x_end: pixel columns ``[x_start, x_end)``; theta_deg: orientation relative to the
    camera (deg, [-90, 90)); vp_index: row in :class:`VanishingPoints`; component: connected
    building component id; support_px: summed length of the component's segments of this VP
    overlapping the piece; confidence: share of the piece's columns where this VP has the most
    direct line support.
    """

    x_start: int
    x_end: int
    theta_deg: float
    vp_index: int
    component: int
    support_px: float
    confidence: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (rounded)."""
        return {
            "x_start": int(self.x_start),
            "x_end": int(self.x_end),
            "theta_deg": round(float(self.theta_deg), 3),
            "vp_index": int(self.vp_index),
            "component": int(self.component),
            "support_px": round(float(self.support_px), 1),
            "confidence": round(float(self.confidence), 3),
        }


@dataclass
class FacadeDecomposition:
    """Facade pieces and per-column results of one image (W = image width).

    pieces: the planar hypotheses, by component then x.
    column_theta_deg: (W,) theta_hat per column (deg), NaN where there is no hypothesis.
    column_present: (W,) confidence in [0, 1] that a facade with that orientation covers the column.
    column_vp: (W,) VP index of the piece of the column's dominant component, -1 if none.
    column_building_frac: (W,) share of the column's pixels that are building (kept components).
    building_segments: (N,) whether each input segment was kept as lying on a building.
    segment_component: (N,) connected component of each segment (0 = none).
    components: (H, W) int32 connected components of the building mask (0 = background;
        components smaller than the minimum area are set to 0).
    """

    pieces: list[FacadePiece]
    column_theta_deg: np.ndarray
    column_present: np.ndarray
    column_vp: np.ndarray
    column_building_frac: np.ndarray
    building_segments: np.ndarray
    segment_component: np.ndarray
    components: np.ndarray

    @property
    def cut_columns(self) -> np.ndarray:
        """Sorted unique cutting-line columns (piece starts and ends)."""
        if not self.pieces:
            return np.zeros(0, dtype=int)
        cuts = [p.x_start for p in self.pieces] + [p.x_end for p in self.pieces]
        return np.unique(np.asarray(cuts, dtype=int))

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form: the pieces and the cutting-line columns."""
        return {"pieces": [p.to_dict() for p in self.pieces], "cut_columns": self.cut_columns.tolist()}


def _row_mode_positive(values: np.ndarray) -> np.ndarray:
    """Per row of an (N, S) non-negative int array, the most frequent positive value (0 if none)."""
    if values.size == 0:
        return np.zeros(len(values), dtype=int)
    pos = values > 0
    eq = (values[:, :, None] == values[:, None, :]) & pos[:, :, None]
    counts = eq.sum(axis=2)
    best = np.argmax(counts, axis=1)
    mode = values[np.arange(len(values)), best]
    return np.where(counts.max(axis=1) > 0, mode, 0)


def _fill_nearest(labels: np.ndarray, valid: np.ndarray, domain: np.ndarray) -> np.ndarray:
    """Fill -1 entries of each row of ``labels`` inside ``domain`` from the nearest ``valid`` entry.

    labels, valid, domain: (R, W). Rows are independent; entries outside ``domain`` become -1.
    """
    r, w = labels.shape
    idx = np.broadcast_to(np.arange(w), (r, w))
    last = np.where(valid, idx, -1)
    last = np.maximum.accumulate(last, axis=1)
    nxt = np.where(valid, idx, w)
    nxt = np.minimum.accumulate(nxt[:, ::-1], axis=1)[:, ::-1]
    d_last = np.where(last >= 0, idx - last, np.iinfo(np.int64).max)
    d_next = np.where(nxt < w, nxt - idx, np.iinfo(np.int64).max)
    src = np.where(d_last <= d_next, last, nxt)
    has = (last >= 0) | (nxt < w)
    rows = np.arange(r)[:, None]
    filled = np.where(has, labels[rows, np.clip(src, 0, w - 1)], -1)
    return np.where(domain, filled, -1)


def _box_filter_last_axis(values: np.ndarray, window: int) -> np.ndarray:
    """Centred moving mean over the last axis (odd ``window``; zeros outside), via cumulative sums."""
    half = window // 2
    pad = [(0, 0)] * (values.ndim - 1) + [(half + 1, half)]
    c: np.ndarray = np.cumsum(np.pad(values, pad), axis=-1)
    return np.asarray((c[..., window:] - c[..., :-window]) / window)


def _runs(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of equal values in a 1-D array: (starts, ends exclusive, values)."""
    if len(values) == 0:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0, values.dtype)
    change = np.flatnonzero(np.diff(values) != 0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(values)]])
    return starts, ends, values[starts]


def _merge_short_runs(label: np.ndarray, min_width: int) -> np.ndarray:
    """Relabel runs (of labels >= 0) shorter than ``min_width`` with the longer adjacent run's label."""
    label = label.copy()
    for _ in range(50):  # a handful of runs; bounded
        starts, ends, vals = _runs(label)
        widths = ends - starts
        short = np.flatnonzero((vals >= 0) & (widths < min_width))
        if len(short) == 0 or np.sum(vals >= 0) <= 1:
            break
        # Take the shortest one first.
        i = short[np.argmin(widths[short])]
        left = i - 1 if i > 0 and vals[i - 1] >= 0 else None
        right = i + 1 if i + 1 < len(vals) and vals[i + 1] >= 0 else None
        if left is None and right is None:
            break
        if left is None:
            pick = right
        elif right is None:
            pick = left
        else:
            pick = left if widths[left] >= widths[right] else right
        label[starts[i] : ends[i]] = vals[pick]
    return label


@dataclass(frozen=True)
class DecompositionOptions:
    """The knobs of :func:`decompose_facades`.

    building_class: the label code of buildings; min_overlap: the share of a segment's samples
    (``n_samples``) on one component that assigns it there. *_frac fields are relative to the image width
    (``mask_dilation_frac``: to the diagonal; ``min_component_frac``: to the image area).
    component_prior: weight of each VP's mean support over the component added to its local support before
    the per-column argmax (0 = the paper's purely local vote). min_coverage_frac, full_coverage_frac: a
    piece's labelled share below which its columns count nothing, and from which they count fully.
    """

    building_class: int = BUILDING
    min_overlap: float = 0.5
    mask_dilation_frac: float = 0.004
    min_component_frac: float = 0.002
    smooth_frac: float = 0.02
    min_piece_frac: float = 0.02
    component_prior: float = 0.25
    min_coverage_frac: float = 0.02
    full_coverage_frac: float = 0.15
    n_samples: int = 16


def decompose_facades(
    labels: np.ndarray,
    segments: np.ndarray,
    vanishing_points: VanishingPoints,
    intrinsics: Intrinsics,
    options: DecompositionOptions = DecompositionOptions(),
) -> FacadeDecomposition:
    """Decompose the building regions of an image into planar facade pieces (module docstring).

    labels: (H, W) class codes (:mod:`geoloc.core.labels`), same size as the image of the segments.
    segments: (N, 4) ``x1, y1, x2, y2`` px; vanishing_points: their VPs and assignment;
    intrinsics: of the image (to place the VPs); options: :class:`DecompositionOptions`.
    Returns :class:`FacadeDecomposition`.
    """
    building_class, min_overlap, n_samples = options.building_class, options.min_overlap, options.n_samples
    mask_dilation_frac, min_component_frac = options.mask_dilation_frac, options.min_component_frac
    smooth_frac, min_piece_frac, component_prior = options.smooth_frac, options.min_piece_frac, options.component_prior
    min_coverage_frac, full_coverage_frac = options.min_coverage_frac, options.full_coverage_frac
    import cv2

    lab = np.asarray(labels)
    h, w = lab.shape
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    n = len(seg)
    mask = (lab == building_class).astype(np.uint8)

    n_comp, comp = cv2.connectedComponents(mask, connectivity=8)
    comp = comp.astype(np.int32)
    areas = np.bincount(comp.ravel(), minlength=n_comp)
    small = areas < max(1.0, min_component_frac * h * w)
    small[0] = False
    if small.any():
        comp[small[comp]] = 0
    # Renumber kept components 1..C.
    kept = np.flatnonzero(~small)
    kept = kept[kept > 0]
    renum = np.zeros(n_comp, dtype=np.int32)
    renum[kept] = np.arange(1, len(kept) + 1)
    comp = renum[comp]
    n_c = len(kept)

    # Per column pixel counts of each component: (C + 1, W).
    col_index = np.broadcast_to(np.arange(w, dtype=np.int64), (h, w))
    counts = np.bincount((comp.astype(np.int64) * w + col_index).ravel(), minlength=(n_c + 1) * w)
    counts = counts.reshape(n_c + 1, w)
    counts[0] = 0
    building_frac = counts.sum(axis=0) / float(h)

    # Segments on buildings, with their component (dilated so boundary edges count).
    radius = max(1, round(mask_dilation_frac * float(np.hypot(h, w))))
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * radius + 1, 2 * radius + 1))
    comp_dil = cv2.dilate(comp.astype(np.float32), kernel).astype(np.int32)
    if n:
        xi, yi = sample_points_along(seg, n_samples, w, h)
        samples = comp_dil[yi, xi]
        overlap = np.mean(samples > 0, axis=1)
        seg_comp = np.where(overlap >= min_overlap, _row_mode_positive(samples), 0)
    else:
        seg_comp = np.zeros(0, dtype=int)
    on_building = seg_comp > 0
    n_vp = len(vanishing_points.directions_cam)
    assign = np.asarray(vanishing_points.assignment, dtype=int)
    useful = on_building & (assign >= 1)

    column_theta = np.full(w, np.nan)
    column_present = np.zeros(w)
    column_vp = np.full(w, -1)
    pieces: list[FacadePiece] = []
    if n_c == 0 or n_vp <= 1:
        return FacadeDecomposition(
            pieces, column_theta, column_present, column_vp, building_frac, on_building, seg_comp, comp
        )

    # Support per (component, VP) and column by interval counting: (C + 1, n_vp, W).
    lengths = segment_lengths_px(seg)
    x_lo = np.clip(np.floor(np.minimum(seg[:, 0], seg[:, 2])).astype(int), 0, w - 1)
    x_hi = np.clip(np.ceil(np.maximum(seg[:, 0], seg[:, 2])).astype(int), 0, w - 1)
    diff = np.zeros((n_c + 1, n_vp, w + 1))
    u = np.flatnonzero(useful)
    np.add.at(diff, (seg_comp[u], assign[u], x_lo[u]), lengths[u])
    np.add.at(diff, (seg_comp[u], assign[u], x_hi[u] + 1), -lengths[u])
    support = np.cumsum(diff, axis=2)[:, :, :w]
    support[:, 0, :] = 0.0  # the vertical VP does not give a facade orientation
    present = counts > 0  # (C + 1, W)
    support *= present[:, None, :]
    win = max(3, round(smooth_frac * w) | 1)
    smoothed = _box_filter_last_axis(support, win) * present[:, None, :]

    best_direct = np.argmax(support, axis=1)  # (C + 1, W)
    has_direct = support.max(axis=1) > 0
    # Component prior: each VP's mean support over the component's columns, so that a few local
    # lines of a minor direction (dormers, roof edges) do not outvote the component's main facade
    # where its own lines are sparse.
    n_cols = np.maximum(present.sum(axis=1), 1)[:, None]
    prior = component_prior * support.sum(axis=2) / n_cols  # (C + 1, n_vp)
    scored = smoothed + prior[:, :, None]
    label = np.where(smoothed.max(axis=1) > 0, np.argmax(scored, axis=1), -1)
    label = np.where(present, label, -1)
    label = _fill_nearest(label, label >= 0, present)
    label[0] = -1
    min_width = max(2, round(min_piece_frac * w))
    # A vertical wall's image lies on one side of its horizontal VP's column (the wall's vanishing
    # line), so a run of one VP that spans that column is two walls (e.g. both sides of a street):
    # encode the side in the label so that runs split there.
    x_vp = vanishing_points.image_points(intrinsics)[:, 0] if n_vp else np.zeros(0)
    side = (np.arange(w)[None, :] >= x_vp[np.maximum(label, 0)]).astype(int)
    label = np.where(label >= 0, 2 * label + side, -1)

    # Pieces per component (a connected component covers an interval of columns).
    direct_ok = np.zeros((n_c + 1, w), dtype=bool)
    for c in range(1, n_c + 1):
        if not (label[c] >= 0).any():
            continue
        merged = np.where(present[c], _merge_short_runs(label[c], min_width), -1)
        starts, ends, vals = _runs(merged)
        label[c] = np.where(merged >= 0, merged // 2, -1)
        vals = np.where(vals >= 0, vals // 2, -1)
        direct_ok[c] = has_direct[c] & (best_direct[c] == label[c])
        seg_c = u[seg_comp[u] == c]
        for s0, e0, v in zip(starts, ends, vals, strict=True):
            if v < 0:
                continue
            on_piece = seg_c[(assign[seg_c] == v) & (x_hi[seg_c] >= s0) & (x_lo[seg_c] < e0)]
            pieces.append(
                FacadePiece(
                    x_start=int(s0),
                    x_end=int(e0),
                    theta_deg=float(vanishing_points.theta_deg[v]),
                    vp_index=int(v),
                    component=c,
                    support_px=float(lengths[on_piece].sum()),
                    confidence=float(np.mean(direct_ok[c, s0:e0])),
                )
            )

    # Per column: doubled-angle mean over components, weighted by their pixel counts.
    theta_vp = np.nan_to_num(np.asarray(vanishing_points.theta_deg, dtype=float))
    has_label = label >= 0
    wts = np.where(has_label, counts, 0).astype(float)
    doubled = np.radians(2.0 * theta_vp[np.maximum(label, 0)])
    cs = (wts * np.cos(doubled)).sum(axis=0)
    sn = (wts * np.sin(doubled)).sum(axis=0)
    labelled_px = wts.sum(axis=0)
    any_label = labelled_px > 0
    column_theta = np.where(any_label, wrap_orientation_deg(np.degrees(np.arctan2(sn, cs)) / 2.0), np.nan)
    dominant = np.argmax(wts, axis=0)
    column_vp = np.where(any_label, label[dominant, np.arange(w)], -1)
    labelled_frac = labelled_px / float(h)
    coverage = np.clip(labelled_frac / full_coverage_frac, 0.0, 1.0)
    coverage[labelled_frac < min_coverage_frac] = 0.0
    direct_share = (np.where(direct_ok, counts, 0).sum(axis=0)) / np.maximum(labelled_px, 1.0)
    support_term = 0.5 + 0.5 * (direct_share >= 0.5)
    column_present = np.where(any_label, coverage * support_term, 0.0)
    column_theta = np.where(column_present > 0, column_theta, np.nan)
    return FacadeDecomposition(
        pieces, column_theta, column_present, column_vp, building_frac, on_building, seg_comp, comp
    )
