"""``geoloc serve`` (API + workers) and ``geoloc worker`` (workers alone), both supervised.

The profile follows the settings: with ``GEOLOC_DATABASE_URL`` and ``GEOLOC_BROKER_URL`` the workers are
a Celery worker (:mod:`workers.celery_worker`) on that broker and database; without them they are the
built-in pool on the SQLite file in ``GEOLOC_DATA_DIR``. Both remove, at start, the metric files their machine's
dead processes left (:func:`workers.metrics.remove_dead_files`).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    from pathlib import Path

    from contracts.settings import Settings


def serve(
    host: str = typer.Option("127.0.0.1", help="Address to listen on (non-loopback needs GEOLOC_API_KEYS)."),
    port: int = typer.Option(8000, help="Port to listen on."),
    workers: int = typer.Option(2, "--workers", "-w", min=0, help="Worker processes to run beside the API."),
    log_level: str = typer.Option("info", help="Log level (debug, info, warning, error)."),
) -> None:
    """Start the REST API and N worker processes; restart any that die; stop all on Ctrl-C/SIGTERM."""
    from service.auth import is_loopback_host  # lazy: keeps `geoloc --help` fast (FastAPI)
    from workers.supervisor import Supervisor, api_spec  # lazy: keeps `geoloc --help` fast

    settings = _start(log_level)
    if not settings.auth_enabled and not is_loopback_host(host):
        typer.echo(
            f"error: refusing to listen on {host}: no API keys are configured. Set GEOLOC_API_KEYS "
            "(e.g. 'mykey:read+write') or use a loopback host such as 127.0.0.1.",
            err=True,
        )
        raise typer.Exit(2)
    if workers > 0 and _needs_models(settings):
        _require_models()
    _prepare_database(settings.database)
    typer.echo(
        f"geoloc: API on http://{host}:{port} with {workers} worker(s), {_profile(settings)}; data in "
        f"{settings.data_dir}",
        err=True,
    )
    specs = [api_spec(host, port, log_level), *_worker_specs(settings, workers, log_level)]
    raise typer.Exit(Supervisor(specs, stop_timeout_s=settings.worker_grace_s + 10).run())


def worker(
    concurrency: int = typer.Option(1, "--concurrency", "-c", min=1, help="Worker processes to run."),
    log_level: str = typer.Option("info", help="Log level (debug, info, warning, error)."),
) -> None:
    """Run worker processes alone (the API may run elsewhere).

    A Celery worker on GEOLOC_BROKER_URL and GEOLOC_DATABASE_URL in the distributed profile, else the
    built-in pool on the SQLite file in GEOLOC_DATA_DIR.
    """
    from workers.supervisor import Supervisor  # lazy: keeps `geoloc --help` fast

    settings = _start(log_level)
    if _needs_models(settings):
        _require_models()
    _prepare_database(settings.database)
    typer.echo(f"geoloc: {concurrency} worker(s), {_profile(settings)}", err=True)
    specs = _worker_specs(settings, concurrency, log_level)
    raise typer.Exit(Supervisor(specs, stop_timeout_s=settings.worker_grace_s + 10).run())


def _profile(settings: Settings) -> str:
    """The profile in words, for the start-up line (no password)."""
    if settings.distributed:
        return "distributed profile (PostgreSQL, Celery on Redis)"
    return f"embedded profile (SQLite at {settings.database_path})"


def _worker_specs(settings: Settings, count: int, log_level: str) -> list[Any]:
    """``count`` built-in workers, or one Celery worker with ``count`` processes (distributed).

    The built-in ones are one forking pool (:mod:`workers.pool`), or ``count`` processes with
    ``GEOLOC_WORKER_START=spawn``.
    """
    from workers.supervisor import celery_worker_spec, pool_spec, worker_spec  # lazy: keeps `geoloc --help` fast

    if count <= 0:
        return []
    if settings.distributed:
        return [celery_worker_spec(count, log_level)]
    if settings.worker_start == "fork":
        return [pool_spec(count, log_level)]
    return [worker_spec(i, log_level) for i in range(count)]


def _start(log_level: str) -> Settings:
    """Settings, logging, the metrics folder (exit 2 with the reason when a setting is invalid)."""
    # lazy: keeps `geoloc --help` fast (pydantic)
    from contracts.logs import configure_logging
    from contracts.settings import SettingsError, get_settings
    from workers.metrics import metrics_folder, remove_dead_files

    try:
        settings = get_settings()
    except SettingsError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    configure_logging(log_level, settings.log_format, "supervisor")
    if settings.metrics and metrics_folder(settings).is_dir():
        removed = remove_dead_files(metrics_folder(settings))
        logging.getLogger("geoloc.supervisor").info("metrics: %d files of stopped processes removed", removed)
    return settings


def _needs_models(settings: Settings) -> bool:
    """Whether the workers run the method's jobs (not when GEOLOC_WORKER_KINDS names only ``load_map``)."""
    from workers.context import needs_models  # lazy: keeps `geoloc --help` fast

    return needs_models(settings)


def _require_models() -> None:
    """Exit 2 listing what is missing or stale when the models the workers need are not built and current.

    Only where workers run: the API alone (``serve --workers 0``) never loads the models, so it starts
    without them and its ``/readyz`` says what is missing.
    """
    # Loads the method (numpy, OpenCV) only when workers start: CLI start-up time.
    from workers.context import model_problems

    problems = model_problems()
    if problems:
        typer.echo("error: the workers cannot run jobs:\n  " + "\n  ".join(problems), err=True)
        raise typer.Exit(2)


def _prepare_database(target: Path | str) -> None:
    """Apply migrations once before the children start (they re-check, idempotently).

    Exits with code 2 when the database cannot be reached.
    """
    from db import connect, migrate  # lazy: keeps `geoloc --help` fast

    try:
        db = connect(target)
    except Exception as exc:
        typer.echo(f"error: cannot open the database: {exc}", err=True)
        raise typer.Exit(2) from exc
    try:
        migrate(db)
    finally:
        db.close()


def register(app: typer.Typer) -> None:
    """Add ``serve`` and ``worker`` to the root command."""
    app.command("serve")(serve)
    app.command("worker")(worker)
