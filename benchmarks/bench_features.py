r"""RootSIFT against ALIKED (n16, t16) for matching across viewpoints (prints tables, writes JSON; not a test).

    .venv/bin/geoloc sim world --map ../shared/data/osm/helsinki.osm.pbf --out /tmp/aliked_w1 \
        --references 60 --queries 30 --seed 1
    .venv/bin/python benchmarks/bench_features.py /tmp/aliked_w1 --json bench_features.json

Feature types (``--methods``): ``rootsift``, ``aliked-n16``, ``aliked-t16`` and ``aliked-n16@1,0.5,0.25``
(ALIKED-n16 on a three-level image pyramid, ``extract_features(aliked_scales=...)``).

Needs the models in the cache (``geoloc models build --features rootsift --features aliked-n16
--features aliked-t16``: the segmentation and ALIKED exports and one SBoW vocabulary per feature type).
Every feature type runs on the same images with the same building masks (the segmentation network's,
as the pipeline does; ``--mask gt`` uses the renderer's labels), ``max_features`` 1500, working side
1024 px (the simulated photos are 640 x 480, the Lund photos 1024 x 768). Matching variants:

- ``ratio0.8``: :func:`geoloc.localize.transfer.match_features` as the pipeline does (Lowe ratio 0.8, then
  one-to-one);
- ``mnn+ratio0.8`` / ``0.9`` / ``0.95``: mutual nearest neighbours, then the ratio test at 0.8 / 0.9 / 0.95;

each followed by the pipeline's verification (:func:`geoloc.localize.transfer.geometric_verification`: USAC
MAGSAC++ F and H, 3 working px, at least 12 inliers or none).

Simulated world (ground truth: true poses, intrinsics, per-pixel facade ids; ``match_truth.py``):

- pairs: every query with every reference that sees at least ``--min-covisible`` (0.02) of the
  query image's area, and every query with every reference sharing *no* building ("wrong pairs").
  Co-visibility is measured by ground truth, not by building shares: a query pixel on a facade is
  co-visible when its 3D point (true ray cut with the facade's plane) projects into the reference
  onto the same facade (so occluded and back-side facades do not count; Helsinki's blocks are single
  buildings with many facades, and a reference often shows another side of the query's building);
  wrong pairs are ``--wrong-per-query`` (15) of those per query, drawn at random (seed 0);
- a verified inlier is *correct* when both keypoints lie on the same facade (GT facade id at the
  keypoint's pixel, or within 2 px for keypoints just off a facade's outline) and the point where the
  query's true viewing ray meets that facade's vertical plane reprojects, with the reference's true
  pose, within ``--tol-px`` (4) pixels of the reference keypoint;
- per feature: the share of queries whose best co-visible reference (over queries with one that sees
  >= 0.1 of the image) gets >= 12 and >= 30 correct inliers; correct / all inliers over sharing
  pairs; the wrong pairs that pass verification (>= 12 inliers) and their largest inlier count;
  how many of the verified pairs (sharing or wrong) are *right* (a sharing pair with at least half
  of its inliers correct), and for how many queries the evaluated reference with the most inliers is
  right; extraction time per 640 x 480 image (median; feature types interleaved per image);
- retrieval with each feature type's own vocabulary (4096 words from CamVid train): the share of
  queries whose best-overlapping reference (``geoloc.evaluation.world``'s definition: ties within 0.02) is
  in the SBoW top 20, and in the top 4 after re-ranking those 20 by verified inliers.

Real photos (``../shared/data/lund/images``, 29 photos along one street, adjacent photos overlap):
verified inliers of the 28 adjacent pairs against pairs at least ``--lund-far`` (8) photos apart.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from baseline import add_baseline_option, baseline_figures
from match_truth import GtView, correct_matches, covisible_shares, filled_facade_ids, overlap

from contracts.settings import shared_path
from geoloc.core import labels as classes
from geoloc.evaluation.world import shown_by_references
from geoloc.localize.retrieval import default_vocabulary
from geoloc.localize.sbow_index import SbowIndex
from geoloc.localize.transfer import DEFAULT_MIN_INLIERS, geometric_verification, match_features
from geoloc.maps import CityMap
from geoloc.sim.world import load_world
from geoloc.vision.features import Features, extract_features
from geoloc.vision.segmentation import load_session, segment
from workers.context import method_context

METHODS = ("rootsift", "aliked-n16", "aliked-t16", "aliked-n16@1,0.5,0.25")
MATCHERS = ("ratio0.8", "mnn+ratio0.8", "mnn+ratio0.9", "mnn+ratio0.95")
SHORTLIST = 20
TOP_K = 4


# ----------------------------------------------------------------------------------------------
# Matching


def mutual_matches(query: Features, reference: Features, ratio: float) -> np.ndarray:
    """(K, 2) (query, reference) index pairs: mutual nearest neighbours passing Lowe's ratio test."""
    if len(query) == 0 or len(reference) < 2:
        return np.zeros((0, 2), np.int64)
    sim = query.descriptors @ reference.descriptors.T
    best_r = np.argmax(sim, axis=1)
    best_q = np.argmax(sim, axis=0)
    rows = np.arange(len(query))
    top2 = -np.partition(-sim, 1, axis=1)[:, :2]
    d1 = np.sqrt(np.maximum(2.0 - 2.0 * top2[:, 0], 0.0))
    d2 = np.sqrt(np.maximum(2.0 - 2.0 * top2[:, 1], 0.0))
    keep = (best_q[best_r] == rows) & (d1 < ratio * d2)
    return np.stack([rows[keep], best_r[keep]], axis=1).astype(np.int64)


