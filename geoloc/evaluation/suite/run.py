"""``geoloc eval suite``: every world of a split rendered (once), evaluated (once per method), and its figures.

:func:`run_suite` is the entry, from Python and the command line. For the split's worlds
(:func:`geoloc.evaluation.suite.worlds.load_suite`) it

1. renders the worlds not yet in the cache (``CACHE/worlds/KEY``, keyed by content), ``jobs`` at a time;
2. evaluates each world with this checkout's method, and with ``baseline``'s when given (``git archive`` of the
   commit into ``CACHE/trees/COMMIT``): ``outcomes.py`` in a subprocess whose ``PYTHONPATH`` is the tree, ``jobs``
   at a time, each with one job thread (the processes are the parallelism; the figures do not depend on thread
   counts). A world's outcomes are kept in ``CACHE/results/FINGERPRINT/KEY.json``: the fingerprint is the tree's
   runtime sources and built models (:func:`geoloc.evaluation.suite.trees.tree_fingerprint`), so a run that stopped
   resumes where it was, a second run of unchanged code reads its results, and ``fresh`` evaluates again;
3. computes every figure (:data:`geoloc.evaluation.suite.figures.FIGURES`) with its 95 % interval
   (:mod:`geoloc.evaluation.suite.bootstrap`) pooled, per capture kind, per urban form and, on the dev split
   only, per world (the test split is read as pooled figures), and with a baseline each figure's paired
   difference and its interval.

The cache's default is ``GEOLOC_DATA_DIR/cache/suite``; the shared maps are read through ``GEOLOC_SHARED``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from contracts.settings import REPO_ROOT, cache_dir, models_dir, shared_path
from geoloc.evaluation.suite.bootstrap import cluster_interval, paired_interval
from geoloc.evaluation.suite.figures import FIGURES, Figure, figure_table, values_table
from geoloc.evaluation.suite.outcomes import OUTCOMES_VERSION
from geoloc.evaluation.suite.trees import export_commit, resolve_commit, tree_fingerprint
from geoloc.evaluation.suite.worlds import (
    WORLDS_TOML,
    SuiteWorld,
    load_suite,
    rendered_world,
    simulator_digest,
    world_key,
)

__all__ = ["SuiteError", "SuiteRun", "WorldOutcomes", "default_cache", "run_suite", "suite_figures"]

Progress = Callable[[str, int, int], None]
"""progress(what, done, total): a stage's count so far (``render``, ``evaluate``, ``baseline``)."""


class SuiteError(RuntimeError):
    """A world that cannot be rendered or evaluated, or a baseline that cannot be exported; the message says which."""


@dataclass
class WorldOutcomes:
    """A world of the suite, its content key and one method's outcomes on it (``outcomes.py``)."""

    world: SuiteWorld
    key: str
    outcomes: dict[str, Any] = field(default_factory=dict)


@dataclass
class SuiteRun:
    """A split's run: the report (``worlds``, ``figures``, ``paired``, ``seconds``...) and this method's outcomes."""

    report: dict[str, Any]
    outcomes: list[WorldOutcomes]


def default_cache() -> Path:
    """``GEOLOC_DATA_DIR/cache/suite``."""
    return cache_dir() / "suite"


def _map_path(world: SuiteWorld) -> Path:
    path = shared_path("data", *world.map_file.split("/"))
    if not path.is_file():
        raise SuiteError(f"world {world.name}: map {world.map_file} is not under the shared data folder")
    return path


def _render(world: SuiteWorld, folder: Path) -> None:
    """Render one world into its cache folder (in a pool process)."""
    rendered_world(world, _map_path(world), folder)


