"""``geoloc map ...``: inspect map files."""

from __future__ import annotations

import json
from pathlib import Path

import typer

app = typer.Typer(
    no_args_is_help=True,
    help="Inspect map files (OSM XML/.bz2/.gz/.pbf, GeoJSON, GeoPackage, FlatGeobuf, zipped Shapefile).",
)


@app.command("info")
def info(
    path: Path,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of text."),
    layer: str | None = typer.Option(None, help="GIS layer to read (when the file has several polygon layers)."),
    name_attribute: str = typer.Option("name", help="Attribute with the building's name."),
    height_attribute: str = typer.Option("height", help="Attribute with the building's height (m)."),
    levels_attribute: str = typer.Option("building:levels", help="Attribute with the number of storeys."),
    crs: str | None = typer.Option(None, help="CRS of a GIS file's coordinates (e.g. EPSG:3857), overriding it."),
) -> None:
    """Load a map and print its buildings, facades, named buildings, bounding box and repair counts."""
    from geoloc.maps import MapLoadError, MapReadOptions, load_map, map_summary  # lazy: keeps `geoloc --help` fast

    options = MapReadOptions(layer, name_attribute, height_attribute, levels_attribute, crs)
    try:
        summary = map_summary(load_map(path, options))
    except MapLoadError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    bbox = summary["bbox_wgs84"]
    report = summary["report"]
    where = "".join(f", {k} {report[k]}" for k in ("layer", "crs") if report.get(k))
    typer.echo(f"map            {summary['source']} ({report['format']}{where})")
    typer.echo(f"buildings      {summary['buildings']}")
    typer.echo(f"facades        {summary['facades']}")
    typer.echo(f"named          {summary['named_buildings']} (e.g. {', '.join(summary['named_examples'][:5])})")
    typer.echo(f"trees          {summary['trees']}    street polylines {summary['streets']}")
    typer.echo(
        f"bbox (WGS84)   lat {bbox['min_lat']:.6f} .. {bbox['max_lat']:.6f}, "
        f"lon {bbox['min_lon']:.6f} .. {bbox['max_lon']:.6f}"
    )
    x0, y0, x1, y1 = summary["extent_m"]
    typer.echo(f"extent         {x1 - x0:.0f} m x {y1 - y0:.0f} m (local frame)")
    typer.echo(f"heights        {summary['height_sources']}")
    counts = ", ".join(f"{k}={v}" for k, v in report.items() if k not in ("format", "layer", "crs"))
    typer.echo("repairs        " + counts)
