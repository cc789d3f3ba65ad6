"""The map-jobs benchmark's figures and verdict (``benchmarks/map_jobs_checks.py``) on synthetic records."""

from __future__ import annotations

from typing import Any

import pytest

from benchmarks.map_jobs_checks import percentiles, summarize, verdict

pytestmark = pytest.mark.slow  # the brief of issue 22 asks for it in the slow suite, beside the benchmark


def reads(ms: list[float], status: int = 200, every_s: float = 0.1) -> list[dict[str, Any]]:
    return [
        {"what": "map" if i % 2 else "maps", "t_s": i * every_s, "ms": v, "status": status} for i, v in enumerate(ms)
    ]


def queries(count: int, job_status: str = "done", start_s: float = 1.0) -> list[dict[str, Any]]:
    return [{"t_s": start_s + 3 * i, "ms": 2500.0, "status": 200, "job_status": job_status} for i in range(count)]


BOMBS = [{"index": 1, "status": 413, "code": "payload_too_large", "seconds": 1.2},
         {"index": 2, "status": 413, "code": "payload_too_large", "seconds": 1.9}]  # fmt: skip


def failed(summary: dict[str, Any]) -> list[str]:
    return [name for name, met in verdict(summary) if not met]


def test_fast_reads_answered_queries_and_refused_bombs_meet_every_must_hold() -> None:
    summary = summarize(reads([10.0] * 990 + [90.0] * 10), queries(5), BOMBS, usable_s=40.0)
    assert failed(summary) == []
    assert summary["reads"]["count"] == 400, "only the reads that started before the map was usable"
    assert summary["queries"]["answered"] == 5 and summary["queries"]["ms"]["p50"] == 2500.0
    assert set(summary["reads"]["by_kind"]) == {"map", "maps"}


def test_a_slow_tail_a_late_bomb_a_failed_query_or_an_unusable_map_each_fail_their_own_check() -> None:
    slow = summarize(reads([10.0] * 95 + [500.0] * 5), queries(3), BOMBS, usable_s=40.0)
    assert failed(slow) == ["read p99 <= 100 ms during the parse"]
    late = summarize(reads([10.0] * 100), queries(3), [BOMBS[0], {**BOMBS[1], "seconds": 5.5}], usable_s=40.0)
    assert failed(late) == ["each 413 within 5 s"]
    stored = summarize(reads([10.0] * 100), queries(3), [BOMBS[0], {**BOMBS[1], "status": 202}], usable_s=40.0)
    assert failed(stored) == ["two bombs, each 413"]
    broken = summarize(reads([10.0] * 100), queries(2) + queries(1, "failed", 20.0), BOMBS, usable_s=40.0)
    assert failed(broken) == ["every query posted during the parse answered"]
    assert failed(summarize(reads([10.0] * 100), [], BOMBS, usable_s=40.0)) == ["queries answered during the parse"]
    never = summarize(reads([10.0] * 100), queries(3), BOMBS, usable_s=None)
    assert failed(never) == ["the map became usable (status done)"] and never["reads"]["count"] == 100


def test_a_read_without_an_answer_is_an_error_and_no_reads_is_no_p99() -> None:
    dropped = summarize(reads([10.0] * 10) + reads([5.0], status=0), queries(1), BOMBS, usable_s=40.0)
    assert failed(dropped) == ["no read errors"] and dropped["reads"]["errors"] == 1
    assert percentiles([]) == {"p50": None, "p95": None, "p99": None, "max": None}
    assert "read p99 <= 100 ms during the parse" in failed(summarize([], queries(1), BOMBS, usable_s=1.0))
