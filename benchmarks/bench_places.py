"""A named place as the query prior, against the photo's EXIF GPS, on a simulated world (docs/places.md).

Each query's place is its camera's nearest addressed building (``addr:street`` + ``addr:housenumber``),
resolved by :func:`geoloc.maps.places.resolve_place` from the address text alone, as the API does; both runs
go through the evaluation's query stage (:func:`geoloc.evaluation.queries.answer_run`) with the same labelled
references; a third run answers with the place's covering disc instead of its shape (the prior before
:meth:`PositionPrior.of_place`), for comparison. Run (minutes on 2 cores)::

    python -m benchmarks.bench_places /tmp/worlds/h1 --out /tmp/places_h1.json
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from geoloc.evaluation.ground_truth import shown_by_references
from geoloc.evaluation.queries import EvalRun, answer_run
from geoloc.evaluation.references import analyze, label_references
from geoloc.localize.grid import PositionPrior
from geoloc.localize.query import QueryConfig
from geoloc.localize.retrieval import default_vocabulary
from geoloc.maps import CityMap
from geoloc.maps.places import place_index, resolve_place
from geoloc.sim.world import load_world
from workers.context import method_context


def nearest_address(city: CityMap, x_m: float, y_m: float) -> tuple[str, float] | None:
    """The address text of the addressed building nearest (x_m, y_m) and its distance (m), if any."""
    addressed = [b for b in city.buildings if b.tags.get("addr:street") and b.tags.get("addr:housenumber")]
    if not addressed:
        return None
    point = shapely.Point(x_m, y_m)
    distances = shapely.distance(np.array([b.polygon for b in addressed], dtype=object), point)
    best = addressed[int(np.argmin(distances))]
    return f"{best.tags['addr:street']} {best.tags['addr:housenumber']}", float(np.min(distances))


def within(rows: list[dict[str, Any]], metres: float) -> float:
    """The share of queries answered within ``metres``."""
    return round(sum(r["error_m"] <= metres for r in rows) / len(rows), 3) if rows else math.nan


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Label the world's references once, answer its queries with the GPS prior and with the place prior."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("world", type=Path)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--max-queries", type=int)
    args = parser.parse_args(argv)
    context = method_context()
    world = load_world(args.world)
    city = world.load_map()
    vocabulary = default_vocabulary(context.models_dir)
    queries = world.queries[: args.max_queries] if args.max_queries else world.queries
    index = place_index(city)
    priors: dict[str, PositionPrior] = {}
    discs: dict[str, PositionPrior] = {}  # the place's covering disc, the prior before it followed the shape
    places: dict[str, dict[str, Any]] = {}
    for q in queries:
        found = nearest_address(city, q.pose.x_m, q.pose.y_m)
        if found is None:
            continue
        text, distance = found
        match = resolve_place(index, text)
        places[q.name] = {"address": text, "building_distance_m": round(distance, 1), "status": match.status}
        if match.place is not None:
            p = match.place
            prior = priors[q.name] = PositionPrior.of_place(p)  # as the workers build it (position_prior_for)
            discs[q.name] = PositionPrior.from_radius(p.x_m, p.y_m, p.radius_m)
            places[q.name] |= {
                "radius_m": p.radius_m,
                "camera_to_centre_m": round(math.hypot(p.x_m - q.pose.x_m, p.y_m - q.pose.y_m), 1),
                "camera_to_prior_m": round(float(prior.distances_m(np.array([q.pose.x_m, q.pose.y_m]))[0]), 1),
                "prior_radius_m": prior.radius_m,
            }
    say = print
    labelled = label_references(world, city, vocabulary, "model", say, context)
    labelled.queries = {q.name: analyze(q.path, None, context) for q in queries}
    shown = {q.name: shown_by_references(world, q.name, [r.name for r in world.references]) for q in queries}
    config = QueryConfig()
    out: dict[str, Any] = {"world": str(args.world), "queries": len(queries), "resolved": len(priors), "places": places}
    runs = (("ours/gps", "gps", {}), ("ours/place", "given", priors), ("ours/place_disc", "given", discs))
    for name, prior, given in runs:
        run = EvalRun(name, prior, "model", "transferred", config)
        summary = answer_run(world, city, labelled, vocabulary, run, queries, shown, say, context, given_priors=given)
        rows = summary["per_query"]
        out[name] = {
            "within_5m": within(rows, 5.0),
            "within_10m": within(rows, 10.0),
            "within_25m": within(rows, 25.0),
            "median_error_m": round(float(np.median([r["error_m"] for r in rows])), 2),
            "errors_m": {r["name"]: r["error_m"] for r in rows},
        }
    text = json.dumps(out, indent=1)
    if args.out:
        args.out.write_text(text)
    print(
        json.dumps(
            {k: v for k, v in out.items() if k not in ("places",)}
            | {k: {m: v for m, v in out[k].items() if m != "errors_m"} for k, _, _ in runs},
            indent=1,
        )
    )
    return out


if __name__ == "__main__":
    main()