def matcher(name: str) -> Callable[[Features, Features], np.ndarray]:
    """The putative-match function of a variant name (module docstring)."""
    if name == "ratio0.8":
        return lambda q, r: match_features(q, r, 0.8)
    ratio = float(name.split("ratio")[1])
    return lambda q, r: mutual_matches(q, r, ratio)


def verified(query: Features, reference: Features, match: Callable[[Features, Features], np.ndarray]):
    """Putative pairs (K, 2) and their inlier mask, verified as the pipeline does."""
    pairs = match(query, reference)
    if len(pairs) == 0:
        return pairs, np.zeros(0, bool)
    q_xy = query.xy[pairs[:, 0]] * query.scale
    inliers, _ = geometric_verification(q_xy, reference.xy[pairs[:, 1]] * reference.scale)
    return pairs, inliers


# ----------------------------------------------------------------------------------------------
# Extraction


def building_mask(rgb: np.ndarray, gt_labels: np.ndarray | None) -> np.ndarray:
    """The building mask the features are restricted to: network segmentation, or the given GT labels."""
    labels = gt_labels if gt_labels is not None else segment(rgb, session=load_session(method_context()))
    return labels == classes.BUILDING


def parse_method(spec: str) -> tuple[str, tuple[float, ...]]:
    """Split ``"aliked-n16@1,0.5"`` into ``("aliked-n16", (1.0, 0.5))``: a feature type and ALIKED's scales."""
    name, _, scales = spec.partition("@")
    return name, tuple(float(v) for v in scales.split(",")) if scales else (1.0,)


def extract(spec: str, rgb: np.ndarray, mask: np.ndarray, max_features: int) -> Features:
    """Features of one image for a method spec (see :func:`parse_method`)."""
    name, scales = parse_method(spec)
    return extract_features(rgb, mask, max_features, method=name, aliked_scales=scales, context=method_context())


def extract_all(
    images: dict[str, np.ndarray], masks: dict[str, np.ndarray], methods: tuple[str, ...], max_features: int
) -> tuple[dict[str, dict[str, Features]], dict[str, list[float]]]:
    """Features of every image for every method (methods interleaved per image) and the times (s)."""
    feats: dict[str, dict[str, Features]] = {m: {} for m in methods}
    times: dict[str, list[float]] = {m: [] for m in methods}
    for method in methods:  # warm-up (session creation) outside the timings
        first = next(iter(images))
        extract(method, images[first], masks[first], max_features)
    for name, rgb in images.items():
        for method in methods:
            t0 = time.perf_counter()
            feats[method][name] = extract(method, rgb, masks[name], max_features)
            times[method].append(time.perf_counter() - t0)
    return feats, times


# ----------------------------------------------------------------------------------------------
# Simulated world


