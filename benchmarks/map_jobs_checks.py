"""The map-jobs benchmark's figures and verdict (``benchmarks/bench_map_jobs.py``), on what its clients recorded.

Issue 22's must-hold: while two gzip bombs are refused (each ``413`` within 5 s of its upload starting) and a
100 k-building map parses as a job, reads keep p99 <= 100 ms and queries keep being answered. Pure functions on
plain records, so that the verdict is tested on synthetic data (``tests/unit/benchmarks/test_map_jobs_checks.py``).

Records: a read is ``{"what": str, "t_s": float, "ms": float, "status": int}`` (``status`` 0: no answer, the
connection failed); a query is ``{"t_s": float, "ms": float, "status": int, "job_status": str}``; a bomb is
``{"status": int, "code": str, "seconds": float}``; ``t_s`` counts seconds from the moment the uploads started.
"""

from __future__ import annotations

from typing import Any

import numpy as np

BOMB_REFUSED_WITHIN_S = 5.0
READ_P99_MS = 100.0


def percentiles(values: list[float]) -> dict[str, float | None]:
    """p50, p95, p99 and max of ``values`` (ms), rounded to 0.1; ``None`` each when there are none."""
    if not values:
        return {"p50": None, "p95": None, "p99": None, "max": None}
    array = np.asarray(values, dtype=float)
    found = {f"p{q}": round(float(np.percentile(array, q)), 1) for q in (50, 95, 99)}
    return found | {"max": round(float(array.max()), 1)}


def during(records: list[dict[str, Any]], until_s: float) -> list[dict[str, Any]]:
    """The records that started before ``until_s`` (the parse's end): what ran while the map was parsed."""
    return [r for r in records if r["t_s"] < until_s]


def summarize(
    reads: list[dict[str, Any]], queries: list[dict[str, Any]], bombs: list[dict[str, Any]], usable_s: float | None
) -> dict[str, Any]:
    """The report's figures: reads and queries while the map parsed (all of them if it never became usable)."""
    until = usable_s if usable_s is not None else float("inf")
    reads_in, queries_in = during(reads, until), during(queries, until)
    answered = [q for q in queries_in if q["status"] == 200 and q["job_status"] == "done"]
    by_kind = sorted({r["what"] for r in reads_in})
    return {
        "bombs": bombs,
        "map_usable_s": usable_s,
        "reads": {
            "count": len(reads_in),
            "ms": percentiles([r["ms"] for r in reads_in]),
            "by_kind": {k: percentiles([r["ms"] for r in reads_in if r["what"] == k]) for k in by_kind},
            "errors": sum(r["status"] != 200 for r in reads_in),
        },
        "queries": {
            "posted": len(queries_in),
            "answered": len(answered),
            "ms": percentiles([q["ms"] for q in answered]),
            "errors": len(queries_in) - len(answered),
        },
    }


def verdict(summary: dict[str, Any]) -> list[tuple[str, bool]]:
    """Each must-hold of issue 22 (a name) and whether :func:`summarize`'s figures meet it."""
    bombs, reads, queries = summary["bombs"], summary["reads"], summary["queries"]
    p99 = reads["ms"]["p99"]
    return [
        ("two bombs, each 413", len(bombs) == 2 and all(b["status"] == 413 for b in bombs)),
        (f"each 413 within {BOMB_REFUSED_WITHIN_S:.0f} s", bool(bombs) and all(
            b["seconds"] <= BOMB_REFUSED_WITHIN_S for b in bombs)),
        ("the map became usable (status done)", summary["map_usable_s"] is not None),
        (f"read p99 <= {READ_P99_MS:.0f} ms during the parse", p99 is not None and p99 <= READ_P99_MS),
        ("no read errors", reads["errors"] == 0),
        ("queries answered during the parse", queries["answered"] > 0),
        ("every query posted during the parse answered", queries["errors"] == 0),
    ]  # fmt: skip
