"""The session factory's devices on a machine without a GPU (this one): cpu, auto -> CPU, cuda -> a clear error.

The CUDA path itself is exercised where onnxruntime-gpu and a GPU exist (``benchmarks/bench_device.py``); here
the CUDA provider is at most pretended (monkeypatched into the available list) to check that a session which
does not get it is refused under ``cuda`` and quietly runs on the CPU under ``auto``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from contracts.settings import SettingsError, get_settings, reset_settings
from geoloc.core.context import MethodContext
from geoloc.vision import onnx_session
from geoloc.vision.onnx_session import CPU_PROVIDER, CUDA_PROVIDER, DeviceUnavailableError
from workers.context import method_context

pytestmark = pytest.mark.skipif(
    CUDA_PROVIDER in onnx_session.available_providers(), reason="this machine has onnxruntime's CUDA provider"
)


@pytest.fixture
def onnx_path(built_models: Path) -> Iterator[str]:
    """A built network (the segmentation export); the factory's cache emptied around each test."""
    onnx_session.onnx_session.cache_clear()
    yield str(next(built_models.glob("espnetv2*.onnx")))
    onnx_session.onnx_session.cache_clear()


def test_cpu_is_exactly_the_cpu_provider_with_the_old_options(onnx_path: str) -> None:
    session = onnx_session.onnx_session(onnx_path, 2, "cpu")
    assert session.get_providers() == [CPU_PROVIDER]
    options = session.get_session_options()
    assert (options.intra_op_num_threads, options.inter_op_num_threads) == (2, 1)
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "0"
    assert onnx_session.session_device(session) == "cpu"


def test_auto_runs_on_the_cpu_here(onnx_path: str) -> None:
    session = onnx_session.onnx_session(onnx_path, 1, "auto")
    assert session.get_providers() == [CPU_PROVIDER]
    assert onnx_session.used_device("auto") == "cpu"


def test_cuda_without_the_provider_names_what_is_missing(onnx_path: str) -> None:
    with pytest.raises(DeviceUnavailableError, match=CUDA_PROVIDER) as raised:
        onnx_session.onnx_session(onnx_path, 1, "cuda")
    assert "geoloc[gpu]" in str(raised.value) and "GEOLOC_DEVICE=cpu" in str(raised.value)
    assert onnx_session.device_problems("cuda") == [str(raised.value)]
    assert onnx_session.device_problems("cpu") == [] and onnx_session.device_problems("auto") == []


def test_a_session_without_the_cuda_provider_is_refused_under_cuda_and_cpu_under_auto(
    onnx_path: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The provider listed but not given to the session (no GPU, no driver): onnxruntime falls back to the CPU."""
    monkeypatch.setattr(onnx_session, "available_providers", lambda: [CUDA_PROVIDER, CPU_PROVIDER])
    with pytest.warns(UserWarning, match=CUDA_PROVIDER):  # onnxruntime's own note that it fell back
        with pytest.raises(DeviceUnavailableError, match="did not get the CUDAExecutionProvider"):
            onnx_session.onnx_session(onnx_path, 1, "cuda")
        assert onnx_session.onnx_session(onnx_path, 1, "auto").get_providers() == [CPU_PROVIDER]


def test_an_unknown_device_is_refused(onnx_path: str) -> None:
    with pytest.raises(ValueError, match="unknown device 'gpu'"):
        onnx_session.onnx_session(onnx_path, 1, "gpu")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="device must be one of auto, cpu, cuda"):
        MethodContext(Path("."), device="gpu")  # type: ignore[arg-type]


def test_the_setting_is_validated_and_carried_into_the_context(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GEOLOC_DEVICE", "gpu")
    reset_settings()
    try:
        with pytest.raises(SettingsError, match="GEOLOC_DEVICE='gpu'.*'auto', 'cpu' or 'cuda'"):
            get_settings()
        monkeypatch.setenv("GEOLOC_DEVICE", "cpu")
        reset_settings()
        assert method_context().device == "cpu"
        monkeypatch.delenv("GEOLOC_DEVICE")
        reset_settings()
        assert get_settings().device == "auto" and method_context().device == "auto"
    finally:
        reset_settings()