def _render_all(worlds: list[SuiteWorld], cache: Path, jobs: int, progress: Progress) -> dict[str, Path]:
    """Each world's rendered folder (rendering those not in the cache ``jobs`` at a time), by world name."""
    generator = simulator_digest()
    folders = {w.name: cache / "worlds" / world_key(w, _map_path(w), generator) for w in worlds}
    missing = [w for w in worlds if not (folders[w.name] / "manifest.json").is_file()]
    done = 0
    progress("render", done, len(missing))
    if missing:
        (cache / "worlds").mkdir(parents=True, exist_ok=True)
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(_render, w, folders[w.name]): w for w in missing}
            for future, world in futures.items():
                try:
                    future.result()
                except Exception as exc:  # noqa: BLE001 - any failure of the simulator is the world's
                    raise SuiteError(f"world {world.name} could not be rendered: {exc}") from exc
                done += 1
                progress("render", done, len(missing))
    return folders


def _evaluate_one(tree: Path, runner: Path, world_dir: Path, out: Path, threads: int) -> None:
    """Run ``outcomes.py`` on one world with ``tree``'s method; its log beside ``out``; SuiteError on failure."""
    env = {**os.environ, "PYTHONPATH": str(tree), "GEOLOC_JOB_THREADS": str(threads)}
    env.update({name: str(threads) for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")})
    log = out.with_suffix(".log")
    with log.open("w") as sink:
        done = subprocess.run([sys.executable, str(runner), str(world_dir), str(out)], env=env, cwd=tree,
                              stdout=sink, stderr=subprocess.STDOUT, check=False)  # fmt: skip
    if done.returncode != 0:
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-15:])
        raise SuiteError(f"evaluating {world_dir.name} failed (exit {done.returncode}); log {log}:\n{tail}")


def _evaluate_all(
    tree: Path,
    worlds: list[SuiteWorld],
    folders: dict[str, Path],
    cache: Path,
    jobs: int,
    fresh: bool,
    progress: Progress,
    stage: str,
) -> list[WorldOutcomes]:
    """Each world's outcomes with ``tree``'s method, from the results cache or evaluated now ``jobs`` at a time."""
    runner_source = Path(__file__).with_name("outcomes.py")
    fingerprint = tree_fingerprint(tree, models_dir())
    results = cache / "results" / f"{fingerprint}-o{OUTCOMES_VERSION}"
    results.mkdir(parents=True, exist_ok=True)
    runner = results / "outcomes.py"  # run from a folder of its own: no module beside it shadows the tree's
    shutil.copyfile(runner_source, runner)
    paths = {w.name: results / f"{folders[w.name].name}.json" for w in worlds}
    todo = [w for w in worlds if fresh or not paths[w.name].is_file()]
    threads = 1 if jobs > 1 else 2
    done = 0
    progress(stage, done, len(todo))
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(_evaluate_one, tree, runner, folders[w.name], paths[w.name], threads) for w in todo]
        for future in futures:
            future.result()
            done += 1
            progress(stage, done, len(todo))
    return [WorldOutcomes(w, folders[w.name].name, json.loads(paths[w.name].read_text())) for w in worlds]


def _baseline_tree(ref: str, cache: Path) -> tuple[str, Path]:
    """The baseline commit's id and its exported tree under ``CACHE/trees`` (exported once)."""
    try:
        commit = resolve_commit(ref)
    except ValueError as exc:
        raise SuiteError(str(exc)) from exc
    tree = cache / "trees" / commit
    if not (tree / ".exported").is_file():
        export_commit(commit, tree)
        (tree / ".exported").write_text(commit + "\n")
    return commit, tree


def _groups(worlds: list[SuiteWorld], per_world: bool) -> dict[str, list[str]]:
    """Group name -> its worlds' names: ``pooled``, ``capture:K``, ``form:F`` and (``per_world``) ``world:NAME``."""
    groups = {"pooled": [w.name for w in worlds]}
    for attribute in ("capture", "form"):
        for value in sorted({getattr(w, attribute) for w in worlds}):
            groups[f"{attribute}:{value}"] = [w.name for w in worlds if getattr(w, attribute) == value]
    if per_world:
        groups.update({f"world:{w.name}": [w.name] for w in worlds})
    return groups


def _rows(result: WorldOutcomes, population: str) -> list[dict[str, Any]]:
    return list(result.outcomes.get(population, []))


