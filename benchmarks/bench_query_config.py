"""Query-stage configurations side by side on simulated worlds: what doing less costs in accuracy.

    .venv/bin/python benchmarks/bench_query_config.py --world /tmp/worlds/h1 --world /tmp/worlds/hw1 \
        --config pnp1000=pnp_max_iters:1000 --config anchors3=anchor_references:3 --json query_config.json

Each world's references are labelled once with the workers' labelling (the evaluation's
:func:`geoloc.evaluation.references.label_references`) and its queries analysed once; then every query is
answered by the workers' query stage (:func:`geoloc.localize.query.geolocate`, through the evaluation's
:func:`geoloc.evaluation.queries.answer_run`, as ``geoloc eval world`` does) under each configuration, with its
EXIF GPS prior (and compass) and with no prior. The first configuration is the default ``QueryConfig()``
(``balanced``); each ``--config NAME=FIELD:VALUE,...`` replaces fields of it. Printed per world, configuration
and prior: the shares within 1 / 5 / 10 m and of headings within 5 deg, the median error, how often the
uncertainty radius holds the truth, the anchored share, and the process CPU of the run (``time.process_time``
around it: every thread of the stage) as a ratio to the default's on the same queries; then how many rank-1
answers moved by more than 0.5 m against the default. Accuracy does not depend on the load; the CPU ratios do
when other jobs run.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

from config_args import comparison_arguments, parse_config

from geoloc.evaluation.ground_truth import shown_by_references
from geoloc.evaluation.queries import EvalRun, answer_run
from geoloc.evaluation.references import analyze, label_references
from geoloc.localize.query import QueryConfig
from geoloc.localize.retrieval import default_vocabulary
from geoloc.sim.world import load_world
from workers.context import method_context

PRIORS = ("gps", "none")
MOVED_M = 0.5


def answer_world(world_dir: Path, configs: dict[str, QueryConfig], say: Any) -> dict[str, Any]:
    """Every query of the world under every configuration and prior (:func:`answer_run`, as ``geoloc eval world``).

    Each run's summary is the evaluation's (:func:`geoloc.evaluation.summaries.run_summary`, per-query rows in
    ``per_query``), with ``cpu_s``: this process's CPU time around the run (every thread of the stage).
    """
    context = method_context()
    world = load_world(world_dir)
    city = world.load_map()
    vocabulary = default_vocabulary(context.models_dir)
    started = time.perf_counter()
    labelled = label_references(world, city, vocabulary, "model", lambda _msg: None, context)
    queries = [q for q in world.queries if "track" not in q.record]
    labelled.queries = {q.name: analyze(q.path, None, context) for q in queries}
    reference_names = [r.name for r in world.references]
    shown = {q.name: shown_by_references(world, q.name, reference_names) for q in queries}
    say(f"{world_dir}: {len(labelled.labelled)} references labelled, {len(queries)} queries analysed "
        f"in {time.perf_counter() - started:.0f} s")  # fmt: skip
    out: dict[str, Any] = {}
    for name, config in configs.items():
        for prior_kind in PRIORS:
            run = EvalRun(f"{name}/{prior_kind}", prior_kind, "model", "transferred", config)
            cpu0 = time.process_time()
            summary = answer_run(world, city, labelled, vocabulary, run, queries, shown, lambda _msg: None, context)
            summary["cpu_s"] = time.process_time() - cpu0
            out.setdefault(name, {})[prior_kind] = summary
    return out


def main() -> int:
    """Answer the worlds under each configuration; print the comparison and write the JSON."""
    args = comparison_arguments(__doc__.split("\n")[0], "query_config.json")
    configs = {"default": QueryConfig(), **dict(parse_config(text, QueryConfig()) for text in args.config)}
    results: dict[str, Any] = {"configs": {n: c.as_dict() for n, c in configs.items()}, "worlds": {}}
    for world_dir in args.world:
        answers = answer_world(world_dir, configs, lambda msg: print(msg, flush=True))
        results["worlds"][str(world_dir)] = answers
        for prior_kind in PRIORS:
            default = answers["default"][prior_kind]
            default_error = {r["name"]: r["error_m"] for r in default["per_query"]}
            for name in configs:
                run = answers[name][prior_kind]
                s = run["all"]
                moved = sum(abs(r["error_m"] - default_error[r["name"]]) > MOVED_M for r in run["per_query"])
                print(f"{world_dir.name:>8} {prior_kind:4} {name:>12}: within 1/5/10 m "
                      f"{s['within_1m']:.2f}/{s['within_5m']:.2f}/{s['within_10m']:.2f}, median "
                      f"{s['median_error_m']:.1f} m, heading 5 deg {s['heading_within_5deg']:.2f}, radius "
                      f"{run['uncertainty_radius_holds_truth']:.2f}, anchored {run['anchored_share']:.2f}, CPU "
                      f"x{run['cpu_s'] / default['cpu_s']:.2f}, moved > {MOVED_M} m: {moved}",
                      flush=True)  # fmt: skip
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
