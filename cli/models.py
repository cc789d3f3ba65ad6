"""``geoloc models ...``: build the exported networks (needs the ``export`` extra, i.e. torch)."""

from __future__ import annotations

import time

import typer

from contracts.settings import models_dir
from geoloc.export.models import build_aliked_model, build_segmentation_model
from geoloc.vision.feature_types import canonical_method
from geoloc.vision.model_files import ALIKED_CONFIG_NAMES, parse_size, read_meta, segmentation_files, vocabulary_path
from workers.context import method_context, segmentation_size

app = typer.Typer(
    no_args_is_help=True, help="Build the exported models (ONNX networks, SBoW vocabularies) in the cache."
)


@app.command("build")
def build(
    force: bool = typer.Option(False, "--force", help="Re-export even if the cached ONNX is current."),
    size: str | None = typer.Option(
        None,
        "--size",
        help="Network input WxH, multiples of 16 (default: GEOLOC_SEGMENTATION_SIZE, else the runtime's size).",
    ),
    features: list[str] | None = typer.Option(
        None,
        "--features",
        help="Feature types to build an SBoW vocabulary for: rootsift, aliked-n16, aliked-t16 "
        "(repeatable; default: the default feature type).",
    ),
) -> None:
    """Export the networks to ONNX and build the SBoW vocabulary, into the cache.

    The segmentation network always, ALIKED when its features are asked for: everything the service
    needs at run time, so that nothing is built on a first request.
    """
    try:
        net_size = parse_size(size) if size else segmentation_size()
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--size or GEOLOC_SEGMENTATION_SIZE") from exc
    try:
        methods = sorted({canonical_method(m) for m in features}) if features else [canonical_method(None)]
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--features") from exc
    t0 = time.perf_counter()
    try:
        path = build_segmentation_model(force=force, size=net_size)
    except (FileNotFoundError, RuntimeError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    seconds = time.perf_counter() - t0
    meta = read_meta(segmentation_files(models_dir(), net_size)) or {}
    shape = meta.get("input", {}).get("shape")
    typer.echo(f"segmentation model  {path}")
    typer.echo(f"input shape         {shape}  (weights sha256 {str(meta.get('weights_sha256', '?'))[:12]}...)")
    typer.echo(f"took                {seconds:.1f} s" + ("" if force or seconds > 1 else " (already current)"))

    # ALIKED (measured, not the default: README "Local features") is exported only when asked for.
    for config_name in [name for name in ALIKED_CONFIG_NAMES if name in methods]:
        t0 = time.perf_counter()
        try:
            files = build_aliked_model(config_name, force=force)
        except (FileNotFoundError, RuntimeError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from exc
        typer.echo(f"{config_name + ' model':<20}{files.onnx}  ({time.perf_counter() - t0:.1f} s)")

    # The vocabulary build loads the feature extraction (OpenCV): only here, for CLI start-up time.
    from geoloc.export.vocabulary import build_default_vocabulary

    context = method_context()
    for method in methods:
        t0 = time.perf_counter()
        try:
            vocabulary = build_default_vocabulary(context, progress=True, method=method)
        except FileNotFoundError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from exc
        path = vocabulary_path(context.models_dir, len(vocabulary), method)
        typer.echo(f"sbow vocabulary     {path}  ({len(vocabulary)} words)")
        typer.echo(f"took                {time.perf_counter() - t0:.1f} s")
