"""``geoloc doctor [--repair] [--json]``: check the deployment's database, stored files and jobs after a crash.

The deployment is the one the settings name (``GEOLOC_DATA_DIR``, ``GEOLOC_DATABASE_URL``, ``GEOLOC_STORE_DIR``);
the checks and repairs are :mod:`db.doctor`'s, this module only prints. Exit code 0: nothing left to repair; 1:
problems found (or left: one that cannot be repaired, such as a damaged database); 2: the deployment cannot be
examined (a setting, no database, another schema).
"""

from __future__ import annotations

import json

import typer


def doctor(
    repair: bool = typer.Option(
        False, "--repair", help="Repair what is safe: orphaned files deleted, dead rows failed, stuck jobs requeued."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the report as JSON instead of lines."),
    grace_s: float = typer.Option(
        300.0,
        "--grace-s",
        min=0.0,
        help="Files younger than this (s) are not judged (an upload may be between file and row); 0 with the "
        "service stopped.",
    ),
) -> None:
    """Check the database's integrity, stored files against rows, and jobs nobody will finish; --repair fixes them.

    Exit code 0 when nothing is left to repair, 1 when problems were found (or remain), 2 when the deployment
    cannot be examined.
    """
    # lazy: keeps `geoloc --help` fast (pydantic, the database drivers)
    from contracts.settings import SettingsError, get_settings
    from db.doctor import DoctorError, examine_deployment

    try:
        settings = get_settings()
        report = examine_deployment(
            settings.database, settings.file_store_dir, repair=repair, grace_s=grace_s, lease_s=settings.job_lease_s
        )
    except (SettingsError, DoctorError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    if as_json:
        typer.echo(json.dumps(report.to_json(), indent=2))
    else:
        integrity = report.integrity or "not checked (PostgreSQL)"
        checked = report.checked
        typer.echo(
            f"{report.profile} profile: integrity {integrity}; {checked['stored_files']} stored files, "
            f"{checked['rows_with_files']} rows with files, {checked['running_jobs']} running jobs, "
            f"{checked['workers']} workers registered as running"
        )
        for finding in report.findings:
            outcome = f" -> repaired: {finding.repair}" if finding.repair else ""
            typer.echo(f"{finding.check}: {finding.subject}: {finding.problem}{outcome}")
        repaired = len(report.findings) - len(report.problems)
        if report.clean:
            typer.echo(f"clean ({repaired} repaired)" if repaired else "clean: nothing to repair")
        else:
            hint = "" if repair else " (geoloc doctor --repair repairs what is safe)"
            typer.echo(f"{len(report.problems)} problems, {repaired} repaired{hint}")
    if not report.clean:
        raise typer.Exit(1)
