"""Benchmark: the SBoW shortlist at city scale, the database path next to the in-memory index, in one run.

    .venv/bin/python benchmarks/bench_sbow.py [--references 100000] [--queries 200] [--sql-queries 5]
                                              [--workers 4] [--workdir DIR] [--json sbow.json]

1. Writes ``--references`` synthetic references into a fresh database of the service's own schema
   (``db.migrate``: ``reference_images``, ``sbow_documents``, ``sbow_postings``, ``sbow_changes``), one
   map, a 4,096-word vocabulary. Word statistics follow the references of a simulated Helsinki world
   labelled with the CamVid vocabulary (measured: median 817 keypoints and 441 distinct words per
   reference, word frequencies Zipf with exponent 0.79): here ~600 keypoints per reference (log-normal,
   100-1,500), 73 % of them drawn from the Zipf distribution over all words and 27 % from 30 words of the
   reference's own (a facade's repeated windows), which gives the measured share of distinct words.
   Rows are written in primary-key order and the postings' secondary index is built after them (the
   same schema, loaded faster than row by row).
2. The same query photos (synthetic, 600 keypoints: half of them a noisy copy of a reference, half
   fresh) go to both shortlists: the database path the service used before
   (``db.sbow.postings_for_words`` + ``geoloc.localize.retrieval.tfidf_scores``: every postings row of the
   query's words, for ``--sql-queries`` queries) and the worker's in-memory index
   (``workers.reference_store.DatabaseReferenceStore.shortlist``: ``geoloc.localize.sbow_index.SbowIndex``,
   refreshed from the change log before each query). Their top-10 lists must be identical.
3. Memory: the index's arrays, and the process's resident memory before and after the first load and its
   peak from the first load through the in-memory queries (the database is written before and the peak is
   reset then: from there on the process holds what a worker holds); the database path's peak apart.
4. Consistency: another connection adds 200 references, re-indexes 50 and deletes 50 through the
   service's own functions (``db.sbow.index_reference``, ``db.references.delete_reference``); the next
   shortlist catches up (time reported) and matches the database path again.

5. Worker processes (``--workers N``, 0 skips it; :mod:`sbow_workers`): one and N processes started together,
   each loading the map's index as a worker does and answering 20 of the queries, first each with its own
   index, then on the machine's shared base segment (``workers.sbow_share``: written once, memory-mapped by
   all), both started as separate processes (``GEOLOC_WORKER_START=spawn``), then forked on the shared base
   by one warmed parent as the service's pool does (``fork``, :func:`workers.pool.freeze_warmed` then
   :func:`workers.pool.fork_child`; the parent counted); their resident memory (RSS) and proportional set
   size (PSS) together, and whether every process's shortlists are byte-identical to this process's. The
   target's ratio is the forked one (``GEOLOC_WORKER_START=fork``, opt-in: the default starts separate
   processes).

Prints a table and writes JSON. Targets (issue 14): <= 30 ms median top-10 latency and <= 2 GB at
100,000 references; (issue 23) N = 4 workers on the shared base take together <= 1.5x one worker's memory
(PSS, the honest sum for shared pages; RSS, which counts a shared page in every process, reported beside it).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from baseline import add_baseline_option, baseline_figures
from local_service import status_mb
from sbow_workers import shortlist_digest, worker_memory

from db import connect, migrate, sbow, transaction
from db import maps as map_store
from db import references as reference_store
from geoloc.localize.retrieval import tfidf_scores
from workers import reference_store as store_module
from workers.reference_store import DatabaseReferenceStore

N_WORDS = 4096
ZIPF_EXPONENT = 0.79
BURST_SHARE = 0.27
BURST_WORDS = 30
TARGET_P50_MS = 30.0
TARGET_GB = 2.0


class Corpus:
    """Synthetic references' words: a global Zipf distribution plus a few words of each reference's own."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        p = 1.0 / np.arange(1, N_WORDS + 1) ** ZIPF_EXPONENT
        self.cdf = np.cumsum(p / p.sum())
        self.permutation = self.rng.permutation(N_WORDS)  # frequent words are not the low ids

    def zipf(self, n: int) -> np.ndarray:
        return self.permutation[np.minimum(np.searchsorted(self.cdf, self.rng.random(n)), N_WORDS - 1)]

    def document(self) -> np.ndarray:
        n = int(np.clip(self.rng.lognormal(np.log(600), 0.4), 100, 1500))
        burst = int(BURST_SHARE * n)
        own = self.zipf(BURST_WORDS)
        return np.concatenate([self.zipf(n - burst), own[self.rng.integers(0, BURST_WORDS, burst)]])

    def noisy_copy(self, words: np.ndarray, keep: float = 0.5) -> np.ndarray:
        kept = words[self.rng.random(len(words)) < keep]
        return np.concatenate([kept, self.zipf(600 - len(kept))]) if len(kept) < 600 else kept


