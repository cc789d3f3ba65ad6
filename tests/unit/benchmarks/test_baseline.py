"""The benchmarks' baseline runs (``benchmarks/baseline.py``): the export, the side-by-side ratios, the checks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.baseline import (
    MAX_LISTED_RECORDS,
    REPO_ROOT,
    Check,
    export_commit,
    run_baseline,
    service_checks,
    side_by_side,
    unknown_options,
    without_options,
)


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=REPO_ROOT, capture_output=True, text=True, check=True).stdout.strip()


def test_the_export_of_head_is_this_repositorys_commit_and_runs_from_its_own_folder(tmp_path: Path) -> None:
    tree = tmp_path / "src"
    (tree / "stale").mkdir(parents=True)  # a folder left from an earlier run is emptied
    commit = export_commit("HEAD", tree)
    assert commit == git("rev-parse", "--short", "HEAD")
    assert not (tree / "stale").exists() and not (tmp_path / "src.tar").exists()
    tracked = git("ls-tree", "-r", "--name-only", "HEAD").split()
    assert sorted(str(p.relative_to(tree)) for p in tree.rglob("*") if p.is_file()) == sorted(tracked)
    code = "import contracts.settings, geoloc.core.geo; print(contracts.settings.__file__, geoloc.core.geo.__file__)"
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        env={"PYTHONPATH": str(tree)},
        capture_output=True,
        text=True,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    assert all(Path(path).is_relative_to(tree) for path in out.stdout.split()), out.stdout


def test_a_benchmark_the_commit_does_not_have_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="has no benchmarks/bench_not_there.py"):
        run_baseline("HEAD", REPO_ROOT / "benchmarks" / "bench_not_there.py", [], workdir=tmp_path)


def test_the_baseline_runs_with_the_arguments_less_its_own_and_the_json() -> None:
    argv = ["world", "--baseline", "7a88952", "--rounds", "1", "--json=x.json", "--json", "y.json", "--baseline=main"]
    assert without_options(argv, "--baseline", "--json") == ["world", "--rounds", "1"]
    flags = ["--skip-lund", "--rounds", "1", "--workers", "0", "--mask", "gt"]
    assert without_options(flags, "--skip-lund", "--workers") == ["--rounds", "1", "--mask", "gt"]


def test_the_options_a_baseline_does_not_know_are_found_in_its_help() -> None:
    usage = "usage: bench_sbow.py [-h] [--references REFERENCES] [--sql-queries SQL_QUERIES] [--json JSON]"
    argv = ["--references", "2000", "--sql-queries=2", "--workers", "0", "--work-dir=x"]
    assert unknown_options(argv, usage) == ["--work-dir", "--workers"]


def test_side_by_side_pairs_the_numbers_both_hold_with_their_ratio() -> None:
    current = {"a": {"ms": 50.0, "n": 3, "ok": True}, "only_here": 1.0, "load": [1.0, 2.0], "zero": 2.0, "name": "x"}
    baseline = {"a": {"ms": 100.0, "n": 3, "ok": True}, "load": [1.0, 2.0], "zero": 0, "name": "y", "only_there": 4}
    current["runs"] = [{"per_s": 0.3}, {"per_s": 0.8}]
    baseline["runs"] = [{"per_s": 0.2}]
    many = [{"ms": float(i)} for i in range(MAX_LISTED_RECORDS + 1)]
    current["queries"], baseline["queries"] = many, many
    assert side_by_side(current, baseline) == {
        "a.ms": {"current": 50.0, "baseline": 100.0, "ratio": 0.5},
        "a.n": {"current": 3.0, "baseline": 3.0, "ratio": 1.0},
        "zero": {"current": 2.0, "baseline": 0.0, "ratio": None},
        "runs.0.per_s": {"current": 0.3, "baseline": 0.2, "ratio": 1.5},
    }


def test_checks_pass_at_their_limits_and_fail_past_them_or_unmeasured() -> None:
    assert Check("x", 2.0, 2.0, at_most=True).passed and not Check("x", 2.01, 2.0, at_most=True).passed
    assert Check("x", 1.5, 1.5, at_most=False).passed and not Check("x", 1.49, 1.5, at_most=False).passed
    assert not Check("x", None, 1.0, at_most=True).passed
    assert Check("x", 2.5, 2.0, at_most=True).line() == "FAIL x: 2.5 (<= 2.0)"
    assert Check("x", 1.6, 1.5, at_most=False).as_json() == {
        "value": 1.6,
        "limit": 1.5,
        "at_most": False,
        "passed": True,
    }


def test_the_service_checks_of_issue_23() -> None:
    met = service_checks(1.9, (300.0, 600.0), (3.3, 2.0), 0)
    assert [check.passed for check in met] == [True, True, True, True]
    assert [check.value for check in met] == [1.9, 0.5, 1.65, 0]
    missed = service_checks(2.1, (400.0, 600.0), (2.9, 2.0), 1)
    assert [check.passed for check in missed] == [False, False, False, False]
    alone = service_checks(1.5, None, None, None)
    assert [check.passed for check in alone] == [True, False, False, False], "without a baseline they cannot pass"
