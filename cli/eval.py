"""``geoloc eval ...``: measure stages on real data (CamVid segmentation)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import typer

from cli.eval_suite import suite

app = typer.Typer(
    no_args_is_help=True, help="Measure the method: segmentation on CamVid, the whole method on a simulated world."
)

IGNORE = 255
# CamVid 11-class index (0 Sky .. 10 Bicyclist, 11 Unlabelled) -> our class code; 11 -> IGNORE.
# Pole, SignSymbol, Fence, Pedestrian and Bicyclist are "other" (0).
CAMVID_TO_OURS = (4, 1, 0, 3, 3, 2, 0, 0, 5, 0, 0, IGNORE)
REPORTED = ("building", "tree", "road", "sky", "car")


def confusion_matrix(truth: Any, pred: Any, n: int) -> Any:
    """(n, n) int64 counts [true, predicted] over pixels whose truth is < n (others ignored)."""
    import numpy as np

    keep = truth < n
    idx = truth[keep].astype(np.int64) * n + pred[keep].astype(np.int64)
    return np.bincount(idx, minlength=n * n).reshape(n, n)


def scores(conf: Any) -> dict[str, Any]:
    """Per-class pixel accuracy (recall) and IoU plus overall pixel accuracy from a confusion matrix."""
    import numpy as np

    from geoloc.core.labels import CLASS_NAMES  # the method loads numpy and OpenCV: for CLI start-up time

    tp = np.diag(conf).astype(float)
    truth, pred = conf.sum(axis=1), conf.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        recall = tp / truth
        iou = tp / (truth + pred - tp)
    per_class = {
        name: {
            "accuracy": None if np.isnan(recall[i]) else round(float(recall[i]), 4),
            "iou": None if np.isnan(iou[i]) else round(float(iou[i]), 4),
            "pixels": int(truth[i]),
        }
        for i, name in enumerate(CLASS_NAMES)
    }
    return {"per_class": per_class, "pixel_accuracy": round(float(tp.sum() / max(conf.sum(), 1)), 4)}


def camvid_images(split: str, stride: int = 1) -> list[Path]:
    """Every ``stride``-th CamVid image of ``split`` (train, val, test), sorted by name (PNG or JPEG)."""
    from contracts import settings as config  # lazy: CLI start-up

    folder = config.shared_path("data", "camvid", split) / "images"
    return sorted([*folder.glob("*.png"), *folder.glob("*.jpg")])[::stride]


def evaluate_camvid(
    split: str, limit: int | None, size: tuple[int, int] | None, stride: int, threads: int | None
) -> dict[str, Any]:
    """Segment CamVid ``split`` images and score them against the labels mapped to our classes."""
    from dataclasses import replace

    import cv2
    import numpy as np

    # The method and the settings load numpy, OpenCV and pydantic: imported per command, for CLI start-up time.
    from contracts import settings as config  # lazy: CLI start-up
    from geoloc.core.labels import CLASS_NAMES
    from geoloc.vision.model_files import segmentation_files
    from geoloc.vision.segmentation import load_session, network_size, segment
    from workers.context import method_context

    root = config.shared_path("data", "camvid", split)
    images = camvid_images(split, stride)[:limit]
    if not images:
        raise FileNotFoundError(f"no images under {root / 'images'}")
    context = method_context()
    context = replace(context, onnx_threads=threads) if threads else context
    session = load_session(context, size)
    lut = np.array(CAMVID_TO_OURS, dtype=np.uint8)
    n = len(CLASS_NAMES)
    conf = np.zeros((n, n), dtype=np.int64)
    seg_seconds = 0.0
    t_all = time.perf_counter()
    segment(cv2.cvtColor(cv2.imread(str(images[0])), cv2.COLOR_BGR2RGB), session=session)  # warm-up
    for path in images:
        rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
        label = cv2.imread(str(root / "labels" / f"{path.stem}.png"), cv2.IMREAD_UNCHANGED)
        t0 = time.perf_counter()
        pred = segment(rgb, session=session)
        seg_seconds += time.perf_counter() - t0
        conf += confusion_matrix(lut[label], pred, n)
    total = time.perf_counter() - t_all
    w, h = network_size(session)
    return {
        "command": " ".join(["geoloc", *sys.argv[1:]]) if sys.argv else "geoloc eval camvid",
        "data": {
            "dataset": "camvid",
            "split": split,
            "images_dir": str(root / "images"),
            "n_images": len(images),
            "stride": stride,
            "limit": limit,
            "label_mapping_camvid_to_ours": list(CAMVID_TO_OURS),
        },
        "model": {"network_size_wxh": [w, h], "onnx": str(segmentation_files(context.models_dir, (w, h)).onnx)},
        "timing": {
            "total_s": round(total, 2),
            "segment_ms_per_image": round(1000 * seg_seconds / len(images), 1),
            "threads": threads,
        },
        "metrics": scores(conf),
        "confusion": conf.tolist(),
    }


@app.command("camvid")
def camvid(
    split: str = typer.Option("test", "--split", help="CamVid split: train, val or test."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the results to this JSON file."),
    limit: int | None = typer.Option(None, "--limit", min=1, help="Use at most N images."),
    size: str | None = typer.Option(None, "--size", help="Network input WxH (default: the runtime's)."),
    stride: int = typer.Option(1, "--stride", min=1, help="Use every k-th image (before --limit)."),
    threads: int | None = typer.Option(None, "--threads", min=1, help="onnxruntime intra-op threads."),
) -> None:
    """Score our segmentation on CamVid: per-class accuracy (recall) and IoU, overall pixel accuracy."""
    # The method loads numpy and OpenCV: imported per command, for CLI start-up time.
    from geoloc.vision.model_files import parse_size  # lazy: CLI start-up
    from geoloc.vision.segmentation import ModelNotBuiltError

    try:
        net_size = parse_size(size) if size else None
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--size") from exc
    try:
        result = evaluate_camvid(split, limit, net_size, stride, threads)
    except (ModelNotBuiltError, FileNotFoundError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    data, metrics = result["data"], result["metrics"]
    w, h = result["model"]["network_size_wxh"]
    typer.echo(
        f"CamVid {split}: {data['n_images']} images, network {w}x{h}, "
        f"{result['timing']['segment_ms_per_image']} ms/image"
    )
    typer.echo(f"{'class':<10}{'accuracy':>10}{'IoU':>8}")
    for name in REPORTED:
        row = metrics["per_class"][name]
        typer.echo(f"{name:<10}{row['accuracy']:>10.3f}{row['iou']:>8.3f}")
    typer.echo(f"{'overall':<10}{metrics['pixel_accuracy']:>10.3f}")
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(result, indent=2) + "\n")
        typer.echo(f"wrote {json_out}")


app.command("suite")(suite)


@app.command("world")
def world(
    world_dir: Path = typer.Argument(..., help="A world folder written by `geoloc sim world`."),
    json_out: Path | None = typer.Option(
        None,
        "--json",
        help="Write the full results (with per-query rows) here, and beside them the figures: "
        "OUT.error_cdf.png (rank-1 error CDF per run) and OUT.top_n.png (Fig. 7, best of top N).",
    ),
    runs: str | None = typer.Option(
        None,
        "--runs",
        help="Comma-separated runs to do (default all): ours/gps, ours/none, gt_poses/gps, gt_identities/gps, "
        "gt_segmentation/gps, paper_identity/none, paper_geometry/none.",
    ),
    max_queries: int | None = typer.Option(None, "--max-queries", min=1, help="Only the first N queries."),
    quiet: bool = typer.Option(False, help="No per-image progress."),
    track_outliers: bool = typer.Option(
        False,
        "--track-outliers",
        help="A world with query tracks: answer each track again with its middle frame replaced by another "
        "track's (a photo from elsewhere), and report whether it is flagged and the other frames' figures.",
    ),
) -> None:
    """Label a simulated world's references (via EXIF), answer its queries with the service's query stage.

    A world with query tracks: each track answered by the track stage, per prior (gps, none), per frame and per
    track, beside the same frames answered one by one (docs/measurements/tracks.md).

    Prints reference labelling, the paper's Tables I/II, the raw-GPS baseline, and per run (prior, ablation)
    the error at N = 1 for all queries, for those whose buildings some reference shows and per query kind,
    the heading error, how often the uncertainty radius holds the truth, and Fig. 7 (best of top N).
    """
    # The method loads numpy and OpenCV: imported per command, for CLI start-up time.
    from geoloc.evaluation.figures import write_world_figures  # lazy: CLI start-up
    from geoloc.evaluation.world import default_runs, evaluate_world  # lazy: CLI start-up
    from geoloc.localize.query import QueryConfig
    from workers.context import method_context

    config = QueryConfig()
    chosen = default_runs(config)
    if runs:
        names = [name.strip() for name in runs.split(",") if name.strip()]
        unknown = sorted(set(names) - {run.name for run in chosen})
        if unknown:
            raise typer.BadParameter(f"unknown runs {unknown}", param_hint="--runs")
        chosen = [run for run in chosen if run.name in names]
    started = time.perf_counter()
    result = evaluate_world(
        world_dir,
        config=config,
        runs=chosen,
        max_queries=max_queries,
        progress=None if quiet else (lambda msg: typer.echo(msg, err=True)),
        context=method_context(),
        track_outliers=track_outliers,
    )
    result["command"] = " ".join(["geoloc", *sys.argv[1:]])
    print_world_summary(result, time.perf_counter() - started)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(result, indent=2, default=str) + "\n")
        typer.echo(f"wrote {json_out}")
        for figure in write_world_figures(result, json_out):
            typer.echo(f"wrote {figure}")


def print_world_summary(result: dict[str, Any], seconds: float) -> None:
    """The tables of ``geoloc eval world`` from its result dict."""
    typer.echo(
        f"world {result['world']}: {result['references']} references, {result['queries']} queries "
        f"{result['query_kinds']}, {result['shown_by_references']} shown by some reference; "
        f"capture {result.get('capture', 'scattered')}; {seconds:.0f} s"
    )
    for seg, labelling in result["reference_labelling"].items():
        acc, heading, position = (
            labelling["identity_accuracy"],
            labelling["heading_error_deg"],
            labelling["position_error_m"],
        )
        typer.echo(
            f"references [{seg}]: identity accuracy greedy {acc['greedy']} / marginalised {acc['marginalized']} "
            f"(paper 0.7466 / 0.7627); heading median {heading['median']} deg, within 5 deg "
            f"{heading['within_5deg']}; position median {position['median_m']} m, within 5 m {position['within_5m']}"
        )
        typer.echo(
            f"references [{seg}] pose: position median {position.get('median_m')} m, within 1 / 2 m "
            f"{position.get('within_1m')} / {position.get('within_2m')}; heading within 2 / 5 deg "
            f"{heading.get('within_2deg')} / {heading.get('within_5deg')}"
        )
        for walk in labelling.get("per_walk", []):
            typer.echo(
                f"  walk {walk['walk_id']} ({walk['n']} references): position median {walk['position_median_m']} m, "
                f"heading within 5 deg {walk['heading_within_5deg']}"
            )
    for source, paper in (("ours", "0.7363 / 0.7915 / 0.8177"), ("gt_reference_labels", "0.7543 / 0.8113 / 0.8254")):
        acc = result["query_identity_accuracy"][source]
        typer.echo(
            f"transfer identity accuracy k=1/4/8 ({source}): {acc['1']} / {acc['4']} / {acc['8']} (paper {paper})"
        )
    if losses := result.get("query_identity_losses"):
        typer.echo(
            "where the shown queries' building pixels go (k=4): "
            + ", ".join(f"{part.replace('_', ' ')} {share}" for part, share in losses.items())
        )
    gps = result["gps_baseline"]
    typer.echo(
        f"raw EXIF GPS of the queries: median {gps.get('median_m')} m, "
        f"within 5 / 10 m {gps.get('within_5m')} / {gps.get('within_10m')}"
    )
    columns = ("w1m", "w5m", "w10m", "med m", "shown w5/10", "hd med", "hd<5", "r90 ok", "anch")
    widths = (5, 5, 5, 6, 12, 6, 5, 6, 5)
    header = f"{'run':22s} " + " ".join(f"{c:>{w}s}" for c, w in zip(columns, widths, strict=True))
    typer.echo(header)
    for name, run in result["runs"].items():
        a, s = run["all"], run["shown"]
        typer.echo(
            f"{name:22s} {a['within_1m']:5.2f} {a['within_5m']:5.2f} {a['within_10m']:5.2f} {a['median_error_m']:6.1f} "
            f"{s.get('within_5m', 0):5.2f}/{s.get('within_10m', 0):5.2f} {a['heading_median_deg']:6.1f} "
            f"{a['heading_within_5deg']:5.2f} {run['uncertainty_radius_holds_truth']:6.2f} {run['anchored_share']:5.2f}"
        )
    for name, run in result["runs"].items():
        errors = " ".join(f"{run['top_n_error_m'][str(n)]['mean']:.1f}" for n in range(1, 11))
        typer.echo(f"{name:22s} best of top N = 1..10, mean error (m): {errors}")
    if "tracks" in result:
        from geoloc.evaluation.tracks import track_summary_lines  # lazy: CLI start-up (numpy, the method)

        for line in track_summary_lines(result["tracks"]):
            typer.echo(line)


@app.command("photos")
def photos(
    photos_dir: Path = typer.Argument(..., help="Folder of geo-tagged photos (EXIF GPS)."),
    map_path: Path = typer.Option(..., "--map", help="The map of the area (any format the service accepts)."),
    truth_csv: Path | None = typer.Option(
        None, "--truth", help="CSV with columns name, true_heading_deg (and heading_accuracy_deg) to compare with."
    ),
    json_out: Path | None = typer.Option(None, "--json", help="Write the results here."),
    compass_prior: bool = typer.Option(
        False, "--compass-prior", help="Use each photo's compass as the robust heading prior (as the service does)."
    ),
    walks: bool = typer.Option(
        False, "--walks", help="Then place the photos' walks jointly (as the service's sequence job does)."
    ),
) -> None:
    """Label real photos with their EXIF GPS on a map (as the service labels references); compare headings.

    For each photo: the estimated compass heading and position, the buildings named, and with --truth the
    heading error against the recorded compass heading. Without --compass-prior the labelling uses no heading
    prior (the map alone, as this command always did); with it, the photo's compass as the service weights it.
    With --walks, photos of one walk (a Mapillary sequence id, or one camera's captures within 60 s and 50 m)
    are then placed jointly; --compass-prior --walks is what the service does with references.
    """
    # The method loads numpy and OpenCV: imported per command, for CLI start-up time.
    from geoloc.evaluation.world import evaluate_photos  # lazy: CLI start-up
    from workers.context import method_context

    result = evaluate_photos(
        photos_dir, map_path, truth_csv, compass_prior=compass_prior, place_walks=walks, context=method_context()
    )
    result["command"] = " ".join(["geoloc", *sys.argv[1:]])
    for row in result["photos"]:
        error = "" if row.get("heading_error_deg") is None else f", error {row['heading_error_deg']:.1f} deg"
        typer.echo(
            f"{row['name']}: heading {row['heading_deg']:.1f} deg (compass {row.get('compass_heading_deg')}){error}; "
            f"moved {row['moved_m']:.1f} m from GPS; buildings: {', '.join(row['buildings']) or '-'}"
        )
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(result, indent=2) + "\n")
        typer.echo(f"wrote {json_out}")


@app.command("facades")
def facades(
    world_dir: Path = typer.Argument(..., help="A world folder written by `geoloc sim world`."),
    segmentation: str = typer.Option("model", help="'model' (the network) or 'gt' (ground-truth labels)."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures here."),
) -> None:
    """Facade orientation accuracy per building column of every image of a world.

    Prints the median absolute error of theta_hat (mod 180), the share of columns within 5 and 10 deg, and
    the fraction of ground-truth building columns that get a hypothesis at all, pooled over all columns.
    """
    import numpy as np

    # The method and the simulator load numpy and OpenCV: imported per command, for CLI start-up time.
    from geoloc.evaluation.facades import column_orientation_errors  # lazy: CLI start-up
    from geoloc.photos.photo import load_photo
    from geoloc.sim.world import load_world
    from geoloc.vision.facades import analyze_image

    if segmentation not in ("model", "gt"):
        raise typer.BadParameter("segmentation must be 'model' or 'gt'")
    # The segmentation loads onnxruntime's session factory: only for this command, for CLI start-up time.
    from geoloc.vision.segmentation import load_session, segment  # lazy: CLI start-up
    from workers.context import method_context

    world_data = load_world(world_dir)
    session = load_session(method_context()) if segmentation == "model" else None
    errors, covered, building_columns = [], 0, 0
    started = time.perf_counter()
    for image in world_data.images:
        gt = world_data.gt(image.name)
        photo = load_photo(image.path)
        labels = gt["labels"] if session is None else segment(photo.image_rgb, session=session)
        model = analyze_image(photo.image_rgb, labels, photo.intrinsics).image_model
        err, n_building, n_covered = column_orientation_errors(
            model, gt["column_theta_deg"], gt["column_building_id"] >= 0, photo.intrinsics
        )
        errors.append(err)
        covered += n_covered
        building_columns += n_building
    err = np.concatenate(errors)
    result = {
        "world": str(world_dir),
        "segmentation": segmentation,
        "images": len(world_data.images),
        "median_abs_error_deg": round(float(np.median(err)), 3),
        "within_5deg": round(float(np.mean(err <= 5.0)), 4),
        "within_10deg": round(float(np.mean(err <= 10.0)), 4),
        "columns_with_hypothesis": round(covered / max(building_columns, 1), 4),
        "seconds": round(time.perf_counter() - started, 1),
    }
    typer.echo(
        f"{result['images']} images, segmentation={segmentation}: median |theta_hat - theta| "
        f"{result['median_abs_error_deg']} deg, within 5 deg {result['within_5deg']}, within 10 deg "
        f"{result['within_10deg']}; building columns with a hypothesis {result['columns_with_hypothesis']}"
    )
    if json_out:
        json_out.write_text(json.dumps(result, indent=2))
