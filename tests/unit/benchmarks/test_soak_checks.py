"""The soak benchmark's verdict (``benchmarks/soak_checks.py``) on synthetic samples: growth flagged, flat passes.

The distributed profile's checks on synthetic outages: a 503 inside an outage window (or its grace) is excused,
anything else is not; a job that did not end done, or failed with a reason, is lost.
"""

from __future__ import annotations

from typing import Any

from benchmarks.soak_checks import lost_jobs, process_checks, unexcused_errors, verdict

MARK_S = 600.0


def samples(rss: dict[str, list[float]], fds: dict[str, list[int]], every_s: float = 30.0) -> list[dict[str, Any]]:
    """One sample per index of the series, ``every_s`` apart, for the processes named in ``rss``."""
    count = len(next(iter(rss.values())))
    return [
        {"t_s": i * every_s, "db_bytes": 0, "store_bytes": 0, "queued": 0,
         "processes": {name: {"rss_mb": rss[name][i], "fds": fds[name][i]} for name in rss if rss[name][i] > 0}}
        for i in range(count)
    ]  # fmt: skip


def report(series: list[dict[str, Any]], **changes: Any) -> dict[str, Any]:
    base = {"samples": series, "mark_s": MARK_S, "errors": {}, "jobs": {"accepted": 10, "done": 10},
            "retention": {"older_than_retention": 5, "pruned": 5}}  # fmt: skip
    return base | changes


def failed(checks: list[tuple[str, bool]]) -> list[str]:
    return [name for name, met in checks if not met]


FLAT = [300.0 + (i % 3) for i in range(121)]  # an hour at 30 s, wobbling by 2 MB
FDS = [20 + (i % 2) for i in range(121)]


def test_flat_memory_and_fds_pass() -> None:
    checks = verdict(report(samples({"api 1": FLAT, "worker 2": FLAT}, {"api 1": FDS, "worker 2": FDS})))
    assert failed(checks) == []
    names = [name for name, _ in checks]
    assert "worker 2 resident memory within 10 % of its level at the mark" in names
    assert "api 1 open file descriptors did not grow" in names


def test_a_steady_leak_is_flagged_and_a_warm_up_before_the_mark_is_not() -> None:
    warm_then_leak = [100.0 + 10 * i if i < 20 else 300.0 + 0.5 * (i - 20) for i in range(121)]  # +50 MB after
    checks = verdict(report(samples({"api 1": FLAT, "worker 2": warm_then_leak}, {"api 1": FDS, "worker 2": FDS})))
    assert failed(checks) == ["worker 2 resident memory within 10 % of its level at the mark"]
    figures = process_checks(samples({"w 2": warm_then_leak}, {"w 2": FDS}), MARK_S)["w 2"]
    assert figures["rss_ratio"] > 1.1
    warm_then_flat = [100.0 + 10 * i if i < 20 else 300.0 for i in range(121)]  # grows only before the mark
    assert failed(verdict(report(samples({"api 1": FLAT, "worker 2": warm_then_flat},
                                         {"api 1": FDS, "worker 2": FDS})))) == []  # fmt: skip


def test_one_peak_does_not_decide_but_shrinking_memory_is_flagged() -> None:
    peak = [*FLAT[:60], 900.0, *FLAT[61:]]
    assert failed(verdict(report(samples({"api 1": FLAT, "worker 2": peak}, {"api 1": FDS, "worker 2": FDS})))) == []
    shrinking = [300.0 - 1.0 * i for i in range(121)]
    assert "api 1 resident memory within 10 % of its level at the mark" in failed(
        verdict(report(samples({"api 1": shrinking, "worker 2": FLAT}, {"api 1": FDS, "worker 2": FDS})))
    )


