"""Evaluation of the whole method on a simulated world (``geoloc eval world DIR --json OUT``).

It runs exactly what the service runs: references are labelled with
:func:`geoloc.localize.reference.label_reference_photo` (EXIF GPS, compass and focal length read from the JPEG),
their walks placed jointly as the workers' sequence job does (:mod:`geoloc.localize.sequence`), and kept as
:class:`geoloc.localize.store.StoredReference`; queries go through :func:`geoloc.localize.query.geolocate` with one
:class:`geoloc.localize.query.QueryConfig`, recorded in the output. Only the reference store differs from the
service's (memory instead of the database; both rank with the same SBoW formula).

Runs (each query is answered once per run; :func:`default_runs`):

- ``ours/gps``: the service's default: the query's EXIF GPS as the position prior (radius
  :func:`contracts.queries.gps_prior_radius_m` of the accuracy the photo states) and its compass, when it has
  one, as the heading prior (as the API reads a photo), network segmentation, transferred identities;
- ``ours/none``: the same without any prior (neither position nor heading);
- ablation ladder under the GPS prior: ``gt_poses/gps`` (every reference at its true pose: the anchors'
  ceiling, the rest as the service does it), ``gt_identities/gps`` (perfect transfer: the query's identities
  from the renderer), ``gt_segmentation/gps`` (ground-truth labels for references and queries);
- the paper's method without the map anchors, no prior: ``paper_identity/none`` and
  ``paper_geometry/none`` (Fig. 7's two curves).

Reported per world: its capture kind (:func:`capture_kind`), reference labelling (Table I identity accuracy,
heading and position errors, with issue 19's reference-pose shares: position within 1 / 2 m, heading within
2 / 5 deg; per walk in a walk world), query
identity accuracy of the transfer for k = 1, 4, 8 with our and with ground-truth reference labels
(Table II), retrieval, the raw-GPS baseline, and per run: errors at N = 1 (all queries, queries whose
buildings some reference shows, per query kind), best of top N = 1..10 (Fig. 7), heading errors, how
often the uncertainty radius holds the truth, and a per-query table.

A world with query tracks (``geoloc sim world --query-tracks``) is also evaluated per track
(:mod:`geoloc.evaluation.tracks`: the track stage beside the same frames answered one by one); its track frames
are left out of the runs above (``--queries 0`` with tracks: no runs).

A query's buildings are "shown by some reference" when a reference shares at least 0.1 of the image in
building pixels with it (:func:`shown_by_references`; the share at the level of facades is reported too).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from geoloc.core.context import MethodContext
from geoloc.evaluation.ground_truth import SHOWN_MIN_SHARE, gps_baseline, shown_by_references
from geoloc.evaluation.photos import evaluate_photos
from geoloc.evaluation.queries import KS, EvalRun, answer_run, transfer_tables
from geoloc.evaluation.references import LabelledWorld, analyze, label_references, references_at_truth
from geoloc.evaluation.summaries import QUERY_KINDS, TOP_N
from geoloc.evaluation.tracks import PRIORS as TRACK_PRIORS
from geoloc.evaluation.tracks import evaluate_tracks
from geoloc.localize.query import QueryConfig
from geoloc.localize.retrieval import Vocabulary, default_vocabulary
from geoloc.sim.world import load_world

__all__ = [
    "KS",
    "QUERY_KINDS",
    "SHOWN_MIN_SHARE",
    "TOP_N",
    "EvalRun",
    "capture_kind",
    "default_runs",
    "evaluate_photos",
    "evaluate_world",
    "shown_by_references",
]


def capture_kind(manifest: dict[str, Any]) -> str:
    """How a world's references were captured: ``"walk"`` or ``"scattered"``.

    Walk worlds record ``options.capture`` in their manifest; scattered worlds made before walks existed (and
    those made since, which leave the default out so that their files stay byte-identical) do not, and read
    as ``"scattered"``.
    """
    return str(manifest.get("options", {}).get("capture", "scattered"))


def default_runs(config: QueryConfig) -> list[EvalRun]:
    """The runs of the module docstring."""
    paper = replace(config, use_anchors=False)
    return [
        EvalRun("ours/gps", "gps", "model", "transferred", config),
        EvalRun("ours/none", "none", "model", "transferred", config),
        EvalRun("gt_poses/gps", "gps", "model", "transferred", config, references="truth"),
        EvalRun("gt_identities/gps", "gps", "model", "gt", config),
        EvalRun("gt_segmentation/gps", "gps", "gt", "transferred", config),
        EvalRun("paper_identity/none", "none", "model", "transferred", paper),
        EvalRun("paper_geometry/none", "none", "model", "transferred", replace(paper, use_identity=False)),
    ]


def evaluate_world(
    world_dir: str | Path,
    *,
    config: QueryConfig | None = None,
    runs: list[EvalRun] | None = None,
    vocabulary: Vocabulary | None = None,
    max_queries: int | None = None,
    progress: Callable[[str], None] | None = None,
    context: MethodContext,
    track_outliers: bool = False,
    track_priors: tuple[str, ...] = TRACK_PRIORS,
) -> dict[str, Any]:
    """Run the method on a world folder and compare with its ground truth; returns a JSON-ready dict.

    context: the models and threads the method runs with (the figures do not depend on the thread counts).
    A world with query tracks also gets ``tracks`` (:func:`geoloc.evaluation.tracks.evaluate_tracks`, with
    ``track_outliers``: the outlier injection, and ``track_priors``: which priors to answer the tracks with); its
    track frames are not among the single queries.
    """
    say = progress or (lambda _msg: None)
    started = time.perf_counter()
    config = config or QueryConfig()
    runs = runs if runs is not None else default_runs(config)
    world = load_world(world_dir)
    city = world.load_map()
    vocabulary = vocabulary or default_vocabulary(context.models_dir)
    singles = [q for q in world.queries if "track" not in q.record]
    queries = singles[:max_queries] if max_queries else singles
    track_frames = [q for q in world.queries if "track" in q.record]
    reference_names = [r.name for r in world.references]
    shown = {q.name: shown_by_references(world, q.name, reference_names) for q in queries}

    worlds: dict[str, LabelledWorld] = {}
    segmentations = sorted({run.segmentation for run in runs}) or ["model"]
    for segmentation in segmentations:
        worlds[segmentation] = label_references(world, city, vocabulary, segmentation, say, context)
        worlds[segmentation].queries = {
            q.name: analyze(q.path, world.gt(q.name)["labels"] if segmentation == "gt" else None, context)
            for q in queries + track_frames
        }

    result: dict[str, Any] = {
        "world": str(world_dir),
        "capture": capture_kind(world.manifest),
        "map": world.manifest.get("map", {}).get("path") if hasattr(world, "manifest") else None,
        "references": len(world.references),
        "queries": len(queries),
        "query_kinds": {k: sum(q.record["kind"] == k for q in queries) for k in QUERY_KINDS},
        "shown_by_references": sum(bool(s["building"]) for s in shown.values()),
        "config": config.as_dict(),
        "reference_labelling": {seg: labelled.summary for seg, labelled in worlds.items()},
        "gps_baseline": gps_baseline(world, city, queries),
    }
    # Tables I/II with the network's labels when a run uses them (the service's case).
    table_segmentation = "model" if "model" in worlds else segmentations[0]
    result["tables_segmentation"] = table_segmentation
    result.update(transfer_tables(world, worlds[table_segmentation], vocabulary, config, queries, shown))
    result["runs"] = {}
    at_truth: dict[str, LabelledWorld] = {}
    for run in runs if queries else []:
        say(f"run {run.name}")
        labelled = worlds[run.segmentation]
        if run.references == "truth":
            if run.segmentation not in at_truth:
                store = references_at_truth(world, city, labelled, vocabulary)
                at_truth[run.segmentation] = replace(labelled, store=store)
            labelled = at_truth[run.segmentation]
        result["runs"][run.name] = answer_run(world, city, labelled, vocabulary, run, queries, shown, say, context)
    if track_frames:
        say("tracks")
        result["tracks"] = evaluate_tracks(
            world,
            city,
            worlds[table_segmentation],
            vocabulary,
            config,
            say,
            context,
            inject_outliers=track_outliers,
            priors=track_priors,
        )
    result["total_s"] = round(time.perf_counter() - started, 1)
    return result
