"""Segmentation: the network, its ONNX export and its runtime.

The hand-written ESPNetv2 loads the published weights, the ONNX export matches it, and the runtime
labels real CamVid pixels correctly.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from contracts import settings as config
from geoloc.core import labels
from geoloc.export import models
from geoloc.vision import model_files, segmentation
from tests.model_fixtures import data_dir_environment
from workers.context import method_context

CAMVID_IMAGE = "Seq05VD_f01110"  # a test image with ~40 % building pixels


def _shared_or_skip(*parts: str) -> Path:
    try:
        return config.shared_path(*parts)
    except FileNotFoundError as exc:
        pytest.skip(f"shared data folder absent: {exc}")


def _rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A temporary GEOLOC_DATA_DIR holding the ONNX export for this module's tests.

    Module-scoped: the variable is restored after them, so the tests a worker runs later see their own data
    folder (with the session's scope, evaluation tests after these found no vocabulary here).
    """
    _shared_or_skip("models", model_files.SEG_WEIGHTS)
    with data_dir_environment(tmp_path_factory.mktemp("geoloc_data")) as folder:
        yield folder


@pytest.fixture(scope="module")
def onnx_path(data_dir: Path) -> Path:
    pytest.importorskip("torch", reason="exporting needs the export extra (torch)")
    return models.build_segmentation_model()


@pytest.fixture(scope="session")
def camvid_pair() -> tuple[np.ndarray, np.ndarray]:
    """(RGB image, CamVid label) of one test frame."""
    root = _shared_or_skip("data", "camvid", "test")
    image = _rgb(root / "images" / f"{CAMVID_IMAGE}.jpg")
    label = cv2.imread(str(root / "labels" / f"{CAMVID_IMAGE}.png"), cv2.IMREAD_UNCHANGED)
    return image, label


@pytest.mark.slow  # loads the PyTorch weights (directly or to export ONNX): tens of seconds
def test_state_dicts_load_strictly() -> None:
    torch = pytest.importorskip("torch")
    from geoloc.export.nets.espnetv2 import load_espnetv2

    for name, s, n_params in [
        ("espnetv2_s_2.0_city_1024x512.pth", 2.0, 789242),
        ("espnetv2_s_1.0_city_512x256.pth", 1.0, 234010),
    ]:
        net = load_espnetv2(_shared_or_skip("models", name), s=s)  # strict=True inside
        assert sum(p.numel() for p in net.parameters()) == n_params  # SOURCES.md's count
        with torch.no_grad():
            assert net(torch.zeros(1, 3, 64, 128)).shape == (1, 20, 64, 128)


@pytest.mark.slow  # loads the PyTorch weights (directly or to export ONNX): tens of seconds
def test_onnx_matches_torch(onnx_path: Path, camvid_pair: tuple[np.ndarray, np.ndarray]) -> None:
    torch = pytest.importorskip("torch")
    from geoloc.export.nets.espnetv2 import NormalizedSegmenter, load_espnetv2

    session = segmentation.load_session(method_context())
    x = segmentation._prepare(camvid_pair[0], segmentation.network_size(session))
    onnx_logits = session.run(None, {"image": x})[0]
    net = load_espnetv2(models.weights_path(), s=model_files.SEG_SCALE)  # reference ops, not the export's
    net.full_resolution = False
    with torch.no_grad():
        torch_logits = NormalizedSegmenter(net)(torch.from_numpy(x)).numpy()
    assert onnx_logits.shape == torch_logits.shape
    np.testing.assert_allclose(onnx_logits, torch_logits, atol=2e-3 * np.abs(torch_logits).max(), rtol=0)
    same = (onnx_logits.argmax(1) == torch_logits.argmax(1)).mean()
    assert same > 0.999


@pytest.mark.slow  # loads the PyTorch weights (directly or to export ONNX): tens of seconds
def test_build_is_cached_and_tracks_weights(onnx_path: Path) -> None:
    files = model_files.segmentation_files(config.models_dir())
    meta = json.loads(files.meta.read_text())
    assert meta["weights_sha256"] == model_files.sha256_file(models.weights_path())
    mtime = onnx_path.stat().st_mtime_ns
    assert models.build_segmentation_model() == onnx_path
    assert onnx_path.stat().st_mtime_ns == mtime  # not re-exported
    assert not model_files.is_current(files, "0" * 64)  # other weights -> stale -> rebuilt


