"""Benchmark: the segmentation network quantised to int8 against the float export, side by side on this CPU.

    .venv/bin/python benchmarks/bench_segmentation_int8.py [--calibration 32] [--stride 4] [--rounds 3]
                                                           [--out /tmp/int8] [--json int8.json]

The recipe issue 52 asks for: onnxruntime's own static quantisation (``quantize_static``) of the float export
``geoloc models build`` made (the runtime's network size), QDQ format, per-channel int8 weights, uint8
activations, MinMax calibration on ``--calibration`` CamVid training images (evenly spaced, prepared as the
runtime prepares a photo), after onnxruntime's ``quant_pre_process``. Two variants are measured, both written to
``--out``: ``int8`` (every operator onnxruntime quantises) and ``int8-dense`` (only the 18 convolutions that
are not grouped: ESPNetv2's other 105 are grouped or depthwise, which int8 kernels do not speed up).

Then, one onnxruntime thread each, sessions as the workers open them: the CPU time of :func:`segment` per
CamVid test image (every ``--stride``-th, the models interleaved, ``--rounds`` rounds, medians) and each model's
CamVid test scores on the same images (building accuracy and IoU, mean IoU over building, tree, road, sky, car).
Prints a table and the CPU's vector extensions (int8 pays with AVX-512 VNNI or AMX, not with AVX2 alone).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from cli.eval import CAMVID_TO_OURS, REPORTED, camvid_images, confusion_matrix, scores
from contracts.settings import models_dir
from geoloc.core.labels import CLASS_NAMES
from geoloc.vision.model_files import SEG_DEFAULT_SIZE, segmentation_files
from geoloc.vision.onnx_session import onnx_session
from geoloc.vision.segmentation import _prepare, segment


def read_rgb(path: Path) -> np.ndarray:
    """An image file as (H, W, 3) uint8 RGB; OSError when OpenCV cannot read it."""
    bgr = cv2.imread(str(path))
    if bgr is None:
        raise OSError(f"cannot read {path}")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def quantise(float_onnx: Path, out_dir: Path, calibration: list[Path], size: tuple[int, int]) -> dict[str, Path]:
    """The int8 variants of ``float_onnx`` in ``out_dir``: {"int8": all operators, "int8-dense": ungrouped convs}."""
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class CamVidReader(CalibrationDataReader):  # type: ignore[misc]  # onnxruntime ships no type hints
        def __init__(self) -> None:
            self.paths = iter(calibration)

        def get_next(self) -> dict[str, np.ndarray] | None:
            path = next(self.paths, None)
            if path is None:
                return None
            return {"image": _prepare(read_rgb(path), size)}

    out_dir.mkdir(parents=True, exist_ok=True)
    prepared = out_dir / "prepared.onnx"
    quant_pre_process(str(float_onnx), str(prepared), skip_symbolic_shape=True)
    dense = [
        node.name
        for node in onnx.load(str(prepared)).graph.node
        if node.op_type == "Conv"
        and all(onnx.helper.get_attribute_value(a) == 1 for a in node.attribute if a.name == "group")
    ]
    variants = {"int8": out_dir / "int8.onnx", "int8-dense": out_dir / "int8_dense.onnx"}
    for name, path in variants.items():
        quantize_static(
            str(prepared),
            str(path),
            CamVidReader(),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            nodes_to_quantize=dense if name == "int8-dense" else None,
        )
    return variants


def measure(models: dict[str, Path], images: list[Path], rounds: int) -> dict[str, dict[str, Any]]:
    """Per model: median CPU ms of :func:`segment` per image (interleaved) and the CamVid scores."""
    sessions = {name: onnx_session(str(path), 1, "cpu") for name, path in models.items()}
    lut = np.array(CAMVID_TO_OURS, dtype=np.uint8)
    n = len(CLASS_NAMES)
    conf = {name: np.zeros((n, n), dtype=np.int64) for name in models}
    cpu_s: dict[str, list[float]] = {name: [] for name in models}
    for round_index in range(rounds):
        for path in images:
            rgb = read_rgb(path)
            truth = lut[cv2.imread(str(path.parent.parent / "labels" / f"{path.stem}.png"), cv2.IMREAD_UNCHANGED)]
            for name, session in sessions.items():
                t0 = time.process_time()
                labels = segment(rgb, session=session)
                cpu_s[name].append(time.process_time() - t0)
                if round_index == 0:
                    conf[name] += confusion_matrix(truth, labels, n)
    figures = {}
    for name in models:
        metrics = scores(conf[name])["per_class"]
        figures[name] = {
            "cpu_ms_median": round(1e3 * float(np.median(cpu_s[name])), 1),
            "building_accuracy": metrics["building"]["accuracy"],
            "building_iou": metrics["building"]["iou"],
            "mean_iou": round(float(np.mean([metrics[c]["iou"] for c in REPORTED])), 4),
        }
    return figures


def cpu_extensions() -> list[str]:
    """The CPU's vector extensions that matter to int8 (from /proc/cpuinfo; empty elsewhere)."""
    try:
        flags = next(line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags"))
    except (OSError, StopIteration):
        return []
    wanted = ("avx2", "avx512f", "avx512_vnni", "avx_vnni", "amx_int8")
    return [flag for flag in flags.split() if flag in wanted]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calibration", type=int, default=32, help="CamVid training images to calibrate on")
    parser.add_argument("--stride", type=int, default=4, help="every k-th CamVid test image")
    parser.add_argument("--rounds", type=int, default=3, help="timing rounds over the images")
    parser.add_argument("--out", type=Path, default=Path("/tmp/geoloc-int8"), help="where the int8 models go")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()

    float_onnx = segmentation_files(models_dir(), SEG_DEFAULT_SIZE).onnx
    training = camvid_images("train", 1)
    calibration = training[:: max(1, len(training) // args.calibration)][: args.calibration]
    t0 = time.perf_counter()
    models = {"float": float_onnx, **quantise(float_onnx, args.out, calibration, SEG_DEFAULT_SIZE)}
    quantise_s = time.perf_counter() - t0
    images = camvid_images("test", args.stride)
    figures = measure(models, images, args.rounds)
    extensions = cpu_extensions()
    report = {
        "command": "benchmarks/bench_segmentation_int8.py "
        + " ".join(f"--{k} {v}" for k, v in vars(args).items() if v is not None),
        "machine": {"cpu": platform.processor() or platform.machine(), "extensions": extensions},
        "network_size_wxh": list(SEG_DEFAULT_SIZE),
        "calibration_images": len(calibration),
        "test_images": len(images),
        "quantise_s": round(quantise_s, 1),
        "models": figures,
    }
    base = figures["float"]["cpu_ms_median"]
    print(f"CPU extensions: {' '.join(extensions) or 'unknown'}")
    print(f"{'model':<12}{'CPU ms':>8}{'x float':>9}{'bld acc':>9}{'bld IoU':>9}{'mean IoU':>10}")
    for name, row in figures.items():
        print(
            f"{name:<12}{row['cpu_ms_median']:>8}{row['cpu_ms_median'] / base:>9.2f}"
            f"{row['building_accuracy']:>9.3f}{row['building_iou']:>9.3f}{row['mean_iou']:>10.3f}"
        )
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
