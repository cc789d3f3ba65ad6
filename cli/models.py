"""``geoloc models ...``: build the exported networks (needs the ``export`` extra, i.e. torch)."""

from __future__ import annotations

import time

import typer

app = typer.Typer(no_args_is_help=True, help="Build the exported models (ONNX network, SBoW vocabulary) in the cache.")


@app.command("build")
def build(
    force: bool = typer.Option(False, "--force", help="Re-export even if the cached ONNX is current."),
    size: str | None = typer.Option(
        None, "--size", help="Network input WxH, multiples of 16 (default: the runtime's size)."
    ),
) -> None:
    """Export the ESPNetv2 segmentation network to ONNX and build the SBoW vocabulary, into the cache.

    Everything the service needs at run time, so that nothing is built on a first request.
    """
    from geoloc.models import build_segmentation_model, parse_size, read_meta, segmentation_files

    try:
        net_size = parse_size(size) if size else None
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--size") from exc
    t0 = time.perf_counter()
    try:
        path = build_segmentation_model(force=force, size=net_size)
    except (FileNotFoundError, RuntimeError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    seconds = time.perf_counter() - t0
    meta = read_meta(segmentation_files(net_size)) or {}
    shape = meta.get("input", {}).get("shape")
    typer.echo(f"segmentation model  {path}")
    typer.echo(f"input shape         {shape}  (weights sha256 {str(meta.get('weights_sha256', '?'))[:12]}...)")
    typer.echo(f"took                {seconds:.1f} s" + ("" if force or seconds > 1 else " (already current)"))

    from geoloc.retrieval import default_vocabulary, vocabulary_path

    t0 = time.perf_counter()
    try:
        vocabulary = default_vocabulary(progress=True)
    except FileNotFoundError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    typer.echo(f"sbow vocabulary     {vocabulary_path(len(vocabulary))}  ({len(vocabulary)} words)")
    typer.echo(f"took                {time.perf_counter() - t0:.1f} s")