def bench_world(args: argparse.Namespace, methods: tuple[str, ...]) -> dict:
    world = load_world(args.world)
    city = world.load_map()
    refs = [im.name for im in world.references]
    queries = [im.name for im in world.queries][: args.max_queries or None]
    names = refs + queries
    images = {n: world.image(n).rgb() for n in names}
    masks = {n: building_mask(images[n], world.gt(n)["labels"] if args.mask == "gt" else None) for n in names}
    views = {
        n: GtView(world.image(n).pose, world.image(n).intrinsics, filled_facade_ids(world.gt(n)["facade_id"]))
        for n in names
    }
    feats, times = extract_all(images, masks, methods, args.max_features)
    print(f"world {args.world}: {len(refs)} references, {len(queries)} queries, masks: {args.mask}")

    overlaps = {(q, r): overlap(world, q, r) for q in queries for r in refs}
    covisible = {(q, r): v for q in queries for r, v in covisible_shares(city, world, q, refs).items()}
    sharing = [(q, r) for (q, r), v in covisible.items() if v >= args.min_covisible]
    rng = np.random.default_rng(0)
    wrong = []
    for q in queries:
        unrelated = [r for r in refs if overlaps[(q, r)] == 0.0]
        picked = rng.choice(len(unrelated), min(args.wrong_per_query, len(unrelated)), replace=False)
        wrong += [(q, unrelated[i]) for i in sorted(picked)]
    best = {}
    for q in queries:
        r = max(refs, key=lambda r, q=q: covisible[(q, r)])
        if covisible[(q, r)] >= 0.1:
            best[q] = r
    best_sets = {q: shown_by_references(world, q, refs)["references"] for q in queries}

    results: dict = {
        "pairs": {"sharing": len(sharing), "wrong": len(wrong), "queries_with_best_overlap": len(best)},
        "features": {},
    }
    for method in methods:
        fm = feats[method]
        t_ms = 1e3 * np.asarray(times[method])
        per_method: dict = {
            "extract_ms_median": round(float(np.median(t_ms)), 1),
            "extract_ms_p90": round(float(np.percentile(t_ms, 90)), 1),
            "keypoints_median": int(np.median([len(fm[n]) for n in names])),
            "matchers": {},
        }
        vocabulary = default_vocabulary(method_context().models_dir, method=parse_method(method)[0])
        words = {n: vocabulary.words(fm[n].descriptors) for n in names}
        index = SbowIndex.from_documents(vocabulary.n_words, ((i, words[r]) for i, r in enumerate(refs)))
        for mname in args.matcher_names:
            match = matcher(mname)
            rows = _pair_rows(city, fm, views, match, {"sharing": sharing, "wrong": wrong}, overlaps, covisible, args)
            by_pair = {(row["query"], row["reference"]): row for row in rows}
            best_correct = np.array([by_pair[(q, r)]["correct"] for q, r in best.items()])
            share_rows = [row for row in rows if row["kind"] == "sharing"]
            wrong_rows = [row for row in rows if row["kind"] == "wrong"]
            inl_sum = sum(row["inliers"] for row in share_rows)
            wrong_inl = np.array([row["inliers"] for row in wrong_rows])
            in_top20, in_top4 = _retrieval_hits(queries, best_sets, (index, refs), words, by_pair, fm, match)
            good = [row for row in share_rows if row["inliers"] and row["correct"] >= 0.5 * row["inliers"]]
            passing = [row for row in rows if row["inliers"] >= DEFAULT_MIN_INLIERS]
            top_right = top_any = 0
            for q in queries:
                top = max((row for row in rows if row["query"] == q), key=lambda row: row["inliers"])
                if top["inliers"] >= DEFAULT_MIN_INLIERS:
                    top_any += 1
                    top_right += top in good
            per_method["matchers"][mname] = {
                "best_pair_correct_ge12": round(float(np.mean(best_correct >= DEFAULT_MIN_INLIERS)), 4),
                "best_pair_correct_ge30": round(float(np.mean(best_correct >= 30)), 4),
                "best_pair_correct_median": float(np.median(best_correct)),
                "sharing_pairs_verified": round(float(np.mean([row["inliers"] > 0 for row in share_rows])), 4),
                "sharing_correct_ratio": round(sum(row["correct"] for row in share_rows) / max(inl_sum, 1), 4),
                "sharing_inliers_mean": round(inl_sum / max(len(share_rows), 1), 2),
                "sharing_correct_mean": round(sum(row["correct"] for row in share_rows) / max(len(share_rows), 1), 2),
                "wrong_pairs_passing": round(float(np.mean(wrong_inl > 0)), 4),
                "wrong_pairs_passing_count": int((wrong_inl > 0).sum()),
                "wrong_inliers_max": int(wrong_inl.max(initial=0)),
                "verified_pairs": len(passing),
                "verified_pairs_right": sum(row in good for row in passing),
                "top_by_inliers_verified": top_any,
                "top_by_inliers_right": top_right,
                "retrieval_best_in_sbow_top20": round(float(np.mean(in_top20)), 4),
                "retrieval_best_in_reranked_top4": round(float(np.mean(in_top4)), 4),
                "pairs": rows,
            }
            print(f"  {method:<22} {mname:<14} done", flush=True)
        results["features"][method] = per_method
    return results


