"""``geoloc eval suite``: the accuracy suite over a split's worlds (:mod:`geoloc.evaluation.suite`)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer


def suite(
    split: str = typer.Option(..., "--split", help="Which worlds: 'dev' (tune here) or 'test' (read pooled only)."),
    list_only: bool = typer.Option(False, "--list", help="List the split's worlds; render and evaluate nothing."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON on stdout (the list, or the whole report)."),
    out: Path | None = typer.Option(
        None, "--out", file_okay=False, help="Write SPLIT.json, SPLIT.md and the plots (SPLIT.*.png) here."
    ),
    baseline: str | None = typer.Option(
        None, "--baseline", help="Also evaluate this commit (git ref) on the same worlds; report paired differences."
    ),
    jobs: int = typer.Option(2, "--jobs", min=1, max=64, help="Worlds rendered or evaluated at once (processes)."),
    cache: Path | None = typer.Option(
        None, "--cache", file_okay=False, help="Rendered worlds and results (default GEOLOC_DATA_DIR/cache/suite)."
    ),
    fresh: bool = typer.Option(False, "--fresh", help="Evaluate every world again (rendered worlds are kept)."),
    worlds_toml: Path | None = typer.Option(
        None, "--worlds", exists=True, dir_okay=False, help="Another list of worlds (default: the suite's own TOML)."
    ),
    background: bool = typer.Option(
        False, "--background", help="Run detached (log in OUT/SPLIT.log); a later run resumes from the cache."
    ),
) -> None:
    """Render (once) and evaluate every world of a split with the workers' own stages; figures with 95 % intervals.

    Prints the pooled figures; --out writes the report (JSON, markdown tables, error-CDF and calibration plots).
    A run that stops resumes where it was: each world's outcomes are cached under the method's fingerprint.
    """
    # The suite loads the method (numpy, OpenCV, the simulator): imported per command, for CLI start-up time.
    from geoloc.evaluation.suite.run import SuiteError, run_suite  # lazy: CLI start-up
    from geoloc.evaluation.suite.worlds import SPLITS, WORLDS_TOML, load_suite  # lazy: as the line above

    if split not in SPLITS:
        raise typer.BadParameter(f"expected one of {', '.join(SPLITS)}, got {split!r}", param_hint="--split")
    toml = worlds_toml or WORLDS_TOML
    try:
        worlds = load_suite(toml).split(split)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    if list_only:
        _print_list([w.as_dict() for w in worlds], as_json)
        return
    if background:
        _detach(split, out)
        return
    try:
        with _progress_bars() as update:
            run = run_suite(
                split, cache=cache, jobs=jobs, fresh=fresh, baseline=baseline, progress=update, worlds_toml=toml
            )
    except SuiteError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from exc
    run.report["command"] = " ".join(["geoloc", *sys.argv[1:]])
    if as_json:
        typer.echo(json.dumps(run.report, indent=1))
    else:
        _print_pooled(run.report)
    if out:
        _write_reports(run.report, [o.outcomes for o in run.outcomes], out)


def _print_list(worlds: list[dict[str, Any]], as_json: bool) -> None:
    if as_json:
        typer.echo(json.dumps(worlds, indent=1))
        return
    for w in worlds:
        lat, lon = w["centre_wgs84"]
        typer.echo(
            f"{w['name']:34s} {w['map']:28s} {lat:.6f},{lon:.6f} seed {w['seed']:5d} {w['capture']:9s} {w['form']}"
        )


def _detach(split: str, out: Path | None) -> None:
    """Start this command again without --background, detached, its output in a log; print where."""
    # lazy: the settings (pydantic) only when a default log folder is needed
    from geoloc.evaluation.suite.run import default_cache

    folder = out or default_cache()
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / f"{split}.log"
    argv = [a for a in sys.argv[1:] if a != "--background"]
    with log.open("a") as sink:
        process = subprocess.Popen(  # noqa: S603 - our own command line, without --background
            [sys.executable, "-m", "cli.main", *argv], stdout=sink, stderr=subprocess.STDOUT, start_new_session=True
        )
    typer.echo(f"running in the background: pid {process.pid}, log {log}")


@contextmanager
def _progress_bars() -> Iterator[Callable[[str, int, int], None]]:
    """A bar per stage of the run (render, evaluate, baseline); the ``progress`` callback that moves them."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    console = Console(stderr=True)
    with Progress(TextColumn("{task.description:10s}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console) as progress:  # fmt: skip
        tasks: dict[str, Any] = {}

        def update(what: str, done: int, total: int) -> None:
            if what not in tasks:
                tasks[what] = progress.add_task(what, total=total)
            progress.update(tasks[what], completed=done, total=total)
            if not console.is_terminal and total:
                console.print(f"{what} {done}/{total}")

        yield update


def _print_pooled(report: dict[str, Any]) -> None:
    from geoloc.evaluation.suite.figures import FIGURES  # lazy: CLI start-up

    typer.echo(f"{report['split']} split: {len(report['worlds'])} worlds, method {report.get('commit')}")
    pooled = report["figures"]["pooled"]
    paired = report.get("paired", {}).get("pooled", {})
    for figure in FIGURES:
        value = pooled.get(figure.name)
        if not value or value["value"] is None:
            continue
        line = f"  {figure.label:48s} {value['value']:8.3f} [{value['low']:.3f}, {value['high']:.3f}]"
        if figure.name in paired and paired[figure.name]["value"] is not None:
            d = paired[figure.name]
            line += f"   vs baseline {d['value']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}]"
        typer.echo(line)
    typer.echo(f"seconds: {report['seconds']}")


def _write_reports(report: dict[str, Any], outcomes: list[dict[str, Any]], out: Path) -> None:
    from geoloc.evaluation.suite.report import markdown, write_plots  # lazy: CLI start-up

    out.mkdir(parents=True, exist_ok=True)
    split = report["split"]
    (out / f"{split}.json").write_text(json.dumps(report, indent=1) + "\n")
    (out / f"{split}.md").write_text(markdown(report))
    for path in [out / f"{split}.json", out / f"{split}.md", *write_plots(report, outcomes, out / split)]:
        typer.echo(f"wrote {path}")