@pytest.mark.slow  # loads the PyTorch weights (directly or to export ONNX): tens of seconds
def test_segment_shape_dtype_on_phone_photo(onnx_path: Path) -> None:
    image = _rgb(_shared_or_skip("data", "lund", "images", "05.jpg"))
    session = segmentation.load_session(method_context())
    out = segmentation.segment(image, session=session)
    assert out.shape == image.shape[:2] and out.dtype == np.uint8
    assert out.max() < len(labels.CLASS_NAMES)
    odd = segmentation.segment(image[:301, :457], session=session)
    assert odd.shape == (301, 457)
    probs = segmentation.class_probabilities(image[:301, :457], session=session)
    assert probs.shape == (301, 457, len(labels.CLASS_NAMES))
    np.testing.assert_allclose(probs.sum(axis=2), 1.0, atol=1e-4)


@pytest.mark.slow  # loads the PyTorch weights (directly or to export ONNX): tens of seconds
def test_segment_camvid_building_pixels(onnx_path: Path, camvid_pair: tuple[np.ndarray, np.ndarray]) -> None:
    from cli.eval import CAMVID_TO_OURS

    image, label = camvid_pair
    truth = np.array(CAMVID_TO_OURS, dtype=np.uint8)[label]
    pred = segmentation.segment(image, session=segmentation.load_session(method_context()))
    building_truth, building_pred = truth == labels.BUILDING, pred == labels.BUILDING
    recall = (building_pred & building_truth).sum() / building_truth.sum()
    iou = (building_pred & building_truth).sum() / (building_pred | building_truth).sum()
    assert recall > 0.85 and iou > 0.8, (recall, iou)  # measured 0.93 and 0.89
    valid = truth != 255
    assert (pred[valid] == truth[valid]).mean() > 0.88  # measured 0.92


def test_missing_model_error_is_clear(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path))
    config.reset_settings()
    with pytest.raises(segmentation.ModelNotBuiltError, match="geoloc models build"):
        segmentation.load_session(method_context())


@pytest.mark.slow  # loads the PyTorch weights (directly or to export ONNX): tens of seconds
def test_cli_eval_camvid_writes_json(onnx_path: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cli.main import app

    out = tmp_path / "camvid.json"
    result = CliRunner().invoke(app, ["eval", "camvid", "--split", "test", "--limit", "2", "--json", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["data"]["n_images"] == 2
    assert set(report["metrics"]["per_class"]) == set(labels.CLASS_NAMES)
    assert "building" in result.output


def test_segmentation_size_setting_selects_the_network(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """GEOLOC_SEGMENTATION_SIZE reaches the context, the session's file, the answer's name and the model check."""
    from workers.context import model_problems

    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("GEOLOC_SEGMENTATION_SIZE", "512x256")
    config.reset_settings()
    try:
        context = method_context()
        assert context.segmentation_size == (512, 256)
        assert segmentation.network_name(context) == "espnetv2_s2_city_512x256"
        with pytest.raises(segmentation.ModelNotBuiltError, match="512x256"):
            segmentation.load_session(context)
        assert any("espnetv2_s2_city_512x256.onnx" in problem for problem in model_problems())
        monkeypatch.setenv("GEOLOC_SEGMENTATION_SIZE", "500x256")  # a size, but not multiples of 16
        config.reset_settings()
        assert model_problems() == [
            "GEOLOC_SEGMENTATION_SIZE: network size must be multiples of 16 and >= 64, got 500x256"
        ]
        monkeypatch.setenv("GEOLOC_SEGMENTATION_SIZE", "wide")
        with pytest.raises(config.SettingsError, match="GEOLOC_SEGMENTATION_SIZE"):
            config.reset_settings()
            config.get_settings()
    finally:
        monkeypatch.delenv("GEOLOC_SEGMENTATION_SIZE")
        config.reset_settings()
    assert method_context().segmentation_size is None
    assert segmentation.network_name(method_context()) == model_files.segmentation_files(tmp_path).onnx.stem