def suite_figures(
    results: list[WorldOutcomes], per_world: bool, baseline: list[WorldOutcomes] | None = None
) -> dict[str, Any]:
    """Every figure with its interval per group (and, with ``baseline``, its paired difference per group)."""
    by_name = {r.world.name: r for r in results}
    base_by_name = {r.world.name: r for r in baseline} if baseline else {}
    figures: dict[str, dict[str, Any]] = {}
    paired: dict[str, dict[str, Any]] = {}
    for group, names in _groups([r.world for r in results], per_world).items():
        figures[group], paired[group] = {}, {}
        for figure in FIGURES:
            tables = [figure_table(figure, _rows(by_name[n], figure.population)) for n in names]
            if not any(len(t) for t in tables):
                continue
            figures[group][figure.name] = cluster_interval(tables, figure.statistic).as_dict()
            if baseline:
                current, before = _aligned(figure, [by_name[n] for n in names], [base_by_name[n] for n in names])
                paired[group][figure.name] = paired_interval(current, before, figure.statistic).as_dict()
    out: dict[str, Any] = {"figures": figures}
    if baseline:
        out["paired"] = paired
    return out


def _aligned(
    figure: Figure, current: list[WorldOutcomes], baseline: list[WorldOutcomes]
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per world, the figure's tables of the items both methods have and the figure keeps, in one order."""
    tables_now, tables_before = [], []
    for now, before in zip(current, baseline, strict=True):
        values_before = {row["name"]: figure.values(row) for row in _rows(before, figure.population)}
        pairs = [
            (value, value_before)
            for row in _rows(now, figure.population)
            if (value := figure.values(row)) is not None
            and (value_before := values_before.get(row["name"])) is not None
        ]
        tables_now.append(values_table([a for a, _ in pairs]))
        tables_before.append(values_table([b for _, b in pairs]))
    return tables_now, tables_before


def _worse_than_gps_worlds(results: list[WorldOutcomes]) -> list[str]:
    """The worlds whose queries' median error exceeds their raw GPS's median."""
    worse = []
    for result in results:
        rows = [r for r in result.outcomes.get("queries", []) if r.get("gps_error_m") is not None]
        if rows and np.median([r["error_m"] for r in rows]) > np.median([r["gps_error_m"] for r in rows]):
            worse.append(result.world.name)
    return worse


def run_suite(
    split: str,
    *,
    cache: Path | None = None,
    jobs: int = 2,
    fresh: bool = False,
    baseline: str | None = None,
    progress: Progress | None = None,
    worlds_toml: Path = WORLDS_TOML,
) -> SuiteRun:
    """Run the split (module docstring): its JSON-ready report and this method's outcomes per world."""
    say = progress or (lambda _what, _done, _total: None)
    started = time.perf_counter()
    cache = cache or default_cache()
    suite = load_suite(worlds_toml)
    worlds = suite.split(split)
    folders = _render_all(worlds, cache, jobs, say)
    rendered_s = time.perf_counter() - started
    results = _evaluate_all(REPO_ROOT, worlds, folders, cache, jobs, fresh, say, "evaluate")
    report: dict[str, Any] = {
        "suite_version": suite.version,
        "split": split,
        "commit": _describe(REPO_ROOT),
        "worlds": [{**r.world.as_dict(), "key": r.key, "evaluation_s": r.outcomes.get("seconds")} for r in results],
    }
    base_results = None
    if baseline:
        commit, tree = _baseline_tree(baseline, cache)
        base_results = _evaluate_all(tree, worlds, folders, cache, jobs, fresh, say, "baseline")
        report["baseline"] = {"ref": baseline, "commit": commit}
    report.update(suite_figures(results, per_world=split == "dev", baseline=base_results))
    report["worlds_median_worse_than_gps"] = _worse_than_gps_worlds(results)
    report["seconds"] = {"render": round(rendered_s, 1), "total": round(time.perf_counter() - started, 1)}
    return SuiteRun(report, results)


def _describe(tree: Path) -> str | None:
    """``git describe --always --dirty`` of the tree (None outside a git checkout)."""
    done = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=tree, capture_output=True, text=True,
                          check=False)  # fmt: skip
    return done.stdout.strip() or None
