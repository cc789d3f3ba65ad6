"""Worker processes holding one map's SBoW index side by side, for ``bench_sbow.py --workers N``: their memory.

Starts ``count`` processes at once, each one doing what a worker does before its first query's shortlist
(``workers.reference_store.DatabaseReferenceStore(..., shared_dir=...)``, as ``workers.method_handlers`` builds
it: the machine's shared base segment when ``shared_dir`` is given, the process's own index otherwise), then
answering the same queries. Once all hold their index, each one's resident memory (``VmRSS``) and proportional
set size (``Pss`` of ``/proc/PID/smaps_rollup``: a shared page counts 1/n in each of the n processes mapping it,
so the processes' PSS add up to the memory they take together; RSS counts a shared page in every process) is
read. Each returns a digest of its shortlists (ids and float scores), which must be the same in every process
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

CHILD = """
import hashlib, json, sys
from pathlib import Path
import numpy as np
from db import connect
from workers.reference_store import DatabaseReferenceStore
db_path, map_id, shared, queries = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
store = DatabaseReferenceStore(connect(Path(db_path)), map_id, shared_dir=Path(shared) if shared else None)
with np.load(queries) as npz:
    lists = [store.shortlist(npz[name], 10) for name in sorted(npz.files, key=int)]
print(json.dumps({"digest": hashlib.sha256(json.dumps(lists).encode()).hexdigest()}), flush=True)
sys.stdin.readline()
"""


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
    db_path: Path, map_id: int, queries: list[np.ndarray], count: int, shared_dir: Path | None
) -> dict[str, Any]:
    """Start ``count`` worker-like processes together; their memory once all hold the index, and their digests."""
    queries_path = db_path.with_name("bench-queries.npz")
    np.savez(queries_path, **{str(i): q for i, q in enumerate(queries)})
    t0 = time.perf_counter()
    args = [str(db_path), str(map_id), str(shared_dir or ""), str(queries_path)]
    children = [
        subprocess.Popen([sys.executable, "-c", CHILD, *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        for _ in range(count)
    ]
    try:
        digests = []
        for child in children:
            assert child.stdout is not None
            line = child.stdout.readline()
            if not line:
                raise SystemExit(f"a worker process failed (exit {child.wait()})")
            digests.append(json.loads(line)["digest"])
        ready_s = time.perf_counter() - t0
        rss = [status_mb(child.pid, "VmRSS") for child in children]
        pss = [pss_mb(child.pid) for child in children]
    finally:
        for child in children:
            if child.stdin is not None:
                child.stdin.close()
            child.wait()
    return {
        "processes": count,
        "shared_base": shared_dir is not None,
        "all_ready_s": round(ready_s, 1),
        "rss_mb_each": [round(v, 1) for v in rss],
        "rss_mb_sum": round(sum(rss), 1),
        "pss_mb_each": [round(v, 1) for v in pss],
        "pss_mb_sum": round(sum(pss), 1),
        "digests": sorted(set(digests)),
    }


def worker_memory(
    db_path: Path, map_id: int, queries: list[np.ndarray], count: int, shared_dir: Path
) -> dict[str, dict[str, Any]]:
    """One process and ``count`` processes, each with its own index and on the shared base: memory and answers."""
    runs = {
        f"{mode}_{n}": run_workers(db_path, map_id, queries, n, shared_dir if mode == "shared" else None)
        for mode in ("own", "shared")
        for n in (1, count)
    }
    for name, run in runs.items():
        print(f"{name:9s}: {run['processes']} processes ready in {run['all_ready_s']} s; RSS together "
              f"{run['rss_mb_sum']:.0f} MB, PSS together {run['pss_mb_sum']:.0f} MB")  # fmt: skip
    return runs
