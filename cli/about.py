"""``geoloc about``: the version and the licence table (the same as ``GET /v1/about`` and docs/licenses.md)."""

from __future__ import annotations

import json

import typer

from contracts.licenses import LICENSES, OSM_ATTRIBUTION, about_document, service_version


def about(as_json: bool = typer.Option(False, "--json", help="Print the JSON of GET /v1/about.")) -> None:
    """Print the version, the map data's default attribution and the licences of models, data and dependencies."""
    if as_json:
        typer.echo(json.dumps(about_document(), indent=2, ensure_ascii=False))
        return
    typer.echo(f"geoloc {service_version()}")
    typer.echo(f"map data: {OSM_ATTRIBUTION} (ODbL), unless a map states its own attribution")
    headings = {"model": "model weights", "dataset": "data sets", "map data": "map data", "dependency": "dependencies"}
    for kind, heading in headings.items():
        typer.echo(f"\n{heading}:")
        for entry in (e for e in LICENSES if e.kind == kind):
            typer.echo(f"  {entry.name}: {entry.license} ({entry.source})")