def _pair_rows(
    city: CityMap,
    fm: dict[str, Features],
    views: dict[str, GtView],
    match: Callable[[Features, Features], np.ndarray],
    pairs_by_kind: dict[str, list[tuple[str, str]]],
    overlaps: dict[tuple[str, str], float],
    covisible: dict[tuple[str, str], float],
    args: argparse.Namespace,
) -> list[dict[str, Any]]:
    """One row per (query, reference) pair of each kind: matches, inliers and (sharing pairs) correct ones."""
    rows = []
    for kind, pairs in pairs_by_kind.items():
        for q, r in pairs:
            p, inl = verified(fm[q], fm[r], match)
            good = p[inl]
            n_correct = 0
            if kind == "sharing":
                q_xy, r_xy = fm[q].xy[good[:, 0]], fm[r].xy[good[:, 1]]
                n_correct = int(correct_matches(city, views[q], views[r], q_xy, r_xy, args.tol_px).sum())
            rows.append({"kind": kind, "query": q, "reference": r, "overlap": round(overlaps[(q, r)], 4),
                         "covisible": round(covisible[(q, r)], 4), "matches": len(p),
                         "inliers": int(inl.sum()), "correct": n_correct})  # fmt: skip
    return rows


def _retrieval_hits(
    queries: list[str],
    best_sets: dict[str, set[str]],
    index: tuple[SbowIndex, list[str]],
    words: dict[str, np.ndarray],
    by_pair: dict[tuple[str, str], dict[str, Any]],
    fm: dict[str, Features],
    match: Callable[[Features, Features], np.ndarray],
) -> tuple[list[bool], list[bool]]:
    """Retrieval: SBoW top 20, re-ranked by verified inliers (this matcher) to the top 4.

    index: the references' SBoW index (document i: the i-th name of the list) and their names.
    For each query with a best-overlapping reference set: whether one of them is in the SBoW top 20, and in
    the re-ranked top 4.
    """
    in_top20, in_top4 = [], []
    for q in queries:
        if not best_sets[q]:
            continue
        shortlist = [(index[1][doc], score) for doc, score in index[0].top(words[q], SHORTLIST)]
        ranked = []
        for r, score in shortlist:
            row = by_pair.get((q, r))
            n_inl = row["inliers"] if row else int(verified(fm[q], fm[r], match)[1].sum())
            ranked.append((-n_inl, -score, r))
        ranked.sort()
        in_top20.append(bool(best_sets[q] & {r for r, _ in shortlist}))
        in_top4.append(bool(best_sets[q] & {r for _, _, r in ranked[:TOP_K]}))
    return in_top20, in_top4


# ----------------------------------------------------------------------------------------------
# Lund


def bench_lund(args: argparse.Namespace, methods: tuple[str, ...]) -> dict:
    paths = sorted(shared_path("data", "lund", "images").glob("*.jpg"))
    images = {p.stem: cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in paths}
    masks = {n: building_mask(rgb, None) for n, rgb in images.items()}
    feats, times = extract_all(images, masks, methods, args.max_features)
    names = list(images)
    adjacent = [(names[i], names[i + 1]) for i in range(len(names) - 1)]
    far = [(names[i], names[j]) for i in range(len(names)) for j in range(i + args.lund_far, len(names))]
    out: dict = {"photos": len(names), "adjacent_pairs": len(adjacent), "far_pairs": len(far), "features": {}}
    for method in methods:
        fm = feats[method]
        t_ms = 1e3 * np.asarray(times[method])
        entry: dict = {"extract_ms_median": round(float(np.median(t_ms)), 1), "matchers": {}}
        for mname in args.matcher_names:
            match = matcher(mname)
            adj = np.array([int(verified(fm[a], fm[b], match)[1].sum()) for a, b in adjacent])
            far_inl = np.array([int(verified(fm[a], fm[b], match)[1].sum()) for a, b in far])
            entry["matchers"][mname] = {
                "adjacent_inliers_median": float(np.median(adj)),
                "adjacent_inliers_mean": round(float(adj.mean()), 1),
                "adjacent_verified": round(float(np.mean(adj > 0)), 4),
                "adjacent_ge30": round(float(np.mean(adj >= 30)), 4),
                "far_passing": round(float(np.mean(far_inl > 0)), 4),
                "far_inliers_max": int(far_inl.max(initial=0)),
                "adjacent_inliers": adj.tolist(),
            }
        out["features"][method] = entry
    return out


