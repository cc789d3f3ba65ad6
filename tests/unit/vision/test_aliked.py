"""ALIKED: the network, its ONNX runtime and its features.

The hand-written network loads the published weights strictly, its grid_sample deformable
convolution is the deformable convolution, the ONNX + numpy runtime gives the PyTorch network's
keypoints and descriptors on real photos, and ``extract_features(method="aliked")`` keeps the
:class:`Features` contract.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from contracts import settings as config
from geoloc.export import models
from geoloc.localize.transfer import match_and_verify
from geoloc.vision import aliked, model_files
from geoloc.vision.feature_types import canonical_method
from geoloc.vision.features import Features, extract_features
from geoloc.vision.model_files import vocabulary_path
from tests.model_fixtures import data_dir_environment
from workers.context import method_context

CONFIGS = ("aliked-n16", "aliked-t16")
DIMS = {"aliked-n16": 128, "aliked-t16": 64}
# Parameter counts of the published state dicts (tensors other than BN running stats and counters, SOURCES.md).
N_PARAMS = {"aliked-n16": 677356, "aliked-t16": 192100}


def _shared_or_skip(*parts: str) -> Path:
    try:
        return config.shared_path(*parts)
    except FileNotFoundError as exc:
        pytest.skip(f"shared data folder absent: {exc}")


def _lund(name: str, size: tuple[int, int] | None = None) -> np.ndarray:
    rgb = cv2.cvtColor(cv2.imread(str(_shared_or_skip("data", "lund", "images", f"{name}.jpg"))), cv2.COLOR_BGR2RGB)
    return rgb if size is None else cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A temporary GEOLOC_DATA_DIR with both ALIKED exports (a few seconds)."""
    pytest.importorskip("torch", reason="exporting needs the export extra (torch)")
    for name in CONFIGS:
        _shared_or_skip("models", f"{name}.pth")
    folder = tmp_path_factory.mktemp("aliked_data")
    with data_dir_environment(folder):
        for name in CONFIGS:
            models.build_aliked_model(name)
        yield folder


# ----------------------------------------------------------------------------------------------
# The network


@pytest.mark.parametrize("name", CONFIGS)
def test_state_dicts_load_strictly(name: str) -> None:
    torch = pytest.importorskip("torch")
    from geoloc.export.nets.aliked import ALIKED_CONFIGS, Aliked, load_aliked

    weights = _shared_or_skip("models", f"{name}.pth")
    net = load_aliked(weights, name)  # strict=True inside
    assert sum(p.numel() for p in net.parameters()) == N_PARAMS[name]
    state = torch.load(weights, map_location="cpu", weights_only=True)
    other = "aliked-t16" if name == "aliked-n16" else "aliked-n16"
    with pytest.raises(RuntimeError):  # the other config's shapes do not fit
        Aliked(ALIKED_CONFIGS[other]).load_state_dict(state, strict=True)
    state.pop("desc_head.agg_weights")
    with pytest.raises(RuntimeError, match="agg_weights"):
        Aliked(ALIKED_CONFIGS[name]).load_state_dict(state, strict=True)