def build_database(path: Path, n_references: int, corpus: Corpus) -> tuple[int, dict[int, np.ndarray], dict[str, Any]]:
    """A fresh service database with one map and ``n_references`` indexed references.

    Returns the map id, a sample of the references' words (for queries) and figures.
    """
    db = connect(path)
    migrate(db)
    content = map_store.MapContent(
        bbox_wgs84=(60.16, 24.93, 60.18, 24.96),
        origin_lat=60.17,
        origin_lon=24.945,
        buildings=[],
        facade_arrays={"start": np.zeros((1, 2)), "building_id": np.zeros(1, np.int32)},
        repair_report={},
    )
    with transaction(db):
        map_id = map_store.insert_map(
            db,
            name="synthetic",
            source_filename="synthetic.geojson",
            source_format="geojson",
            source_path="maps/synthetic.geojson",
            sha256="f" * 64,
            size_bytes=1,
            content=content,
        )
        sbow.save_vocabulary(db, map_id, {"centers": np.zeros((N_WORDS, 1), np.float32)})
    t0 = time.perf_counter()
    now = time.time()
    words_of: list[np.ndarray] = []
    counts_of: list[np.ndarray] = []
    totals = np.zeros(n_references)
    sample: dict[int, np.ndarray] = {}
    for i in range(n_references):
        words = corpus.document()
        distinct, counts = np.unique(words, return_counts=True)
        words_of.append(distinct.astype(np.int16))
        counts_of.append(counts.astype(np.uint16))
        totals[i] = len(words)
        if i % max(1, n_references // 1000) == 0:
            sample[i + 1] = words
    ids = np.arange(1, n_references + 1)
    generated_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    db.execute("DROP INDEX sbow_postings_reference")  # built once after the rows (same schema)
    with transaction(db):
        db.conn.executemany(
            "INSERT INTO reference_images (id, map_id, image_path, original_filename, sha256, size_bytes,"
            " image_format, width, height, gps_lat, gps_lon, position_source, status, created_at, updated_at)"
            " VALUES (?, ?, ?, NULL, ?, 1, 'JPEG', 640, 480, 60.17, 24.945, 'request', 'done', ?, ?)",
            ((int(r), map_id, f"images/{r}.jpg", f"{r:064x}", now, now) for r in ids),
        )
        db.conn.executemany(
            "INSERT INTO sbow_documents (reference_id, map_id, word_total, created_at) VALUES (?, ?, ?, ?)",
            ((int(r), map_id, float(t), now) for r, t in zip(ids, totals, strict=True)),
        )
        db.conn.executemany(
            "INSERT INTO sbow_changes (map_id, reference_id, changed_at) VALUES (?, ?, ?)",
            ((map_id, int(r), now) for r in ids),
        )
    # Postings in primary-key order (map, word, reference): a counting sort by word.
    sizes = np.array([len(w) for w in words_of])
    all_words = np.concatenate(words_of)
    all_counts = np.concatenate(counts_of)
    all_refs = np.repeat(ids.astype(np.int32), sizes)
    del words_of, counts_of
    order = np.argsort(all_words, kind="stable")
    all_words, all_counts, all_refs = all_words[order], all_counts[order], all_refs[order]
    del order
    chunk = 1 << 20
    with transaction(db):
        for start in range(0, len(all_words), chunk):
            rows = zip(
                [map_id] * len(all_words[start : start + chunk]),
                all_words[start : start + chunk].tolist(),
                all_refs[start : start + chunk].tolist(),
                all_counts[start : start + chunk].astype(float).tolist(),
                strict=True,
            )
            db.conn.executemany(
                "INSERT INTO sbow_postings (map_id, word_id, reference_id, weight) VALUES (?, ?, ?, ?)", rows
            )
    rows_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    db.execute("CREATE INDEX sbow_postings_reference ON sbow_postings(reference_id)")
    index_s = time.perf_counter() - t0
    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    figures = {
        "references": n_references,
        "postings_rows": int(len(all_words)),
        "keypoints_per_reference_median": float(np.median(totals)),
        "distinct_words_per_reference_median": float(np.median(sizes)),
        "generate_s": round(generated_s, 1),
        "write_rows_s": round(rows_s, 1),
        "postings_index_s": round(index_s, 1),
        "database_mb": round(sum(p.stat().st_size for p in path.parent.glob(path.name + "*")) / 2**20, 1),
    }
    db.close()
    return map_id, sample, figures


def sql_shortlist(db: Any, map_id: int, words: np.ndarray, n: int) -> tuple[list[tuple[int, float]], int]:
    """The database path: every postings row of the query's words, ranked by tfidf_scores."""
    p = sbow.postings_for_words(db, map_id, words)
    scores = tfidf_scores(words, p.word, p.doc, p.count, p.doc_lengths, p.n_docs)
    order = np.argsort(-scores, kind="stable")[:n]
    return [(int(p.reference_ids[i]), float(scores[i])) for i in order if scores[i] > 0], len(p.word)


def _percentile(values: list[float], q: float) -> float:
    return round(float(np.percentile(values, q)), 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--references", type=int, default=100_000)
    parser.add_argument("--queries", type=int, default=200)
    parser.add_argument("--sql-queries", type=int, default=5, help="queries also run through the database path")
    parser.add_argument("--workers", type=int, default=4, help="worker processes started side by side (0: none)")
    parser.add_argument("--workdir", type=Path, help="folder for the database (default: temporary, removed)")
    parser.add_argument("--json", type=Path, default=Path("sbow.json"))
    parser.add_argument("--seed", type=int, default=0)
    add_baseline_option(parser)
    args = parser.parse_args()

    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench-sbow-"))
    workdir.mkdir(parents=True, exist_ok=True)
    path = workdir / "geoloc.sqlite3"
    for stale in workdir.glob("geoloc.sqlite3*"):
        stale.unlink()
    figures: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start",
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
    }
    print(f"machine: {figures['machine']}; database in {workdir}")
    corpus = Corpus(args.seed)
    map_id, sample, figures["database"] = build_database(path, args.references, corpus)
    d = figures["database"]
    distinct, keypoints = d["distinct_words_per_reference_median"], d["keypoints_per_reference_median"]
    print(f"database: {d['references']:,} references, {d['postings_rows']:,} postings rows "
          f"({distinct:.0f} distinct words of {keypoints:.0f} keypoints per reference), {d['database_mb']:,} MB; "
          f"rows {d['write_rows_s']} s, postings index {d['postings_index_s']} s")  # fmt: skip

    # From here on the process is what a worker is: the index, the queries. Its peak memory counts from now.
    gc.collect()
    Path("/proc/self/clear_refs").write_text("5")
    db = connect(path)
    store = DatabaseReferenceStore(db, map_id)
    rss_before = status_mb(os.getpid(), "VmRSS")
    t0 = time.perf_counter()
    live = store.live_index()
    load_s = time.perf_counter() - t0
    assert live is not None
    figures["index"] = {
        "first_load_s": round(load_s, 1),
        "index_mb": round(live.index.nbytes / 2**20, 1),
        "rss_before_mb": round(rss_before, 1),
        "rss_after_mb": round(status_mb(os.getpid(), "VmRSS"), 1),
        "peak_rss_mb": round(status_mb(os.getpid(), "VmHWM"), 1),
    }
    f = figures["index"]
    print(f"in-memory index: first load {f['first_load_s']} s; arrays {f['index_mb']} MB; process resident "
          f"{f['rss_before_mb']:.0f} -> {f['rss_after_mb']:.0f} MB (peak {f['peak_rss_mb']:.0f} MB)")  # fmt: skip

    sources = list(sample.values())
    queries = [
        corpus.noisy_copy(sources[i % len(sources)]) if i % 2 == 0 else corpus.zipf(600) for i in range(args.queries)
    ]
    memory_ms: list[float] = []
    fast_lists = []
    for words in queries:
        t0 = time.perf_counter()
        fast_lists.append(store.shortlist(words, 10))
        memory_ms.append(1e3 * (time.perf_counter() - t0))
    index_peak_mb = status_mb(os.getpid(), "VmHWM")
    # The database path after, with its own peak: it holds every postings row of the query's words in Python.
    Path("/proc/self/clear_refs").write_text("5")
    sql_ms: list[float] = []
    rows_read: list[int] = []
    identical = 0
    for words, fast in zip(queries[: args.sql_queries], fast_lists, strict=False):
        t0 = time.perf_counter()
        slow, rows = sql_shortlist(db, map_id, words, 10)
        sql_ms.append(1e3 * (time.perf_counter() - t0))
        rows_read.append(rows)
        identical += fast == slow
    sql_peak_mb = status_mb(os.getpid(), "VmHWM")
    figures["shortlist_top10"] = {
        "in_memory": {
            "queries": len(memory_ms),
            "p50_ms": _percentile(memory_ms, 50),
            "p95_ms": _percentile(memory_ms, 95),
            "mean_ms": round(statistics.fmean(memory_ms), 2),
        },
        "database_path": {
            "queries": len(sql_ms),
            "p50_ms": _percentile(sql_ms, 50) if sql_ms else None,
            "postings_rows_read_median": int(np.median(rows_read)) if rows_read else None,
            "peak_rss_mb": round(sql_peak_mb, 1),
        },
        "identical_top10": f"{identical}/{len(sql_ms)}",
    }
    s = figures["shortlist_top10"]
    print(f"top-10, in-memory index: p50 {s['in_memory']['p50_ms']} ms, p95 {s['in_memory']['p95_ms']} ms "
          f"({s['in_memory']['queries']} queries, each after a change-log check)")  # fmt: skip
    if sql_ms:
        print(f"top-10, database path:   p50 {s['database_path']['p50_ms']:,} ms "
              f"({s['database_path']['postings_rows_read_median']:,} postings rows read per query, peak memory "
              f"{sql_peak_mb:.0f} MB); identical lists {s['identical_top10']}")  # fmt: skip
    print(f"peak resident memory of the process from the index's first load through its queries: "
          f"{index_peak_mb:.0f} MB")  # fmt: skip

    # Consistency: another connection writes through the service's functions; the next shortlist catches up.
    writer = connect(path)
    rng = np.random.default_rng(args.seed + 1)
    next_id = args.references + 1
    t0 = time.perf_counter()
    for _ in range(200):
        words = corpus.document()
        with transaction(writer):
            writer.execute(
                "INSERT INTO reference_images (id, map_id, image_path, sha256, size_bytes, image_format, width,"
                " height, gps_lat, gps_lon, position_source, status, created_at, updated_at)"
                " VALUES (?, ?, ?, ?, 1, 'JPEG', 640, 480, 60.17, 24.945, 'request', 'done', ?, ?)",
                (next_id, map_id, f"images/{next_id}.jpg", f"{next_id:064x}", time.time(), time.time()),
            )
            sbow.index_reference(writer, map_id, next_id, words, np.ones(len(words)))
        next_id += 1
    for reference_id in rng.choice(np.arange(1, args.references + 1), 100, replace=False).tolist():
        with transaction(writer):
            if len(sample) and reference_id % 2:
                reference_store.delete_reference(writer, int(reference_id))
            else:
                words = corpus.document()
                sbow.index_reference(writer, map_id, int(reference_id), words, np.ones(len(words)))
    write_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    catch_up = store.shortlist(queries[0], 10)
    catch_up_ms = 1e3 * (time.perf_counter() - t0)
    consistent = catch_up == sql_shortlist(db, map_id, queries[0], 10)[0]
    for words in queries[1:3]:
        consistent &= store.shortlist(words, 10) == sql_shortlist(db, map_id, words, 10)[0]
    figures["consistency"] = {
        "changes": "200 added, ~50 re-indexed, ~50 deleted by another connection",
        "writes_s": round(write_s, 1),
        "catch_up_query_ms": round(catch_up_ms, 1),
        "identical_to_database_path_after_changes": bool(consistent),
        "documents": len(live.index),
    }
    print(f"after 300 changes by another connection: the next shortlist took {catch_up_ms:.0f} ms (catching up); "
          f"identical to the database path: {consistent}")  # fmt: skip
    if args.workers:
        runs = worker_memory(path, map_id, queries[:20], args.workers, workdir / "cache" / "sbow")
        expected = shortlist_digest([store.shortlist(words, 10) for words in queries[:20]])
        one, many = runs["fork_1"], runs[f"fork_{args.workers}"]
        figures["workers"] = {
            **runs,
            "identical_shortlists_in_every_process": all(run["digests"] == [expected] for run in runs.values()),
            "pss_ratio_many_to_one": round(many["pss_mb_sum"] / one["pss_mb_sum"], 2),
            "rss_ratio_many_to_one": round(many["rss_mb_sum"] / one["rss_mb_sum"], 2),
            "pss_ratio_many_to_one_spawned": round(
                runs[f"shared_{args.workers}"]["pss_mb_sum"] / runs["shared_1"]["pss_mb_sum"], 2
            ),
            "pss_ratio_many_to_one_own_indexes": round(
                runs[f"own_{args.workers}"]["pss_mb_sum"] / runs["own_1"]["pss_mb_sum"], 2
            ),
        }
    peak_gb = index_peak_mb / 1024
    figures["memory"] = {
        "index_arrays_mb": f["index_mb"],
        "process_peak_rss_gb_index_load_and_queries": round(peak_gb, 2),
        "process_peak_rss_gb_database_path": round(sql_peak_mb / 1024, 2),
    }
    figures["targets"] = {
        "p50_ms": {"value": s["in_memory"]["p50_ms"], "target": TARGET_P50_MS, "met": s["in_memory"]["p50_ms"] <= 30},
        "memory_gb": {"value": round(peak_gb, 2), "target": TARGET_GB, "met": peak_gb <= TARGET_GB},
        "same_ranking": {"value": s["identical_top10"], "met": identical == len(sql_ms) and bool(consistent)},
    }
    if args.workers:
        w = figures["workers"]
        figures["targets"]["workers_memory_ratio"] = {
            "value": w["pss_ratio_many_to_one"],
            "rss": w["rss_ratio_many_to_one"],
            "target": 1.5,
            "met": w["pss_ratio_many_to_one"] <= 1.5 and w["identical_shortlists_in_every_process"],
        }
    for name, target in figures["targets"].items():
        print(f"target {name}: {target['value']} (target {target.get('target', 'identical')}): "
              f"{'met' if target['met'] else 'NOT MET'}")  # fmt: skip
    figures["load_average_end"] = round(os.getloadavg()[0], 1)
    baseline_figures(args.baseline, __file__, figures)
    args.json.write_text(json.dumps(figures, indent=2))
    print(f"figures written to {args.json}")
    db.close()
    writer.close()
    store_module._INDEXES.clear()
    if args.workdir is None:
        shutil.rmtree(workdir)


if __name__ == "__main__":
    main()
