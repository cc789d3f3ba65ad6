"""``geoloc sim ...``: render simulated worlds from OSM footprints."""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(no_args_is_help=True, help="Simulated street-view worlds with ground truth.")


def parse_centre(text: str) -> tuple[float, float]:
    """``"LAT,LON"`` (WGS84 degrees) to a tuple; BadParameter when it is not two numbers in range."""
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError as exc:
        raise typer.BadParameter(f"centre must look like 60.1700,24.9400 (lat,lon), got {text!r}") from exc
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise typer.BadParameter(f"centre out of range (lat -90..90, lon -180..180): {text!r}")
    return lat, lon


def _parse_size(size: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size.lower().split("x"))
    except ValueError as exc:
        raise typer.BadParameter(f"size must look like 640x480, got {size!r}") from exc
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise typer.BadParameter("width and height must be in 16..8192")
    return w, h


@app.command("world")
def world(
    map_path: Path = typer.Option(
        ..., "--map", exists=True, dir_okay=False, help="Map file (.osm, .osm.pbf, GeoJSON)."
    ),
    out: Path = typer.Option(..., "--out", file_okay=False, help="Output folder (created)."),
    references: int = typer.Option(60, "--references", min=1, help="Number of reference photos."),
    queries: int = typer.Option(30, "--queries", min=0, help="Number of query photos."),
    seed: int = typer.Option(1, "--seed", help="World seed (poses, looks, trees, cars, sky, noise)."),
    gps_noise_m: float = typer.Option(5.0, "--gps-noise-m", min=0.0, help="Std (m, per axis) of reference GPS noise."),
    query_gps_noise_m: float = typer.Option(
        20.0, "--query-gps-noise-m", help="Std (m, per axis) of query GPS noise; negative: no GPS in queries."
    ),
    size: str = typer.Option("640x480", "--size", help="Image size WIDTHxHEIGHT."),
    hfov: float = typer.Option(
        60.0,
        "--hfov",
        min=10.0,
        max=120.0,
        help="Horizontal field of view (deg), rounded to an integer 35 mm-equivalent focal length.",
    ),
    radius_m: float = typer.Option(220.0, "--radius-m", min=0.0, help="World disk radius (m); 0: whole map."),
    centre: str | None = typer.Option(
        None, "--centre", help="World disk centre LAT,LON (WGS84 degrees); default: the buildings' median."
    ),
    pitch_std_deg: float = typer.Option(1.0, "--pitch-std-deg", min=0.0, help="Camera pitch std (deg)."),
    roll_std_deg: float = typer.Option(0.3, "--roll-std-deg", min=0.0, help="Camera roll std (deg)."),
    query_tracks: int = typer.Option(
        0, "--query-tracks", min=0, help="Number of query tracks: walks of query photos 3-8 m apart (needs streets)."
    ),
    track_length: int = typer.Option(10, "--track-length", min=2, max=200, help="Frames per query track."),
    capture: str = typer.Option(
        "scattered",
        "--capture",
        help="How references are taken: 'scattered' (one by one along the streets) or 'walk' (on walks, a photo "
        "every 4-12 m, with a phone's correlated GPS, compass and capture time; needs OSM highways).",
    ),
) -> None:
    """Sample references along streets and queries elsewhere, and render them.

    Writes the photos, their ground truth, manifest.json and contact_sheet.jpg.
    """
    # lazy (CLI start-up time): the map reader and the simulator (pyproj, shapely, OpenCV, the compiled ray
    # caster) load only for this command, so that `geoloc --help` and the other commands start without them.
    from geoloc.maps import MapLoadError
    from geoloc.sim.walks import NoStreetsError  # lazy: as the line above
    from geoloc.sim.world import WorldOptions, generate_world  # lazy: as the line above

    width, height = _parse_size(size)
    if capture not in ("scattered", "walk"):
        raise typer.BadParameter(f"--capture must be 'scattered' or 'walk', got {capture!r}")
    centre_wgs84 = parse_centre(centre) if centre else None
    opts = WorldOptions(
        n_references=references, n_queries=queries, seed=seed, radius_m=radius_m, centre_wgs84=centre_wgs84,
        gps_noise_m=gps_noise_m, query_gps_noise_m=query_gps_noise_m,  # the GPS the photos carry
        width=width, height=height, hfov_deg=hfov, pitch_std_deg=pitch_std_deg, roll_std_deg=roll_std_deg,  # camera
        capture="walk" if capture == "walk" else "scattered",  # how people took the references
        query_tracks=query_tracks, track_length=track_length,  # walks of query photos
    )  # fmt: skip
    try:
        manifest = generate_world(map_path, out, opts, progress=lambda msg: typer.echo(msg, err=True))
    except (MapLoadError, NoStreetsError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    n_ref = sum(r["role"] == "reference" for r in manifest["images"])
    n_track = sum("track" in r for r in manifest["images"])
    n_query = len(manifest["images"]) - n_ref - n_track
    typer.echo(f"{out}: {n_ref} references, {n_query} queries" + (f", {n_track} track frames" if n_track else ""))