def test_only_the_samples_under_load_are_judged() -> None:
    leak_then_idle = [*[20 + i // 10 for i in range(121)], *[15] * 20]  # fds grow, then drop once the load ends
    flat = [*FLAT, *FLAT[:20]]
    series = samples({"api 1": flat, "worker 2": flat}, {"api 1": leak_then_idle, "worker 2": [*FDS, *FDS[:20]]})
    assert failed(verdict(report(series, duration_s=3600.0))) == ["api 1 open file descriptors did not grow"]
    assert failed(verdict(report(series))) == []  # judged with the idle tail, the growth would hide


def test_growing_fds_a_restarted_worker_errors_and_unfinished_jobs_fail() -> None:
    leaking_fds = [20 + i // 10 for i in range(121)]
    checks = verdict(report(samples({"api 1": FLAT, "worker 2": FLAT}, {"api 1": leaking_fds, "worker 2": FDS})))
    assert failed(checks) == ["api 1 open file descriptors did not grow"]
    gone_at_half = [*FLAT[:60], *[0.0] * 61]  # worker 2 died; worker 3 took over
    late = [*[0.0] * 60, *FLAT[60:]]
    series = samples({"api 1": FLAT, "worker 2": gone_at_half, "worker 3": late},
                     {"api 1": FDS, "worker 2": FDS, "worker 3": FDS})  # fmt: skip
    assert {"worker 2 resident memory within 10 % of its level at the mark",
            "worker 3 open file descriptors did not grow"} <= set(failed(verdict(report(series))))  # fmt: skip
    flat = samples({"api 1": FLAT, "worker 2": FLAT}, {"api 1": FDS, "worker 2": FDS})
    assert failed(verdict(report(flat, errors={"GET /v1/maps 500 internal": 1}))) == [
        "0 errors other than documented 429s"
    ]
    assert failed(verdict(report(flat, jobs={"accepted": 10, "done": 9}))) == ["every accepted job done"]
    assert failed(verdict(report(flat, retention={"older_than_retention": 5, "pruned": 4}))) == [
        "retention pruned every query older than it"
    ]


def test_a_worker_level_is_taken_between_jobs_when_it_can_be() -> None:
    """Busier at the end (more samples mid-job) is not a leak; a growth between jobs is one, busy or not."""
    idle, job = 300.0, 420.0  # a worker between jobs, and while it holds a query's arrays
    busy_share = [0.2 if i < 60 else 0.7 for i in range(121)]  # a machine that got busier after the half hour
    busy = [(i * 37) % 100 < 100 * share for i, share in enumerate(busy_share)]
    series = samples({"api 1": FLAT, "worker 2": [job if b else idle for b in busy]}, {"api 1": FDS, "worker 2": FDS})
    for sample, is_busy in zip(series, busy, strict=True):
        sample["processes"]["worker 2"]["busy"] = is_busy
    figures = process_checks(series, MARK_S)["worker 2"]
    assert figures["rss_level_from"] == "between jobs" and figures["rss_ratio"] == 1.0
    assert figures["rss_ratio_all"] > 1.1  # the median of every sample moves with the share of busy ones
    assert failed(verdict(report(series))) == []
    for i, sample in enumerate(series):  # the same mix with the worker's own memory growing between jobs
        sample["processes"]["worker 2"]["rss_mb"] += 0.5 * i
    assert failed(verdict(report(series))) == ["worker 2 resident memory within 10 % of its level at the mark"]


def test_shared_and_private_memory_are_reported_beside_the_resident_size() -> None:
    """PSS and USS levels come from the same samples as RSS's; reports written before they were sampled have none."""
    series = samples({"worker 2": FLAT}, {"worker 2": FDS})
    for i, sample in enumerate(series):  # resident size flat, its private part growing: pages unshared over time
        sample["processes"]["worker 2"] |= {"pss_mb": 200.0 + 0.5 * i, "uss_mb": 100.0 + 1.0 * i}
    figures = process_checks(series, MARK_S)["worker 2"]
    assert abs(figures["rss_ratio"] - 1.0) < 0.01
    assert figures["uss_mark_mb"] < figures["uss_end_mb"] and figures["uss_ratio"] > 1.5
    assert 1.1 < figures["pss_ratio"] < figures["uss_ratio"]
    assert "uss_ratio" not in process_checks(samples({"worker 2": FLAT}, {"worker 2": FDS}), MARK_S)["worker 2"]


OUTAGES = [{"server": "postgres", "start_s": 1200.0, "down_s": 1201.0, "end_s": 1222.0},
           {"server": "redis", "start_s": 2400.0, "down_s": 2400.1, "end_s": 2420.5}]  # fmt: skip


def event(t_s: float, status: int = 503, took_s: float = 0.1, retry_after_s: float | None = 5.0) -> dict[str, Any]:
    """A failed request sent at ``t_s`` and answered ``took_s`` later."""
    return {"t_s": t_s, "end_s": t_s + took_s, "status": status, "key": f"GET /v1/maps {status}",
            "retry_after_s": retry_after_s}  # fmt: skip


def test_only_503s_overlapping_an_outage_or_its_grace_are_excused() -> None:
    inside = [event(1200.5), event(1221.9), event(2410.0, retry_after_s=None)]
    in_grace = [event(1236.9), event(2435.4)]  # up to 15 s after the end
    spanning = [event(1190.0, took_s=10.5), event(2300.0, took_s=200.0)]  # sent before, answered inside or after
    assert unexcused_errors([*inside, *in_grace, *spanning], OUTAGES) == []
    after_grace, before = event(1237.1), event(1190.0, took_s=9.9)
    server_error, unreachable, not_found = event(1210.0, 500), event(1210.0, 0), event(2410.0, 404)
    wrong = [after_grace, before, server_error, unreachable, not_found, event(30.0)]
    assert unexcused_errors([*inside, *wrong, *in_grace], OUTAGES) == wrong
    assert unexcused_errors(in_grace, OUTAGES, grace_s=5.0) == in_grace
    assert unexcused_errors(inside, []) == inside


def test_a_job_is_lost_unless_done_or_failed_with_a_reason() -> None:
    ended = {"accepted": 10, "done": 8, "failed": 2, "failed_without_reason": 0, "gone": 0, "unfinished": 0}
    assert lost_jobs(ended) == 0
    assert lost_jobs(ended | {"failed_without_reason": 1}) == 1
    assert lost_jobs(ended | {"done": 6, "unfinished": 1, "gone": 1}) == 2


def distributed(**changes: Any) -> dict[str, Any]:
    """A distributed run's report: two APIs, the Celery parent and a worker, flat; both restarts; 503s inside them."""
    names = ["api 1", "api 2", "pool 3", "worker 4"]
    base = report(samples({n: FLAT for n in names}, {n: FDS for n in names}),
                  outages=OUTAGES, outage_grace_s=15.0, errors={"GET /v1/maps 503 database_unavailable": 2},
                  error_events=[event(1205.0), event(1230.0)],
                  jobs={"accepted": 10, "done": 9, "failed": 1, "failed_without_reason": 0})  # fmt: skip
    return base | changes


def test_a_distributed_run_passes_with_503s_inside_its_outages_and_fails_without_them() -> None:
    assert failed(verdict(distributed())) == []
    errors_check = "errors only 503s inside an outage (or 15 s after it)"
    assert failed(verdict(distributed(error_events=[event(1205.0), event(1800.0)]))) == [errors_check]
    assert failed(verdict(distributed(error_events=[event(1205.0, 500)]))) == [errors_check]
    assert failed(verdict(distributed(error_events=[event(1205.0, retry_after_s=None)]))) == [
        "every 503 carries Retry-After"
    ]
    assert failed(verdict(distributed(outages=OUTAGES[:1]))) == ["PostgreSQL and Redis each restarted once"]
    lost = {"accepted": 10, "done": 9, "failed": 1, "failed_without_reason": 1}
    assert failed(verdict(distributed(jobs=lost))) == ["0 lost jobs (each accepted job done, or failed with a reason)"]
    one_api = samples({"api 1": FLAT, "worker 4": FLAT}, {"api 1": FDS, "worker 4": FDS})
    assert failed(verdict(distributed(samples=one_api))) == ["two API processes and a worker sampled"]
    assert "0 errors other than documented 429s" in failed(verdict(report(distributed()["samples"], errors={"x": 1})))


def test_samples_without_the_database_do_not_count_as_between_jobs() -> None:
    """While PostgreSQL is down whether a worker is busy is unknown (None): such samples make no between-jobs level."""
    idle, job = 300.0, 420.0
    series = samples({"worker 2": [job if i % 2 else idle for i in range(121)]}, {"worker 2": FDS})
    for i, sample in enumerate(series):
        sample["processes"]["worker 2"]["busy"] = None if i % 2 else False
    assert process_checks(series, MARK_S)["worker 2"]["rss_level_from"] == "between jobs"
    assert process_checks(series, MARK_S)["worker 2"]["rss_mark_mb"] == idle
    for sample in series:
        sample["processes"]["worker 2"]["busy"] = None
    assert process_checks(series, MARK_S)["worker 2"]["rss_level_from"] == "all samples"
