"""The soak benchmark's samples and verdict (``benchmarks/bench_soak.py``), apart so the verdict is unit-tested.

:func:`sample` reads, at one moment, each service process's resident memory (``/proc/PID/status`` ``VmRSS``,
MB; beside it PSS and USS from ``/proc/PID/smaps_rollup``, reported, not judged) and open file descriptors
(``/proc/PID/fd``), the database size (the SQLite file with its ``-wal`` and ``-shm``, or PostgreSQL's
``pg_database_size``), the store size (bytes under the data folder, less the database files and the linked
models) and the queue depth (jobs ``queued``). :func:`verdict` turns a run's
samples and counts into the issue's checks; in the distributed profile, whose run restarts PostgreSQL and Redis,
:func:`unexcused_errors` says which errors no outage excuses.

Decisions: a process's *level* is the median of its samples in a window (a sixth of the mark, at least three
samples), so that one sample taken while a worker holds a query's images does not decide. A worker's samples say
whether it was running a job (``busy``: its row in the ``workers`` table names a current job); its level is taken
from its samples between jobs (those of the window, widened to at least :data:`MIN_IDLE_SAMPLES`) when the run
after the mark has twice that many, else from all: what a worker keeps is what a leak raises, while a job's arrays
come and go with it, and a machine busier at the end than at the mark (other work beside the soak) would shift the
median of all samples towards those taken mid-job. The level from all samples is reported beside it
(``rss_ratio_all``). Memory is *within 10 %* when the level of the run's last window is within 10 % of the level
just after the mark (the 10-minute mark of an hour's run, a sixth of a shorter one). The file descriptors *did not
grow* when the fewest open in the last window is no more than the most open in the window after the mark:
descriptors that leak never close, so they raise the floor, while the API's connections in flight come and go
above it (one more socket open at the end than at the mark is load, not a leak). A process that was not alive at
both ends (a worker restarted) fails its checks: a restart hides a leak. Only the samples taken while the load ran
count (not those of the drain and the retention check after it).

Outages (the distributed profile): an error is excused when it is a ``503`` whose request, from sending to its
answer, overlaps an outage window (from the server's stop to its being back) widened by :data:`OUTAGE_GRACE_S`
after its end; any other status (a ``500``, no answer at all) is not, nor is a ``503`` outside every window. A job
is *lost* unless it ended ``done``, or ``failed`` with a reason.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import statistics
from pathlib import Path
from typing import Any

RSS_TOLERANCE = 0.10
"""Resident memory may end at most this fraction above or below its level at the mark."""
DB_FILES = ("geoloc.sqlite3", "geoloc.sqlite3-wal", "geoloc.sqlite3-shm")


ROLLUP_FIELDS = {"Pss": "pss_mb", "Pss_Anon": "pss_anon_mb", "Pss_File": "pss_file_mb", "Private_Clean": "uss_mb",
                 "Private_Dirty": "uss_mb"}  # fmt: skip
"""``/proc/PID/smaps_rollup`` lines read into a sample (USS: the private pages, clean and dirty, summed)."""


def process_figures(pid: int) -> dict[str, float] | None:
    """``{"rss_mb", "fds"}`` of a live process and its ``smaps_rollup`` figures (:data:`ROLLUP_FIELDS`); None if gone.

    RSS counts every page the process maps, shared ones whole: a worker forked from the pool
    (``GEOLOC_WORKER_START=fork``) starts with the pool's pages in its RSS, and a page it frees and faults in again
    moves between shared and private without changing what the machine holds. PSS (a shared page split between its
    sharers) and USS (the pages only this process holds) say what it costs.
    """
    try:
        rss_kb = next(
            int(line.split()[1])
            for line in Path(f"/proc/{pid}/status").read_text().splitlines()
            if line.startswith("VmRSS:")
        )
        fds = len(os.listdir(f"/proc/{pid}/fd"))
        rollup = Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines()
    except (OSError, StopIteration):
        return None
    figures: dict[str, float] = {"rss_mb": round(rss_kb / 1024.0, 1), "fds": fds}
    for line in rollup:
        key, _, value = line.partition(":")
        if (name := ROLLUP_FIELDS.get(key)) is not None:
            figures[name] = round(figures.get(name, 0.0) + int(value.split()[0]) / 1024.0, 1)
    return figures


def store_bytes(data_dir: Path) -> int:
    """Bytes of the files under ``data_dir``: the stored maps and photos (not the database, not ``cache/``)."""
    total = 0
    for root, dirs, files in os.walk(data_dir):  # does not follow the models' symlink
        top = Path(root) == data_dir
        if top:
            dirs[:] = [d for d in dirs if d != "cache"]
        for name in files:
            if top and name in DB_FILES:
                continue
            with contextlib.suppress(OSError):
                total += (Path(root) / name).lstat().st_size
    return total


QUEUED_SQL = "SELECT count(*) FROM jobs WHERE status = 'queued'"
BUSY_SQL = "SELECT pid FROM workers WHERE stopped_at IS NULL AND current_job_id IS NOT NULL"
"""The worker processes running a job now (their pids)."""


def database_figures(data_dir: Path, database_url: str | None) -> tuple[int, int, set[int]] | None:
    """(database bytes, queued jobs, busy workers' pids) of the SQLite file in ``data_dir`` or of ``database_url``.

    The busy workers are those whose row names a current job. None while PostgreSQL cannot be reached (the
    distributed soak restarts it).
    """
    if database_url is not None:
        return _postgres_figures(database_url)
    size = sum((data_dir / name).stat().st_size for name in DB_FILES if (data_dir / name).exists())
    conn = sqlite3.connect(f"file:{data_dir / DB_FILES[0]}?mode=ro", uri=True, timeout=10)
    try:
        row = conn.execute(QUEUED_SQL).fetchone()
        busy = {int(pid) for (pid,) in conn.execute(BUSY_SQL).fetchall()}
    finally:
        conn.close()
    return size, int(row[0]), busy


def _postgres_figures(database_url: str) -> tuple[int, int, set[int]] | None:
    """(``pg_database_size``, queued jobs, busy workers' pids) of the distributed profile's database; None if away."""
    import psycopg  # only the distributed profile needs it

    try:
        with psycopg.connect(database_url, autocommit=True, connect_timeout=5) as conn:
            size = conn.execute("SELECT pg_database_size(current_database())").fetchone()
            queued = conn.execute(QUEUED_SQL).fetchone()
            busy = {int(pid) for (pid,) in conn.execute(BUSY_SQL).fetchall()}
    except psycopg.OperationalError:  # stopped or restarting: the sample has no database figures
        return None
    return int(size[0] if size else 0), int(queued[0] if queued else 0), busy


def sample(t_s: float, roles: dict[str, list[int]], data_dir: Path, database_url: str | None) -> dict[str, Any]:
    """One sample at ``t_s`` seconds into the run; ``roles``: ``{"api": [pid, ...], "worker": [...]}``.

    With the database away, ``db_bytes`` and ``queued`` are None and whether a worker is busy is unknown (None).
    """
    figures_now = database_figures(data_dir, database_url)
    db_bytes, queued, busy = figures_now if figures_now is not None else (None, None, None)
    processes = {}
    for role, pids in roles.items():
        for pid in pids:
            if (figures := process_figures(pid)) is not None:
                processes[f"{role} {pid}"] = {**figures, "busy": None if busy is None else pid in busy}
    return {"t_s": round(t_s, 1), "processes": processes, "db_bytes": db_bytes,
            "store_bytes": store_bytes(data_dir), "queued": queued}  # fmt: skip


def _window(samples: list[dict[str, Any]], start_s: float, width_s: float) -> list[dict[str, Any]]:
    """The samples in ``[start_s, start_s + width_s]``, at least the three from ``start_s`` on."""
    after = [s for s in samples if s["t_s"] >= start_s]
    inside = [s for s in after if s["t_s"] <= start_s + width_s]
    return inside if len(inside) >= 3 else after[:3]


MIN_IDLE_SAMPLES = 5
"""Samples between jobs that make a level (the window is widened until it holds them)."""


def _nearest(series: list[tuple[float, dict[str, Any]]], edge_s: float, *, first: bool) -> list[dict[str, Any]]:
    """The figures of ``series`` ((t_s, figures) in time order) up to ``edge_s`` (``first``) or from it on.

    Widened to the first or last :data:`MIN_IDLE_SAMPLES` when fewer.
    """
    inside = [p for t, p in series if (t <= edge_s if first else t >= edge_s)]
    if len(inside) >= MIN_IDLE_SAMPLES:
        return inside
    return [p for _, p in (series[:MIN_IDLE_SAMPLES] if first else series[-MIN_IDLE_SAMPLES:])]


def process_checks(samples: list[dict[str, Any]], mark_s: float) -> dict[str, dict[str, Any]]:
    """Per process: RSS level at the mark and at the end, their ratio, fds most open at both; ``ok`` flags."""
    width = max(mark_s / 6.0, 1e-9)
    end_start = samples[-1]["t_s"] - width if samples else 0.0
    at_mark, at_end = _window(samples, mark_s, width), [s for s in samples if s["t_s"] >= end_start]
    names = sorted({name for s in samples for name in s["processes"]})
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        early = [s["processes"][name] for s in at_mark if name in s["processes"]]
        late = [s["processes"][name] for s in at_end if name in s["processes"]]
        alive = bool(early) and bool(late) and name in samples[-1]["processes"]
        if not alive:
            out[name] = {"alive_throughout": False, "rss_ok": False, "fds_ok": False}
            continue
        level_all = statistics.median(p["rss_mb"] for p in early)
        final_all = statistics.median(p["rss_mb"] for p in late)
        idle = [
            (s["t_s"], s["processes"][name])
            for s in samples
            if s["t_s"] >= mark_s and name in s["processes"] and s["processes"][name].get("busy") is False
        ]
        idle_early = _nearest(idle, mark_s + width, first=True)
        idle_late = _nearest(idle, end_start, first=False)
        between_jobs = len(idle) >= 2 * MIN_IDLE_SAMPLES
        first, last = (idle_early, idle_late) if between_jobs else (early, late)
        level, final = _medians(first, last, "rss_mb") or (level_all, final_all)
        ratio = final / level if level else float("inf")
        fds_mark, fds_end = max(p["fds"] for p in early), min(p["fds"] for p in late)
        out[name] = {
            "alive_throughout": True,
            "rss_mark_mb": round(level, 1),
            "rss_end_mb": round(final, 1),
            "rss_max_mb": max(s["processes"][name]["rss_mb"] for s in samples if name in s["processes"]),
            "rss_ratio": round(ratio, 3),
            "rss_level_from": "between jobs" if between_jobs else "all samples",
            "rss_ratio_all": round(final_all / level_all if level_all else float("inf"), 3),
            "rss_ok": abs(ratio - 1.0) <= RSS_TOLERANCE,
            "fds_mark_max": fds_mark,
            "fds_end_min": fds_end,
            "fds_end_max": max(p["fds"] for p in late),
            "fds_ok": fds_end <= fds_mark,
        }
        for share in ("pss", "uss"):  # reported beside the RSS level, from the same samples; where sampled
            if (found := _medians(first, last, f"{share}_mb")) is not None:
                mark, end = found
                out[name] |= {f"{share}_mark_mb": round(mark, 1), f"{share}_end_mb": round(end, 1),
                              f"{share}_ratio": round(end / mark if mark else float("inf"), 3)}  # fmt: skip
    return out


def _medians(first: list[dict[str, Any]], last: list[dict[str, Any]], key: str) -> tuple[float, float] | None:
    """The median of ``key`` over the samples ``first`` and over ``last``; None where either has none of it."""
    at_first = [p[key] for p in first if key in p]
    at_last = [p[key] for p in last if key in p]
    return (statistics.median(at_first), statistics.median(at_last)) if at_first and at_last else None


def under_load(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The samples taken while the load ran (``t_s`` up to ``duration_s``), not while the queue drained after."""
    return [s for s in report["samples"] if s["t_s"] <= report.get("duration_s", float("inf"))]


OUTAGE_GRACE_S = 15.0
"""Seconds after an outage's end in which a ``503`` is still the outage's: an API process finds its pooled connections
to the restarted server dead as it next uses them, and a request that waited through the outage answers after it."""


def unexcused_errors(
    events: list[dict[str, Any]], outages: list[dict[str, Any]], grace_s: float = OUTAGE_GRACE_S
) -> list[dict[str, Any]]:
    """The error ``events`` that no outage excuses, in their order.

    events: ``{"t_s", "end_s", "status", ...}`` per failed request (sent and answered, seconds into the run; status
    0 when nothing answered); outages: ``{"start_s", "end_s", ...}`` per window. A ``503`` is excused when
    ``[t_s, end_s]`` overlaps some ``[start_s, end_s + grace_s]``; nothing else is.
    """

    def excused(event: dict[str, Any]) -> bool:
        return event["status"] == 503 and any(
            event["t_s"] <= window["end_s"] + grace_s and event["end_s"] >= window["start_s"] for window in outages
        )

    return [event for event in events if not excused(event)]


def lost_jobs(jobs: dict[str, Any]) -> int:
    """Accepted jobs that did not end ``done`` or ``failed`` with a reason (unfinished, cancelled, gone, no reason)."""
    ended = jobs["done"] + jobs["failed"] - jobs.get("failed_without_reason", 0)
    return int(jobs["accepted"] - ended)


def outage_checks(report: dict[str, Any]) -> list[tuple[str, bool]]:
    """The distributed profile's error and job checks (``outages``, ``error_events``, ``jobs``): (name, met)."""
    outages, events = report["outages"], report["error_events"]
    grace = report.get("outage_grace_s", OUTAGE_GRACE_S)
    kinds = sorted(window["server"] for window in outages)
    unavailable = [event for event in events if event["status"] == 503]
    unexcused = unexcused_errors(events, outages, grace)
    return [
        ("PostgreSQL and Redis each restarted once", kinds == ["postgres", "redis"]),
        (f"errors only 503s inside an outage (or {grace:.0f} s after it)", not unexcused),
        ("every 503 carries Retry-After", all(event.get("retry_after_s") for event in unavailable)),
        ("0 lost jobs (each accepted job done, or failed with a reason)",
         report["jobs"]["accepted"] > 0 and lost_jobs(report["jobs"]) == 0),
    ]  # fmt: skip


def verdict(report: dict[str, Any]) -> list[tuple[str, bool]]:
    """The issue's checks on a run's report (``samples``, ``mark_s``, ``errors``, ``jobs``): (name, met).

    A report with ``outages`` (the distributed profile) is judged by :func:`outage_checks` on errors and jobs, and
    must have sampled two API processes. The memory and fd checks look at the samples :func:`under_load` (an idle
    tail would hide a growth in fds).
    """
    processes = process_checks(under_load(report), report["mark_s"])
    jobs = report["jobs"]
    roles = [name.split()[0] for name in processes]
    if "outages" in report:
        checks = [*outage_checks(report), ("two API processes and a worker sampled",
                                           roles.count("api") >= 2 and "worker" in roles)]  # fmt: skip
    else:
        checks = [
            ("0 errors other than documented 429s", sum(report["errors"].values()) == 0),
            ("every accepted job done", jobs["accepted"] > 0 and jobs["done"] == jobs["accepted"]),
            ("an API and a worker process sampled", {"api", "worker"} <= set(roles)),
        ]
    if "retention" in report:  # queries left to retention are gone once older than it
        old, pruned = report["retention"]["older_than_retention"], report["retention"]["pruned"]
        checks.append(("retention pruned every query older than it", old > 0 and pruned == old))
    for name, figures in processes.items():
        checks.append((f"{name} resident memory within 10 % of its level at the mark", figures["rss_ok"]))
        checks.append((f"{name} open file descriptors did not grow", figures["fds_ok"]))
    return checks
