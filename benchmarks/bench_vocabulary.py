"""Benchmark: does retrieval need a larger vocabulary at scale? The 4,096 words next to a 65,536-word tree.

    .venv/bin/python benchmarks/bench_vocabulary.py [--world DIR] [--distractors 100000] [--json vocabulary.json]

Both vocabularies are trained on the building pixels of the CamVid train images (the service's own
vocabulary, ``geoloc.localize.retrieval.default_vocabulary``: flat k-means, 4,096 words; and a two-level
hierarchical one built here, 256 x 256 words by k-means within each first-level word, the usual vocabulary
tree, from 1,500 descriptors per image). On a simulated Helsinki world (60 references, 30 queries, seed 1;
made here unless ``--world`` names one), every reference and query photo is analysed as the service does
(network segmentation, RootSIFT on buildings) and the references are indexed
(:class:`geoloc.localize.sbow_index.SbowIndex`, the worker's index). For each query, the references that share the
most building area with it (:func:`geoloc.evaluation.world.shown_by_references`) are looked up in the SBoW
ranking: recall at 1, 5, 20 (the query stage's shortlist) and 60 (the shortlist ranked before a position
prior leaves far references out).

At scale: ``--distractors`` more documents are added to each index, as a city's other references would
be: each a resampling of the words of a real street photo (the 701 CamVid train, val and test images, RootSIFT
on their labelled building pixels; ~600 keypoints, with repeats) in that vocabulary. The world's references must still
rank as high among them. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from baseline import add_baseline_option, baseline_figures
from PIL import Image

from contracts.settings import shared_path
from geoloc.core.labels import BUILDING
from geoloc.evaluation.world import shown_by_references
from geoloc.export.vocabulary import camvid_building_descriptors
from geoloc.localize.retrieval import Vocabulary, build_vocabulary, default_vocabulary
from geoloc.localize.sbow_index import SbowIndex
from geoloc.photos.photo import load_photo
from geoloc.sim.world import WorldOptions, generate_world, load_world
from geoloc.vision.evidence import analyze_photo
from geoloc.vision.features import extract_features
from workers.context import method_context

KS = (1, 5, 20, 60)
BRANCHING = 256


class TreeVocabulary:
    """A two-level vocabulary tree: ``BRANCHING`` coarse words, each split into up to ``BRANCHING`` fine words."""

    def __init__(self, coarse: Vocabulary, fine: list[Vocabulary]) -> None:
        self.coarse = coarse
        self.fine = fine

    @classmethod
    def build(cls, descriptors: np.ndarray, seed: int = 0) -> TreeVocabulary:
        coarse = build_vocabulary(descriptors, BRANCHING, seed)
        assignment = coarse.words(descriptors)
        fine = []
        for word in range(len(coarse)):
            members = descriptors[assignment == word]
            if len(members) == 0:  # an empty coarse word keeps its centre as its only fine word
                fine.append(Vocabulary(coarse.centroids[word : word + 1]))
                continue
            fine.append(build_vocabulary(members, min(BRANCHING, max(1, len(members) // 4)), seed + 1 + word))
        return cls(coarse, fine)

    def __len__(self) -> int:
        return len(self.coarse) * BRANCHING

    def words(self, descriptors: np.ndarray) -> np.ndarray:
        coarse = self.coarse.words(descriptors)
        out = np.empty(len(descriptors), np.int64)
        for word in np.unique(coarse):
            members = coarse == word
            out[members] = word * BRANCHING + self.fine[word].words(descriptors[members])
        return out


def recall(
    index: SbowIndex, ids: list[str], queries: dict[str, np.ndarray], best: dict[str, set[str]]
) -> dict[str, Any]:
    """Share of queries (that some reference shows) whose best-overlapping reference ranks within each k."""
    hits: dict[int, list[bool]] = {k: [] for k in KS}
    number = {name: i for i, name in enumerate(ids)}
    for name, words in queries.items():
        if not best[name]:
            continue
        ranked = [doc for doc, _ in index.top(words, max(KS))]
        wanted = {number[r] for r in best[name]}
        for k in KS:
            hits[k].append(bool(wanted & set(ranked[:k])))
    return {f"recall_at_{k}": round(float(np.mean(v)), 3) for k, v in hits.items()} | {"queries": len(hits[1])}


def distractor_documents(photo_words: list[np.ndarray], n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``n`` documents, each ~600 words resampled (with repeats) from one real photo's words."""
    out = []
    for _ in range(n):
        source = photo_words[int(rng.integers(len(photo_words)))]
        size = int(np.clip(rng.lognormal(np.log(600), 0.4), 100, 1500))
        out.append(source[rng.integers(0, len(source), size)] if len(source) else source)
    return out


