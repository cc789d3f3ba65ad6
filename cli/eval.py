"""``geoloc eval ...``: measure stages on real data (CamVid segmentation)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import typer

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

    from geoloc.labels import CLASS_NAMES

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


def evaluate_camvid(
    split: str, limit: int | None, size: tuple[int, int] | None, stride: int, threads: int | None
) -> dict[str, Any]:
    """Segment CamVid ``split`` images and score them against the labels mapped to our classes."""
    import cv2
    import numpy as np

    from geoloc import config
    from geoloc.labels import CLASS_NAMES
    from geoloc.models import segmentation_files
    from geoloc.segmentation import load_session, network_size, segment

    root = config.shared_path("data", "camvid", split)
    images = sorted((root / "images").glob("*.png")) + sorted((root / "images").glob("*.jpg"))
    images = sorted(images)[::stride][:limit]
    if not images:
        raise FileNotFoundError(f"no images under {root / 'images'}")
    session = load_session(size, threads)
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
        "model": {"network_size_wxh": [w, h], "onnx": str(segmentation_files((w, h)).onnx)},
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
    from geoloc.models import parse_size
    from geoloc.segmentation import ModelNotBuiltError

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


@app.command("world")
def world(
    world_dir: Path = typer.Argument(..., help="A world folder written by `geoloc sim world`."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the full results here."),
    segmentation: str = typer.Option("model", help="'model' (the network) or 'gt' (ground-truth labels)."),
    localize_k: int = typer.Option(4, "--k", help="References whose identities drive localisation."),
    max_queries: int | None = typer.Option(None, "--max-queries", help="Only the first N queries."),
    quiet: bool = typer.Option(False, help="No per-image progress."),
) -> None:
    """Ingest a simulated world's references (via EXIF), localise its queries, compare with the ground truth.

    Prints the paper's tables (reference and query identity accuracy, localisation error of the best of
    the top N, with and without identities) and writes every figure to --json.
    """
    from geoloc.evaluation import evaluate_world

    if segmentation not in ("model", "gt"):
        raise typer.BadParameter("segmentation must be 'model' or 'gt'")
    started = time.perf_counter()
    result = evaluate_world(
        world_dir,
        segmentation=segmentation,
        localize_k=localize_k,
        max_queries=max_queries,
        progress=None if quiet else (lambda msg: typer.echo(msg, err=True)),
    )
    result["command"] = " ".join(sys.argv)
    ref = result["reference_identity_accuracy"]
    typer.echo(
        f"world {world_dir}: {result['references']} references, {result['queries']} queries, "
        f"segmentation={segmentation}, {time.perf_counter() - started:.0f} s"
    )
    typer.echo(
        f"reference identity accuracy   greedy {ref['greedy']}   marginalized {ref['marginalized']}"
        "   (paper: 0.7466 / 0.7627)"
    )
    for source, paper in (("ours", "0.7363 / 0.7915 / 0.8177"), ("gt_reference_labels", "0.7543 / 0.8113 / 0.8254")):
        acc = result["query_identity_accuracy"][source]
        typer.echo(
            f"query identity accuracy k=1/4/8 ({source}): {acc['1']} / {acc['4']} / {acc['8']}   (paper {paper})"
        )
    heading = result["reference_heading_error_deg"]
    typer.echo(f"reference heading error: median {heading['median']} deg, within 5 deg {heading['within_5deg']}")
    for mode, block in result["localization"].items():
        errors = " ".join(f"{block['top_n_error_m'][str(n)]['mean']:.1f}" for n in range(1, 11))
        q = result["query_heading_error_deg"][mode]
        typer.echo(f"{mode:14s} best-of-top-N error (m), N=1..10: {errors}")
        typer.echo(
            f"{'':14s} median {block['median_error_m_at_1']} m at N=1, recall 5 m {block['recall_5m_at_1']}, "
            f"10 m {block['recall_10m_at_1']}; heading median {q['median']} deg"
        )
    if json_out:
        json_out.write_text(json.dumps(result, indent=2))
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

    from geoloc.facade_metrics import column_orientation_errors
    from geoloc.facades import analyze_image
    from geoloc.pipeline import load_photo
    from geoloc.sim.world import load_world

    if segmentation not in ("model", "gt"):
        raise typer.BadParameter("segmentation must be 'model' or 'gt'")
    from geoloc.segmentation import segment

    world_data = load_world(world_dir)
    errors, covered, building_columns = [], 0, 0
    started = time.perf_counter()
    for image in world_data.images:
        gt = world_data.gt(image.name)
        photo = load_photo(image.path)
        labels = gt["labels"] if segmentation == "gt" else segment(photo.image_rgb)
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
