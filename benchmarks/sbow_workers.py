"""Worker processes holding one map's SBoW index side by side, for ``bench_sbow.py --workers N``: their memory.

Starts ``count`` processes at once, each one doing what a worker does before its first query's shortlist
(``workers.reference_store.DatabaseReferenceStore(..., shared_dir=...)``, as ``workers.handler_helpers`` builds
it: the machine's shared base segment when ``shared_dir`` is given, the process's own index otherwise), then
answering the same queries. Once all hold their index, each one's resident memory (``VmRSS``) and proportional
set size (``Pss`` of ``/proc/PID/smaps_rollup``: a shared page counts 1/n in each of the n processes mapping it,
so the processes' PSS add up to the memory they take together; RSS counts a shared page in every process) is
read. With ``start="fork"`` the processes are forked by one parent as the service's pool forks its workers
(``GEOLOC_WORKER_START=fork``: :func:`workers.pool.freeze_warmed` once, then :func:`workers.pool.fork_child`
per child, the pool's own functions), and the parent's memory counts in the sum. Each returns a
digest of its shortlists (ids and float scores), which must be the same in every process
and mode.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from local_service import status_mb

ANSWER = """
import hashlib, json, os, sys
from pathlib import Path
import numpy as np
from db import connect
from workers.reference_store import DatabaseReferenceStore
def answer():
    db_path, map_id, shared, queries = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
    store = DatabaseReferenceStore(connect(Path(db_path)), map_id, shared_dir=Path(shared) if shared else None)
    with np.load(queries) as npz:
        lists = [store.shortlist(npz[name], 10) for name in sorted(npz.files, key=int)]
    return json.dumps({"pid": os.getpid(), "digest": hashlib.sha256(json.dumps(lists).encode()).hexdigest()})
"""

CHILD = (
    ANSWER
    + """
print(answer(), flush=True)
sys.stdin.readline()
"""
)

POOL = (
    ANSWER
    + """
from workers.pool import fork_child, freeze_warmed
r, w = os.pipe()
def child(_):
    os.write(w, (answer() + "\\n").encode())  # one line < PIPE_BUF: written at once
    sys.stdin.readline()
    return 0
freeze_warmed()
pids = [fork_child(lambda i=i: child(i)) for i in range(int(sys.argv[5]))]
os.close(w)
with os.fdopen(r) as lines:
    for _ in pids:
        print(lines.readline().strip(), flush=True)
sys.stdin.readline()
for pid in pids:
    os.waitpid(pid, 0)
"""
)
"""The pool's way (``GEOLOC_WORKER_START=fork``): one parent warms and freezes its heap
(:func:`workers.pool.freeze_warmed`) and forks the children (:func:`workers.pool.fork_child`), as the service's
pool does; it prints each child's line."""


def shortlist_digest(lists: list[list[tuple[Any, float]]]) -> str:
    """The digest a child prints for its shortlists (ids and scores as JSON: float scores to the last bit)."""
    return hashlib.sha256(json.dumps(lists).encode()).hexdigest()


def pss_mb(pid: int) -> float:
    """``Pss`` of ``/proc/PID/smaps_rollup`` in MB (NaN if absent)."""
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        if line.startswith("Pss:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def run_workers(
    db_path: Path, map_id: int, queries: list[np.ndarray], count: int, shared_dir: Path | None, start: str = "spawn"
) -> dict[str, Any]:
    """``count`` worker-like processes together; their memory once all hold the index, and their digests.

    ``start``: ``spawn`` (separate processes, ``GEOLOC_WORKER_START=spawn``) or ``fork`` (children of one pool
    parent, as the service's :mod:`workers.pool`: the parent's memory is counted too).
    """
    queries_path = db_path.with_name("bench-queries.npz")
    np.savez(queries_path, **{str(i): q for i, q in enumerate(queries)})
    t0 = time.perf_counter()
    args = [str(db_path), str(map_id), str(shared_dir or ""), str(queries_path)]
    if start == "fork":
        launch = [[sys.executable, "-c", POOL, *args, str(count)]]
    else:
        launch = [[sys.executable, "-c", CHILD, *args] for _ in range(count)]
    processes = [subprocess.Popen(a, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) for a in launch]
    try:
        lines = []
        for process in processes:
            assert process.stdout is not None
            for _ in range(count if start == "fork" else 1):
                line = process.stdout.readline()
                if not line:
                    raise SystemExit(f"a worker process failed (exit {process.wait()})")
                lines.append(json.loads(line))
        ready_s = time.perf_counter() - t0
        pids = [line["pid"] for line in lines]
        rss = [status_mb(pid, "VmRSS") for pid in pids]
        pss = [pss_mb(pid) for pid in pids]
        parent = [pss_mb(processes[0].pid), status_mb(processes[0].pid, "VmRSS")] if start == "fork" else [0.0, 0.0]
    finally:
        for process in processes:
            if process.stdin is not None:
                process.stdin.close()
            process.wait()
    return {
        "processes": count,
        "start": start,
        "shared_base": shared_dir is not None,
        "all_ready_s": round(ready_s, 1),
        "rss_mb_each": [round(v, 1) for v in rss],
        "rss_mb_sum": round(sum(rss) + parent[1], 1),
        "pss_mb_each": [round(v, 1) for v in pss],
        "pss_mb_parent": round(parent[0], 1),
        "pss_mb_sum": round(sum(pss) + parent[0], 1),
        "digests": sorted({line["digest"] for line in lines}),
    }


def worker_memory(
    db_path: Path, map_id: int, queries: list[np.ndarray], count: int, shared_dir: Path
) -> dict[str, dict[str, Any]]:
    """One process and ``count`` processes: each with its own index, on the shared base, and forked by the pool.

    Keys ``own_N`` and ``shared_N`` (spawned), ``fork_N`` (the pool's way, on the shared base; its parent counted).
    """
    modes = {"own": (None, "spawn"), "shared": (shared_dir, "spawn"), "fork": (shared_dir, "fork")}
    runs = {
        f"{mode}_{n}": run_workers(db_path, map_id, queries, n, folder, start)
        for mode, (folder, start) in modes.items()
        for n in (1, count)
    }
    for name, run in runs.items():
        print(f"{name:9s}: {run['processes']} processes ready in {run['all_ready_s']} s; RSS together "
              f"{run['rss_mb_sum']:.0f} MB, PSS together {run['pss_mb_sum']:.0f} MB")  # fmt: skip
    return runs
