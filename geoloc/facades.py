"""Piecewise-planar facade decomposition and the per-column image model (paper: "Decomposition of
Building Facades").

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
   ``[x_start, x_end)`` with the orientation ``theta_deg`` of its VP (see :mod:`geoloc.camera`).
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

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geoloc.camera import Intrinsics, wrap_orientation_deg
from geoloc.image_model import DEFAULT_BIN_DEG, ImageModel, column_bins, image_model_from_columns
from geoloc.labels import BUILDING, CAR, SKY, TREE
from geoloc.lines import detect_line_segments, segment_lengths_px
from geoloc.vanishing import VanishingPoints, estimate_vanishing_points

CLUTTER_CLASSES: tuple[int, ...] = (TREE, CAR, SKY)
"""Segments lying mostly on these classes are left out of vanishing point estimation: foliage
gives random short lines, cars strong lines of their own orientation."""


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

    def to_dict(self) -> dict:
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

    def to_dict(self) -> dict:
        return {"pieces": [p.to_dict() for p in self.pieces], "cut_columns": self.cut_columns.tolist()}


@dataclass
class ImageAnalysis:
    """Everything the image side of the likelihood derives from one photo."""

    intrinsics: Intrinsics
    segments: np.ndarray
    vanishing_points: VanishingPoints
    decomposition: FacadeDecomposition
    image_model: ImageModel
    timings_s: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-friendly summary (no per-pixel arrays)."""
        intr = self.intrinsics
        m = self.image_model
        return {
            "image": {"width": intr.width, "height": intr.height},
            "intrinsics": {
                "focal_px": round(intr.focal_px, 2),
                "hfov_deg": round(intr.hfov_deg, 3),
                "source": intr.source,
            },
            "n_segments": len(self.segments),
            "n_building_segments": int(self.decomposition.building_segments.sum()),
            "vanishing_points": self.vanishing_points.to_dict(intr),
            "facades": self.decomposition.to_dict(),
            "image_model": {
                "bin_deg": m.bin_deg,
                "n_bins": m.n_bins,
                "share_bins_with_facade": round(float(np.mean(m.facade_present > 0)), 4),
                "mean_confidence": round(float(np.mean(m.facade_present)), 4),
            },
            "timings_s": {k: round(v, 4) for k, v in self.timings_s.items()},
        }


# ----------------------------------------------------------------------------------------------
# Helpers