def build_index(n_words: int, documents: list[np.ndarray]) -> SbowIndex:
    index = SbowIndex(n_words)
    bags = [np.unique(words, return_counts=True) for words in documents]
    index.load(
        np.arange(len(documents)),
        np.array([len(words) for words in documents], float),
        np.concatenate([w for w, _ in bags]),
        np.repeat(np.arange(len(bags)), [len(w) for w, _ in bags]),
        np.concatenate([c for _, c in bags]).astype(float),
    )
    return index


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--world", type=Path, help="a simulated Helsinki world (default: made here)")
    parser.add_argument("--distractors", type=int, default=100_000)
    parser.add_argument("--json", type=Path, default=Path("vocabulary.json"))
    add_baseline_option(parser)
    args = parser.parse_args()
    figures: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start",
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
    }
    print(f"machine: {figures['machine']}")
    world_dir = args.world
    if world_dir is None:
        world_dir = Path(tempfile.mkdtemp(prefix="bench-vocabulary-")) / "world"
        options = WorldOptions(n_references=60, n_queries=30, seed=1)
        generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), world_dir, options)
    world = load_world(world_dir)
    t0 = time.perf_counter()
    images = [*world.references, *world.queries]
    context = method_context()
    descriptors = {im.name: analyze_photo(load_photo(im.path), context=context).features.descriptors for im in images}
    reference_names = [im.name for im in world.references]
    best = {q.name: shown_by_references(world, q.name, reference_names)["references"] for q in world.queries}
    shown = sum(bool(b) for b in best.values())
    print(f"world: {len(reference_names)} references, {len(world.queries)} queries analysed in "
          f"{time.perf_counter() - t0:.0f} s; {shown} queries shown by a reference")  # fmt: skip

    t0 = time.perf_counter()
    train = camvid_building_descriptors(method_context(), "train", per_image=1500)
    flat = default_vocabulary(method_context().models_dir)
    tree = TreeVocabulary.build(train)
    build_s = time.perf_counter() - t0
    print(f"vocabularies: flat {len(flat):,} words (the service's); tree {len(tree):,} words built in {build_s:.0f} s "
          f"from {len(train):,} CamVid train descriptors")  # fmt: skip
    photo_descriptors = [
        extract_features(
            np.asarray(Image.open(path).convert("RGB")),
            np.asarray(Image.open(shared_path("data", "camvid", split, "labels", f"{path.stem}.png"))) == BUILDING,
        ).descriptors
        for split in ("train", "val", "test")
        for path in sorted(shared_path("data", "camvid", split, "images").glob("*.*"))
    ]
    print(f"distractor sources: {len(photo_descriptors)} CamVid photos (train, val and test; their labelled "
          f"building pixels)")  # fmt: skip

    figures["vocabularies"] = {}
    rng = np.random.default_rng(0)
    for label, vocabulary in (("flat 4096", flat), ("tree 65536", tree)):
        words = {name: vocabulary.words(d) for name, d in descriptors.items()}
        queries = {q.name: words[q.name] for q in world.queries}
        references = [words[name] for name in reference_names]
        row: dict[str, Any] = {"words": len(vocabulary)}
        row["world_only"] = recall(build_index(len(vocabulary), references), reference_names, queries, best)
        sources = [vocabulary.words(d) for d in photo_descriptors]
        distractors = distractor_documents(sources, args.distractors, rng)
        t0 = time.perf_counter()
        index = build_index(len(vocabulary), references + distractors)
        row["with_distractors"] = recall(index, reference_names, queries, best)
        row["with_distractors"]["distractors"] = args.distractors
        row["with_distractors"]["index_mb"] = round(index.nbytes / 2**20, 1)
        row["with_distractors"]["build_s"] = round(time.perf_counter() - t0, 1)
        times = []
        for query_words in queries.values():
            t1 = time.perf_counter()
            index.top(query_words, 10)
            times.append(1e3 * (time.perf_counter() - t1))
        row["with_distractors"]["top10_ms_p50"] = round(float(np.median(times)), 2)
        figures["vocabularies"][label] = row
        del index, distractors
        w, d = row["world_only"], row["with_distractors"]
        alone = "/".join(str(w[f"recall_at_{k}"]) for k in KS)
        crowded = "/".join(str(d[f"recall_at_{k}"]) for k in KS)
        print(f"{label:11s} recall@1/5/20/60 world only {alone}; with {args.distractors:,} distractors {crowded} "
              f"(top-10 {d['top10_ms_p50']} ms, index {d['index_mb']} MB)")  # fmt: skip
    figures["load_average_end"] = round(os.getloadavg()[0], 1)
    baseline_figures(args.baseline, __file__, figures)
    args.json.write_text(json.dumps(figures, indent=2))
    print(f"figures written to {args.json}")


if __name__ == "__main__":
    main()
