"""``geoloc locate-track PHOTOS... --map ID``: a walk of photos located together by a running service.

The photos go in one ``POST /v1/maps/{id}/tracks`` in the order given (``--by-capture-time``: the service orders
them by their EXIF capture time), then the command waits for the answer (long polls) and prints one line per
frame: index, file, position, heading, 90 % radius, source, outlier. ``--json`` prints the track as the API
answers it, ``--geojson`` its GeoJSON form (the trajectory, a point and a view cone per frame).

Exit codes: 0 the track was located; 1 it failed (the reason on stderr) or the wait timed out; 2 the service
refused the request (a bad photo, too many frames, an unknown map, a bad key) or could not be reached.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from client import Client, GeolocClientError, Track, WaitTimeoutError


def _lines(track: Track) -> list[str]:
    """One line per frame of a located track."""
    out = [f"track {track.id} on map {track.map_id}: {track.status}, {len(track.frames)} frames"]
    for f in track.frames:
        where = "no pose" if f.lat is None or f.lon is None else f"{f.lat:.6f}, {f.lon:.6f}"
        heading = "" if f.heading_deg is None else f"  heading {f.heading_deg:6.1f} deg"
        radius = "" if f.uncertainty_radius_m is None else f"  ±{f.uncertainty_radius_m:.1f} m"
        flag = "  OUTLIER" if f.outlier else ""
        out.append(f"{f.index:3d}  {f.original_filename or ''}  {where}{heading}{radius}  {f.source or ''}{flag}")
    return out


def locate_track(
    photos: list[Path] = typer.Argument(..., exists=True, dir_okay=False, help="The photos, in frame order."),
    map_id: int = typer.Option(..., "--map", "-m", help="Id of the map to locate the track on."),
    url: str = typer.Option("http://127.0.0.1:8000", "--url", envvar="GEOLOC_URL", help="Base URL of the service."),
    api_key: str | None = typer.Option(
        None, "--key", "--api-key", envvar="GEOLOC_API_KEY", help="API key with the read scope (X-API-Key)."
    ),
    by_capture_time: bool = typer.Option(False, "--by-capture-time", help="Order the frames by EXIF capture time."),
    gps: bool = typer.Option(True, "--gps/--no-gps", help="Use each photo's EXIF GPS as its prior position."),
    as_json: bool = typer.Option(False, "--json", help="Print the track as the API answers it (JSON)."),
    as_geojson: bool = typer.Option(False, "--geojson", help="Print the track as GeoJSON."),
    timeout: float = typer.Option(600.0, "--timeout", min=1, help="Seconds to wait for the answer."),
) -> None:
    """Locate a walk of photos together on a map of a running service; print each frame's pose."""
    if as_json and as_geojson:
        typer.echo("error: give --json or --geojson, not both", err=True)
        raise typer.Exit(2)
    client = Client(url, api_key, timeout_s=120.0)
    try:
        try:
            track = client.upload_track(
                map_id, list(photos), by_capture_time=by_capture_time, use_exif_gps=gps, wait_s=min(timeout, 60.0)
            )
            track = client.wait_for_track(track.id, timeout_s=timeout)
        except WaitTimeoutError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from exc
        except GeolocClientError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from exc
        if as_geojson:
            typer.echo(json.dumps(client.get_track_geojson(track.id).model_dump(mode="json"), indent=2))
        elif as_json:
            typer.echo(json.dumps(track.model_dump(mode="json"), indent=2))
        else:
            typer.echo("\n".join(_lines(track)))
    finally:
        client.close()
    if track.status != "done":
        typer.echo(f"error: track {track.id} {track.status}: {track.error}", err=True)
        raise typer.Exit(1)
