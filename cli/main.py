"""Root of the ``geoloc`` console script. Each command group lives in its own module."""

from __future__ import annotations

import typer

from cli import about as about_cmd
from cli import analyze as analyze_cmd
from cli import backup as backup_cmd
from cli import doctor as doctor_cmd
from cli import eval as eval_cmd
from cli import ingest as ingest_cmd
from cli import map as map_cmd
from cli import models as models_cmd
from cli import serve as serve_cmd
from cli import sim as sim_cmd
from cli import track as track_cmd

app = typer.Typer(no_args_is_help=True, help="Map-based visual geolocation: maps, simulation, analysis, service.")
app.add_typer(map_cmd.app, name="map")
app.add_typer(sim_cmd.app, name="sim")
app.add_typer(models_cmd.app, name="models")
app.add_typer(eval_cmd.app, name="eval")
serve_cmd.register(app)
backup_cmd.register(app)
app.command("analyze")(analyze_cmd.analyze)
app.command("ingest", context_settings=ingest_cmd.CONTEXT_SETTINGS)(ingest_cmd.ingest)
app.command("about")(about_cmd.about)
app.command("doctor")(doctor_cmd.doctor)
app.command("locate-track")(track_cmd.locate_track)


if __name__ == "__main__":  # `python -m cli.main`: what `geoloc eval suite --background` starts
    app()