def _naive_deform_conv(x: np.ndarray, offset: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Deformable 3x3 conv (stride 1, padding 1) written from its definition, one output pixel at a time."""
    c_in, h, w = x.shape
    out = np.zeros((weight.shape[0], h, w))

    def value(c: int, yy: float, xx: float) -> float:  # bilinear, zero outside
        y0, x0 = int(np.floor(yy)), int(np.floor(xx))
        total = 0.0
        for cy, wy in ((y0, 1 - (yy - y0)), (y0 + 1, yy - y0)):
            for cx, wx in ((x0, 1 - (xx - x0)), (x0 + 1, xx - x0)):
                if 0 <= cy < h and 0 <= cx < w:
                    total += wy * wx * x[c, cy, cx]
        return total

    for oy in range(h):
        for ox in range(w):
            for i in range(3):
                for j in range(3):
                    k = 3 * i + j
                    yy = oy - 1 + i + offset[2 * k, oy, ox]
                    xx = ox - 1 + j + offset[2 * k + 1, oy, ox]
                    column = np.array([value(c, yy, xx) for c in range(c_in)])
                    out[:, oy, ox] += weight[:, :, i, j] @ column
    return out


def test_grid_sample_deformable_conv_is_the_deformable_convolution() -> None:
    torch = pytest.importorskip("torch")
    from geoloc.export.nets.aliked import DeformConv3x3

    torch.manual_seed(0)
    conv = DeformConv3x3(3, 4)
    with torch.no_grad():
        conv.offset_conv.weight.normal_(0.0, 0.8)  # offsets of a few pixels, some leaving the map
        conv.offset_conv.bias.normal_(0.0, 1.0)
        x = torch.randn(1, 3, 6, 7)
        got = conv(x)[0].numpy()
        offset = conv.offset_conv(x)[0].numpy()
    assert np.abs(offset).max() > 2.0
    offset = np.clip(offset, -7 / 4, 7 / 4)  # the reference clamps offsets to max(H, W) / 4
    expected = _naive_deform_conv(x[0].numpy(), offset, conv.regular_conv.weight.detach().numpy())
    np.testing.assert_allclose(got, expected, atol=1e-4)


# ----------------------------------------------------------------------------------------------
# Export and runtime


@pytest.mark.slow
@pytest.mark.parametrize("name", CONFIGS)
def test_onnx_runtime_matches_pytorch_on_a_real_photo(exported: Path, name: str) -> None:
    torch = pytest.importorskip("torch")
    from geoloc.export.nets.aliked import load_aliked

    net = load_aliked(models.aliked_weights_path(name), name)
    runtime = aliked.load_runtime(method_context(), name)
    image = _lund("05", (500, 370))  # not a multiple of 32: exercises the padding
    found = aliked.aliked_keypoints(image, 1000, runtime=runtime)
    xy, scores, desc = found.xy, found.scores, found.descriptors
    with torch.no_grad():
        x = torch.from_numpy(image.astype(np.float32) / 255.0).permute(2, 0, 1)[None]
        score_map, feature_map = net.dense(x)
        ref_xy, ref_scores = net.detect(score_map[0, 0], 1000)
        ref_desc = net.describe(feature_map[0], ref_xy).numpy()
    # The exported graph (score head restructured per level) against the network's plain dense pass.
    np.testing.assert_allclose(aliked.dense_maps(runtime, image).score, score_map[0, 0].numpy(), atol=1e-4)
    assert len(xy) == len(ref_xy) == 1000
    dist = np.linalg.norm(xy[:, None, :] - ref_xy.numpy()[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    same = dist[np.arange(len(xy)), nearest] < 1e-2
    assert same.mean() > 0.99
    np.testing.assert_allclose(scores[same], ref_scores.numpy()[nearest[same]], atol=1e-4)
    dots = np.einsum("ij,ij->i", desc[same], ref_desc[nearest[same]])
    assert dots.min() > 0.9999
    assert desc.shape == (1000, DIMS[name])


def test_detect_keypoints_local_maxima_mask_and_subpixel() -> None:
    score = np.zeros((40, 50), np.float32)
    score[10, 12], score[10, 13] = 0.9, 0.6  # sub-pixel peak between columns 12 and 13, nearer 12
    score[30, 40] = 0.8
    score[11, 13] = 0.7  # next to a stronger maximum: suppressed
    score[1, 1] = 1.0  # in the 2-pixel border: dropped
    xy, s = aliked.detect_keypoints(score, 10)
    assert len(xy) == 2
    np.testing.assert_allclose(xy[0], [40.0, 30.0], atol=1e-6)  # strongest (refined score) first
    assert 12.0 < xy[1, 0] < 12.5 and 10.0 < xy[1, 1] < 10.5  # pulled towards its neighbours
    assert s[0] == pytest.approx(0.8) and 0.6 < s[1] < 0.9
    allowed = np.zeros_like(score, bool)
    allowed[25:35, 35:45] = True
    xy_masked, _ = aliked.detect_keypoints(score, 10, allowed)
    np.testing.assert_allclose(xy_masked, [[40.0, 30.0]], atol=1e-6)
    assert len(aliked.detect_keypoints(score, 1)[0]) == 1


def test_missing_export_says_how_to_build_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path))
    config.reset_settings()
    with pytest.raises(aliked.AlikedNotBuiltError, match="geoloc models build"):
        aliked.load_runtime(method_context(), "aliked-n16")
    with pytest.raises(ValueError, match="MethodContext"):
        extract_features(_lund("05", (320, 240)), None, 10, method="aliked")


def test_export_is_cached_and_tracks_weights(exported: Path) -> None:
    files = model_files.aliked_files(config.models_dir(), "aliked-n16")
    mtime = files.onnx.stat().st_mtime_ns
    assert models.build_aliked_model("aliked-n16") == files
    assert files.onnx.stat().st_mtime_ns == mtime  # not re-exported
    sha = model_files.sha256_file(models.aliked_weights_path("aliked-n16"))
    assert model_files.aliked_is_current(files, sha) and not model_files.aliked_is_current(files, "0" * 64)
    meta = model_files.read_meta(files)
    assert meta is not None and meta["descriptor_dim"] == 128


# ----------------------------------------------------------------------------------------------
# The Features contract


def test_aliked_features_contract(exported: Path, tmp_path: Path) -> None:
    image = _lund("05")  # 1024 x 768
    mask = np.zeros(image.shape[:2], bool)
    mask[100:500, :600] = True
    f = extract_features(image, mask, 800, method="aliked", context=method_context(), max_side=640)
    assert f.method == "aliked-n16" and len(f) == 800
    assert f.image_shape == (768, 1024) and f.scale == pytest.approx(0.625)
    assert f.descriptors.shape == (800, 128) and f.descriptors.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(f.descriptors, axis=1), 1.0, atol=1e-5)
    assert np.all(np.diff(f.responses) <= 0)  # strongest first
    # Input pixels, inside the mask dilated by 4 working px (6.4 input px) plus the sub-pixel refinement.
    assert f.xy[:, 0].max() < 600 + 6.4 + 2 / 0.625 and f.xy[:, 1].min() > 100 - 6.4 - 2 / 0.625
    assert f.xy[:, 0].max() > 500  # not working pixels
    # The same content at the working size gives the same keypoints, scaled.
    work = cv2.resize(image, (640, 480), interpolation=cv2.INTER_AREA)
    g = extract_features(
        work,
        cv2.resize(mask.astype(np.uint8), (640, 480), interpolation=cv2.INTER_NEAREST),
        800,
        method="aliked",
        context=method_context(),
    )
    d = np.linalg.norm(((f.xy + 0.5) * f.scale - 0.5)[:, None, :] - g.xy[None, :, :], axis=2).min(axis=1)
    assert np.median(d) < 1e-3
    again = extract_features(image, mask, 800, method="aliked", context=method_context(), max_side=640)
    np.testing.assert_array_equal(again.xy, f.xy)
    np.testing.assert_array_equal(again.descriptors, f.descriptors)
    # Storage keeps the type; other types and sizes.
    f.save(tmp_path / "f.npz")
    h = Features.load(tmp_path / "f.npz")
    assert h.method == "aliked-n16" and h.descriptor_dim == 128
    np.testing.assert_allclose(h.descriptors, f.descriptors, atol=1e-3)
    t = extract_features(image, mask, 300, method="aliked-t16", context=method_context(), max_side=640)
    assert t.descriptors.shape == (300, 64) and t.method == "aliked-t16"
    empty = extract_features(image, np.zeros_like(mask), method="aliked-t16", context=method_context())
    assert len(empty) == 0 and empty.descriptors.shape == (0, 64) and empty.method == "aliked-t16"
    gray_image = cv2.cvtColor(work, cv2.COLOR_RGB2GRAY)
    gray = extract_features(gray_image, None, 100, method="aliked", context=method_context())
    assert len(gray) == 100


@pytest.mark.slow
def test_aliked_matches_overlapping_real_photos_and_rejects_distant_ones(exported: Path) -> None:
    """Adjacent Lund photos (same street, overlapping) verify with hundreds of inliers.

    Photos 16 apart verify with a few (whole images: road, cars and trees match too).
    """
    context = method_context()
    feats = {n: extract_features(_lund(n), None, 1500, method="aliked", context=context) for n in ("04", "05", "20")}
    _, adjacent, _ = match_and_verify(feats["04"], feats["05"])
    _, far, _ = match_and_verify(feats["04"], feats["20"])
    assert adjacent.sum() >= 150
    assert adjacent.sum() >= 5 * far.sum()


def test_feature_types_are_named_and_have_their_own_vocabulary_file() -> None:
    assert canonical_method(None) == "rootsift" and canonical_method("aliked") == "aliked-n16"
    with pytest.raises(ValueError, match="unknown feature method"):
        canonical_method("orb")
    paths = {vocabulary_path(Path("models"), 4096, m) for m in ("rootsift", "aliked", "aliked-t16")}
    assert len(paths) == 3
    assert vocabulary_path(Path("models"), 4096, "aliked").name == "sbow_vocabulary_aliked-n16_4096.npz"
    stored = Features.empty((10, 10)).to_arrays()
    stored.pop("method")  # stored before feature types existed: RootSIFT
    assert Features.from_arrays(stored).method == "rootsift"


def test_pyramid_levels_are_the_image_at_that_size(exported: Path) -> None:
    """Keypoints found at pyramid scale 0.5 are those of the half-size image, positions in full-size pixels."""
    image = _lund("05", (640, 480))
    runtime = aliked.load_runtime(method_context(), "aliked-n16")
    both = aliked.aliked_keypoints(image, 1200, runtime=runtime, scales=(1.0, 0.5))
    assert set(np.unique(both.scales).tolist()) == {0.5, 1.0}
    assert np.all(np.diff(both.scores) <= 0)
    half = aliked.aliked_keypoints(cv2.resize(image, (320, 240), interpolation=cv2.INTER_AREA), 1200, runtime=runtime)
    small = both.scales == 0.5
    in_half = (both.xy[small] + 0.5) * 0.5 - 0.5
    dist = np.linalg.norm(in_half[:, None, :] - half.xy[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    np.testing.assert_allclose(dist[np.arange(len(in_half)), nearest], 0.0, atol=1e-4)
    np.testing.assert_allclose(both.descriptors[small], half.descriptors[nearest], atol=1e-5)
    f = extract_features(image, None, 500, method="aliked", context=method_context(), aliked_scales=(1.0, 0.5))
    assert len(f) == 500 and f.sizes.max() == pytest.approx(2 * f.sizes.min())  # 5 px windows at both scales


def test_models_build_rejects_an_unknown_feature_type(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from cli.main import app

    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path))
    result = CliRunner().invoke(app, ["models", "build", "--features", "orb"])
    assert result.exit_code == 2
    assert "unknown feature method" in result.output
    assert not (tmp_path / "cache" / "models").exists() or not any((tmp_path / "cache" / "models").iterdir())
