"""A benchmark's figures beside a baseline commit's, in one run: the export, the side-by-side table, the checks.

:func:`export_commit` (from :mod:`geoloc.evaluation.suite.trees`, shared with the accuracy suite) writes
``git archive REF`` of this repository into a folder (the baseline's source; run
with the same Python environment). A service benchmark starts the baseline's service from that folder beside
this checkout's (``bench_service.py``, ``bench_ingest.py``). An in-process benchmark runs the baseline's own copy
of itself, its measuring code and its method, from that folder in a subprocess with ``PYTHONPATH`` set to it
(:func:`run_baseline`: the same arguments, so the same inputs, its JSON to a temporary file), after its own
measurement, and prints the two side by side (:func:`side_by_side`: every number both JSONs hold at the same
key, with the ratio current / baseline). The two run one after the other, not interleaved: the machine's load
average at each start is in the figures.

:class:`Check` is a must-hold check printed as a ``PASS``/``FAIL`` line and stored in the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from contracts.settings import REPO_ROOT, get_settings
from geoloc.evaluation.suite.trees import export_commit


def without_options(argv: list[str], *names: str) -> list[str]:
    """``argv`` without the options ``names``: ``--x=V``, or ``--x`` and the argument after it unless an option.

    (A flag's next argument is kept when it is an option; the benchmarks put their positional arguments first.)
    """
    out: list[str] = []
    skip = False
    for arg in argv:
        dropped_value = skip and not arg.startswith("--")
        skip = arg in names
        if not (dropped_value or skip or any(arg.startswith(name + "=") for name in names)):
            out.append(arg)
    return out


def unknown_options(argv: list[str], help_text: str) -> list[str]:
    """The options of ``argv`` (``--x`` or ``--x=V``) that a benchmark's ``--help`` text does not name."""
    names = {arg.split("=", 1)[0] for arg in argv if arg.startswith("--")}
    known = set(re.findall(r"--[A-Za-z0-9][-A-Za-z0-9_]*", help_text))
    return sorted(names - known)


def run_baseline(ref: str, script: Path, argv: list[str], workdir: Path | None = None) -> dict[str, Any]:
    """The baseline ``ref``'s copy of benchmark ``script`` run with ``argv`` (less ``--baseline``/``--json``).

    Runs ``python benchmarks/NAME.py ARGV --json TMP`` in the exported tree with ``PYTHONPATH`` the tree (its
    method and its measuring code) and returns ``{"commit", "figures"}``: the JSON it wrote. Raises SystemExit
    when the commit has no such benchmark or it fails.
    """
    with tempfile.TemporaryDirectory(prefix="bench-baseline-", dir=workdir) as tmp:
        tree = Path(tmp) / "src"
        commit = export_commit(ref, tree)
        relative = script.resolve().relative_to(REPO_ROOT)
        if not (tree / relative).exists():
            raise SystemExit(f"baseline {commit} has no {relative}: no baseline figures")
        out = Path(tmp) / "baseline.json"
        # This checkout's shared folder and data folder (its built models): their defaults lie beside the source.
        settings = get_settings()
        env = {**os.environ, "PYTHONPATH": str(tree), "GEOLOC_SHARED": str(settings.shared),
               "GEOLOC_DATA_DIR": str(settings.data_dir)}  # fmt: skip
        argv = without_options(argv, "--baseline", "--json")
        usage = subprocess.run(
            [sys.executable, str(relative), "--help"], cwd=tree, env=env, capture_output=True, text=True, check=True
        )
        if missing := unknown_options(argv, usage.stdout):
            print(f"baseline {commit}'s {relative} has no {', '.join(missing)}: run without them (its defaults)")
            argv = without_options(argv, *missing)
        command = [sys.executable, str(relative), *argv, "--json", str(out)]
        print(f"\nbaseline {commit}: {' '.join(command[1:])}", flush=True)
        done = subprocess.run(command, cwd=tree, env=env, check=False)
        if done.returncode not in (0, 1) or not out.exists():  # 1: a benchmark whose own target was missed
            raise SystemExit(f"baseline {commit}'s {relative} failed ({done.returncode})")
        return {"commit": commit, "figures": json.loads(out.read_text())}


MAX_LISTED_RECORDS = 8
"""A list of at most this many objects is compared item by item (a benchmark's runs: ``bench_ingest.py``'s four)."""


def numbers(tree: Any, prefix: str = "") -> Iterator[tuple[str, float]]:
    """Every number (not a bool) in a JSON tree, with its dotted key (a listed object's by its index).

    Lists of numbers and longer lists of objects are left out: per-query records (their count and order are
    the run's) and a figure's parts (a load average's three numbers) are not figures to compare.
    """
    if isinstance(tree, dict):
        for key, value in tree.items():
            yield from numbers(value, f"{prefix}.{key}" if prefix else str(key))
    elif isinstance(tree, list) and len(tree) <= MAX_LISTED_RECORDS and all(isinstance(v, dict) for v in tree):
        for index, value in enumerate(tree):
            yield from numbers(value, f"{prefix}.{index}")
    elif isinstance(tree, int | float) and not isinstance(tree, bool):
        yield prefix, float(tree)


def ratio(current: float, baseline: float) -> float | None:
    """The ratio current / baseline, rounded to 3 decimals; None when the baseline is 0."""
    return round(current / baseline, 3) if baseline else None


def side_by_side(current: dict[str, Any], baseline: dict[str, Any]) -> dict[str, dict[str, float | None]]:
    """Each number both figure trees hold at the same key: ``{key: {current, baseline, ratio}}`` (current's order)."""
    theirs = dict(numbers(baseline))
    return {
        key: {"current": value, "baseline": theirs[key], "ratio": ratio(value, theirs[key])}
        for key, value in numbers(current)
        if key in theirs
    }


def print_side_by_side(rows: dict[str, dict[str, float | None]], commit: str) -> None:
    """The table of :func:`side_by_side`."""
    width = max((len(key) for key in rows), default=10) + 2
    print(f"\n{'':{width}s}{'current':>14s}{'baseline ' + commit:>20s}{'ratio':>9s}")
    for key, row in rows.items():
        shown = "" if row["ratio"] is None else f"{row['ratio']:.3f}"
        print(f"{key:{width}s}{row['current']:>14,.4g}{row['baseline']:>20,.4g}{shown:>9s}")


def compare_with_baseline(ref: str, script: Path, argv: list[str], figures: dict[str, Any]) -> dict[str, Any]:
    """Run the baseline (:func:`run_baseline`), print the table; returns what goes to the JSON's ``baseline``."""
    baseline = run_baseline(ref, script, argv)
    rows = side_by_side(figures, baseline["figures"])
    print_side_by_side(rows, baseline["commit"])
    return {"commit": baseline["commit"], "side_by_side": rows, "figures": baseline["figures"]}


def add_baseline_option(parser: argparse.ArgumentParser) -> None:
    """The ``--baseline REF`` option of an in-process benchmark (:func:`baseline_figures`)."""
    parser.add_argument(
        "--baseline", metavar="REF", help="also run this benchmark from commit REF of this repository; side by side"
    )


def baseline_figures(ref: str | None, script: str, figures: dict[str, Any]) -> None:
    """With a ``ref``, run the baseline (this process's arguments) and add ``figures["baseline"]``; else nothing.

    script: the benchmark's ``__file__``.
    """
    if ref:
        figures["baseline"] = compare_with_baseline(ref, Path(script), sys.argv[1:], figures)


@dataclass(frozen=True)
class Check:
    """A must-hold check: ``value`` against ``limit`` (``at_most``: value <= limit, else value >= limit).

    A check whose value is None (its figure could not be measured, e.g. no baseline) fails.
    """

    name: str
    value: float | None
    limit: float
    at_most: bool

    @property
    def passed(self) -> bool:
        if self.value is None:
            return False
        return self.value <= self.limit if self.at_most else self.value >= self.limit

    def line(self) -> str:
        verdict = "PASS" if self.passed else "FAIL"
        return f"{verdict} {self.name}: {self.value} ({'<=' if self.at_most else '>='} {self.limit})"

    def as_json(self) -> dict[str, Any]:
        return {"value": self.value, "limit": self.limit, "at_most": self.at_most, "passed": self.passed}


MAX_CPU_PER_SEGMENTATION = 2.0
"""Issue 23: worker CPU per query at most this many times the segmentation network's own CPU per query."""
MAX_P50_OF_BASELINE = 0.6
"""Issue 23: current query p50 at most this share of the baseline's."""
MIN_REFERENCES_PER_CPU_S_OF_BASELINE = 1.5
"""Issue 23: references labelled per worker CPU-second at least this many times the baseline's."""


def service_checks(
    cpu_per_segmentation: float | None,
    p50_ms: tuple[float, float] | None,
    references_per_cpu_s: tuple[float, float] | None,
    different_answers: int | None,
) -> list[Check]:
    """Issue 23's must-hold checks of ``bench_service.py``; the pairs are (current, baseline), None without one.

    cpu_per_segmentation: worker CPU per query / the network's own CPU per query (medians); different_answers:
    the queries whose ranked locations are not exactly the baseline's.
    """
    return [
        Check("worker CPU per query / segmentation's", cpu_per_segmentation, MAX_CPU_PER_SEGMENTATION, True),
        Check("query p50 / baseline's", ratio(*p50_ms) if p50_ms else None, MAX_P50_OF_BASELINE, True),
        Check(
            "references per CPU-second / baseline's",
            ratio(*references_per_cpu_s) if references_per_cpu_s else None,
            MIN_REFERENCES_PER_CPU_S_OF_BASELINE,
            False,
        ),
        Check("queries answered differently from the baseline", different_answers, 0, True),
    ]