def _sample_points(segments: np.ndarray, n_samples: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, S) integer x and y of points sampled evenly along each segment (clipped to the image)."""
    t = (np.arange(n_samples) + 0.5) / n_samples
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    x = s[:, 0:1] + t[None, :] * (s[:, 2:3] - s[:, 0:1])
    y = s[:, 1:2] + t[None, :] * (s[:, 3:4] - s[:, 1:2])
    xi = np.clip(np.round(x).astype(int), 0, width - 1)
    yi = np.clip(np.round(y).astype(int), 0, height - 1)
    return xi, yi


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
    c = np.cumsum(np.pad(values, pad), axis=-1)
    return (c[..., window:] - c[..., :-window]) / window


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


# ----------------------------------------------------------------------------------------------
# Decomposition


def decompose_facades(
    labels: np.ndarray,
    segments: np.ndarray,
    vanishing_points: VanishingPoints,
    intrinsics: Intrinsics,
    building_class: int = BUILDING,
    min_overlap: float = 0.5,
    mask_dilation_frac: float = 0.004,
    min_component_frac: float = 0.002,
    smooth_frac: float = 0.02,
    min_piece_frac: float = 0.02,
    component_prior: float = 0.25,
    min_coverage_frac: float = 0.02,
    full_coverage_frac: float = 0.15,
    n_samples: int = 16,
) -> FacadeDecomposition:
    """Decompose the building regions of an image into planar facade pieces (module docstring).

    labels: (H, W) class codes (:mod:`geoloc.labels`), same size as the image of the segments.
    segments: (N, 4) ``x1, y1, x2, y2`` px; vanishing_points: their VPs and assignment;
    intrinsics: of the image (to place the VPs).
    *_frac parameters are relative to the image width (dilation: to the diagonal; component area:
    to the image area). component_prior: weight of each VP's mean support over the component
    added to its local support before the per-column argmax (0 = the paper's purely local vote).
    Returns :class:`FacadeDecomposition`.
    """
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
        xi, yi = _sample_points(seg, n_samples, w, h)
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


# ----------------------------------------------------------------------------------------------
# Entry points


def segment_class_fraction(
    labels: np.ndarray, segments: np.ndarray, classes: tuple[int, ...], n_samples: int = 16
) -> np.ndarray:
    """(N,) share of points sampled along each segment whose label is one of ``classes``."""
    lab = np.asarray(labels)
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    if len(seg) == 0:
        return np.zeros(0)
    xi, yi = _sample_points(seg, n_samples, lab.shape[1], lab.shape[0])
    return np.isin(lab[yi, xi], classes).mean(axis=1)


def estimate_scene_vanishing_points(
    labels: np.ndarray, segments: np.ndarray, intrinsics: Intrinsics, max_clutter_frac: float = 0.5
) -> VanishingPoints:
    """VPs from the segments that are not mostly on clutter (:data:`CLUTTER_CLASSES`).

    The returned ``assignment`` covers all input segments (-1 for the ones left out).
    """
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    use = segment_class_fraction(labels, seg, CLUTTER_CLASSES) <= max_clutter_frac
    vps = estimate_vanishing_points(seg[use], intrinsics)
    assignment = np.full(len(seg), -1)
    assignment[use] = vps.assignment
    vps.assignment = assignment
    return vps


def _as_segments(segments_or_image: np.ndarray) -> tuple[np.ndarray, bool]:
    """Return (segments, was_image): an (N, 4) float array is taken as segments, anything else as an image."""
    arr = np.asarray(segments_or_image)
    is_segments = arr.ndim == 2 and arr.shape[1] == 4 and arr.dtype.kind == "f"
    if is_segments:
        return arr.astype(float), False
    return detect_line_segments(arr), True


def facade_image_model(
    labels: np.ndarray,
    segments_or_image: np.ndarray,
    intrinsics: Intrinsics,
    vanishing_points: VanishingPoints | None = None,
    bin_deg: float = DEFAULT_BIN_DEG,
    **decompose_kwargs: Any,
) -> tuple[ImageModel, FacadeDecomposition]:
    """Per-column facade image model of an image.

    labels: (H, W) class codes; segments_or_image: (N, 4) float segments (px) or the image itself
    ((H, W) / (H, W, 3), segments are then detected); intrinsics: of that image (width/height must
    match ``labels``); vanishing_points: reuse already estimated VPs for these segments (default:
    :func:`estimate_scene_vanishing_points`, i.e. without segments on trees, cars and sky).
    Returns the binned :class:`ImageModel` (``bin_deg`` wide angular bins) and the decomposition.
    """
    lab = np.asarray(labels)
    if lab.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f"labels {lab.shape} do not match the intrinsics ({intrinsics.height}, {intrinsics.width})")
    segments, _ = _as_segments(segments_or_image)
    vps = vanishing_points
    if vps is None:
        vps = estimate_scene_vanishing_points(lab, segments, intrinsics)
    deco = decompose_facades(lab, segments, vps, intrinsics, **decompose_kwargs)
    model = image_model_from_columns(
        intrinsics, deco.column_present, np.nan_to_num(deco.column_theta_deg), bin_deg=bin_deg
    )
    model.meta.update(
        {
            "pitch_deg": float(vps.pitch_deg),
            "roll_deg": float(vps.roll_deg),
            "n_pieces": len(deco.pieces),
            "hfov_deg": float(intrinsics.hfov_deg),
        }
    )
    return model, deco


def analyze_image(
    image_rgb: np.ndarray,
    labels: np.ndarray,
    intrinsics: Intrinsics,
    bin_deg: float = DEFAULT_BIN_DEG,
    **decompose_kwargs: Any,
) -> ImageAnalysis:
    """Full image side of the method: segments, VPs, facade decomposition and image model.

    image_rgb: (H, W, 3) uint8 RGB (or gray); labels: (H, W) class codes (resized with nearest
    neighbour if their size differs); intrinsics: of the image (rescaled if its size differs);
    decompose_kwargs: passed to :func:`decompose_facades`.
    """
    import cv2

    img = np.asarray(image_rgb)
    h, w = img.shape[:2]
    if (intrinsics.width, intrinsics.height) != (w, h):
        intrinsics = intrinsics.scaled(w, h)
    lab = np.asarray(labels)
    if lab.shape != (h, w):
        lab = cv2.resize(lab.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    segments = detect_line_segments(img)
    t1 = time.perf_counter()
    vps = estimate_scene_vanishing_points(lab, segments, intrinsics)
    t2 = time.perf_counter()
    model, deco = facade_image_model(
        lab, segments, intrinsics, vanishing_points=vps, bin_deg=bin_deg, **decompose_kwargs
    )
    t3 = time.perf_counter()
    timings.update({"lines": t1 - t0, "vanishing_points": t2 - t1, "facades": t3 - t2})
    return ImageAnalysis(intrinsics, segments, vps, deco, model, timings)


# ----------------------------------------------------------------------------------------------
# Evaluation


@dataclass
class OrientationErrors:
    """Facade orientation accuracy against ground truth, per pixel column.

    median_abs_error_deg: median |theta_hat - theta| (mod 180, in [0, 90]) over GT building columns
        that have a hypothesis; within_5deg / within_10deg: share of those columns within 5 / 10 deg;
    coverage: share of GT building columns that have a hypothesis at all;
    n_building_columns / n_evaluated_columns: the counts behind them.
    """

    median_abs_error_deg: float
    within_5deg: float
    within_10deg: float
    coverage: float
    n_building_columns: int
    n_evaluated_columns: int

    def to_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def column_orientation_errors(
    pred_model: ImageModel,
    gt_column_orientation_deg: np.ndarray,
    gt_column_is_building: np.ndarray,
    intrinsics: Intrinsics,
    min_confidence: float = 0.0,
) -> tuple[np.ndarray, int, int]:
    """Per-column errors behind :func:`orientation_errors` (same arguments), for pooling over images.

    Returns (|theta_hat - theta| mod 180 in deg of every evaluated column, number of GT building columns
    inside the model's bins, number of those with a hypothesis).
    """
    gt_theta = np.asarray(gt_column_orientation_deg, dtype=float)
    gt_bld = np.asarray(gt_column_is_building, dtype=bool)
    if gt_theta.shape != (intrinsics.width,) or gt_bld.shape != (intrinsics.width,):
        raise ValueError("ground truth must have one value per pixel column")
    bins = column_bins(intrinsics, pred_model.offsets_deg, pred_model.bin_deg)
    inside = bins >= 0
    safe = np.maximum(bins, 0)
    has_hyp = inside & (pred_model.facade_present[safe] > min_confidence)
    building = gt_bld & inside
    evaluated = building & has_hyp & np.isfinite(gt_theta)
    err = np.abs(wrap_orientation_deg(pred_model.orientation_deg[safe] - gt_theta))[evaluated]
    return err, int(building.sum()), int((building & has_hyp).sum())


def orientation_errors(
    pred_model: ImageModel,
    gt_column_orientation_deg: np.ndarray,
    gt_column_is_building: np.ndarray,
    intrinsics: Intrinsics,
    min_confidence: float = 0.0,
) -> OrientationErrors:
    """Compare a predicted image model with per-pixel-column ground truth.

    pred_model: the image model (angular bins); gt_column_orientation_deg: (W,) true theta per pixel
    column (deg, NaN allowed where unknown); gt_column_is_building: (W,) whether the column shows a
    building; intrinsics: of the image (W = width). A column has a hypothesis when its bin's
    ``facade_present > min_confidence``. Columns outside the model's bins are ignored.
    """
    err, n_b, n_covered = column_orientation_errors(
        pred_model, gt_column_orientation_deg, gt_column_is_building, intrinsics, min_confidence
    )
    n_e = len(err)
    return OrientationErrors(
        median_abs_error_deg=float(np.median(err)) if n_e else float("nan"),
        within_5deg=float(np.mean(err <= 5.0)) if n_e else 0.0,
        within_10deg=float(np.mean(err <= 10.0)) if n_e else 0.0,
        coverage=n_covered / n_b if n_b else float("nan"),
        n_building_columns=n_b,
        n_evaluated_columns=n_e,
    )
