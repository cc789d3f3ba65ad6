"""``geoloc backup DEST`` and ``geoloc restore SRC``: the deployment's database and stored files, while it runs.

The deployment is the one the settings name (``GEOLOC_DATA_DIR``, ``GEOLOC_DATABASE_URL``, ``GEOLOC_STORE_DIR``);
what a backup holds and what a restore checks: :mod:`db.backup`, :mod:`db.restore`,
[operations.md](../docs/operations.md#backup-and-restore).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

if TYPE_CHECKING:
    from db.backup import Deployment


def _deployment() -> Deployment:
    """The settings' data folder, database and file store (exit 2 with the reason when a setting is invalid)."""
    from contracts.settings import SettingsError, get_settings  # lazy: keeps `geoloc --help` fast (pydantic)
    from db.backup import Deployment  # lazy: keeps `geoloc --help` fast

    try:
        settings = get_settings()
    except SettingsError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    return Deployment(settings.data_dir, settings.database, settings.file_store_dir)


def backup(
    dest: Path = typer.Argument(..., help="New folder (absent or empty) to write the backup into."),
) -> None:
    """Back up the database, stored maps and photos, and the data folder's other files (not caches), live."""
    from db.backup import BackupError, create_backup  # lazy: keeps `geoloc --help` fast

    try:
        report = create_backup(_deployment(), dest)
    except BackupError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    manifest = report.manifest
    total = sum(int(entry["size"]) for entry in manifest["files"])
    typer.echo(
        f"backup of the {manifest['profile']} profile, schema {manifest['schema_version']}: "
        f"{len(manifest['files'])} files, {total / 1e6:.1f} MB in {dest}"
    )
    for key in report.missing_files:
        typer.echo(f"warning: {key} was deleted while the backup ran; its row is in the backup without it", err=True)


def restore(
    src: Path = typer.Argument(..., help="Backup folder written by `geoloc backup`."),
    force: bool = typer.Option(False, "--force", help="Replace what the target data folder and database hold."),
) -> None:
    """Restore a backup into the settings' data folder, database and store (stop the service first).

    Every checksum is verified before anything is written; a target that holds data is refused unless --force.
    """
    from db.backup import BackupError  # lazy: keeps `geoloc --help` fast
    from db.restore import restore_backup  # lazy: keeps `geoloc --help` fast

    try:
        manifest = restore_backup(_deployment(), src, force=force)
    except BackupError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    typer.echo(
        f"restored {len(manifest['files'])} files of a backup made {manifest['created_at']} "
        f"(schema {manifest['schema_version']}; the service migrates it forward when it starts)"
    )


def register(app: typer.Typer) -> None:
    """Add ``backup`` and ``restore`` to the root command."""
    app.command("backup")(backup)
    app.command("restore")(restore)