# ----------------------------------------------------------------------------------------------
# Report


def print_tables(world: dict | None, lund: dict | None) -> None:
    if world:
        print("\nSimulated world: best co-visible pairs (>= 0.1), co-visible pairs, wrong pairs, retrieval")
        head = (
            f"{'feature':<22} {'matcher':<14} {'ms/img':>7} {'>=12 ok':>8} {'>=30 ok':>8} {'med ok':>7} "
            f"{'ok/inl':>7} {'inl/pair':>8} {'wrong>0':>8} {'wrongmax':>8} {'right/ver':>9} {'top1':>6} "
            f"{'top20':>6} {'top4':>6}"
        )
        print(head)
        for method, entry in world["features"].items():
            for mname, m in entry["matchers"].items():
                print(
                    f"{method:<22} {mname:<14} {entry['extract_ms_median']:>7.0f} {m['best_pair_correct_ge12']:>8.2f} "
                    f"{m['best_pair_correct_ge30']:>8.2f} {m['best_pair_correct_median']:>7.0f} "
                    f"{m['sharing_correct_ratio']:>7.2f} {m['sharing_inliers_mean']:>8.1f} "
                    f"{m['wrong_pairs_passing']:>8.3f} {m['wrong_inliers_max']:>8d} "
                    f"{m['verified_pairs_right']:>4d}/{m['verified_pairs']:<4d} "
                    f"{m['top_by_inliers_right']:>3d}/{m['top_by_inliers_verified']:<2d} "
                    f"{m['retrieval_best_in_sbow_top20']:>6.2f} {m['retrieval_best_in_reranked_top4']:>6.2f}"
                )
    if lund:
        print(f"\nLund: verified inliers, {lund['adjacent_pairs']} adjacent pairs vs {lund['far_pairs']} far pairs")
        print(
            f"{'feature':<22} {'matcher':<14} {'ms/img':>7} {'adj med':>8} {'adj mean':>8} {'adj>=30':>8} "
            f"{'far>0':>6} {'farmax':>6}"
        )
        for method, entry in lund["features"].items():
            for mname, m in entry["matchers"].items():
                print(
                    f"{method:<22} {mname:<14} {entry['extract_ms_median']:>7.0f} {m['adjacent_inliers_median']:>8.0f} "
                    f"{m['adjacent_inliers_mean']:>8.1f} {m['adjacent_ge30']:>8.2f} {m['far_passing']:>6.2f} "
                    f"{m['far_inliers_max']:>6d}"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("world", nargs="?", help="a world folder from `geoloc sim world` (omit to skip)")
    parser.add_argument("--json", type=Path, default=Path("bench_features.json"))
    parser.add_argument(
        "--methods",
        default=";".join(METHODS),
        help="feature types, ';'-separated; 'aliked-n16@1,0.5' runs ALIKED on a pyramid of those scales",
    )
    parser.add_argument("--mask", choices=("network", "gt"), default="network")
    parser.add_argument("--max-features", type=int, default=1500)
    parser.add_argument("--min-covisible", type=float, default=0.02)
    parser.add_argument("--tol-px", type=float, default=4.0)
    parser.add_argument("--max-queries", type=int, default=0)
    parser.add_argument("--wrong-per-query", type=int, default=15)
    parser.add_argument("--lund-far", type=int, default=8)
    parser.add_argument("--skip-lund", action="store_true")
    parser.add_argument("--matchers", default="", help=f"';'-separated subset of {';'.join(MATCHERS)}")
    add_baseline_option(parser)
    args = parser.parse_args()
    methods = tuple(m.strip() for m in args.methods.split(";"))

    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}"
    print(f"machine: {machine}")
    args.matcher_names = tuple(args.matchers.split(";")) if args.matchers else MATCHERS
    t0 = time.perf_counter()
    world = bench_world(args, methods) if args.world else None
    lund = None if args.skip_lund else bench_lund(args, methods)
    print_tables(world, lund)
    report = {
        "command": "benchmarks/bench_features.py " + " ".join(os.sys.argv[1:]),
        "machine": machine,
        "settings": {k: v for k, v in vars(args).items() if k != "json"} | {"json": str(args.json)},
        "world": world,
        "lund": lund,
        "total_s": round(time.perf_counter() - t0, 1),
    }
    baseline_figures(args.baseline, __file__, report)
    args.json.write_text(json.dumps(report, indent=1) + "\n")
    print(f"\nwrote {args.json} ({report['total_s']} s)")


if __name__ == "__main__":
    main()
