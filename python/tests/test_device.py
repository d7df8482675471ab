"""device="cpu" | "cuda[:N]": without onnxruntime's CUDA build (CI's CPU wheel) a clear
BundleError, never a CPU session in disguise; and the bench command."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import onnxruntime as ort
import pytest

import nerf_bundle
from conftest import MODELS, REPO, sessions_that_say_cuda

CUDA = "CUDAExecutionProvider" in ort.get_available_providers()


@pytest.mark.skipif(CUDA, reason="this onnxruntime has the CUDA provider")
def test_cuda_without_the_gpu_wheel_says_what_to_install():
    with pytest.raises(nerf_bundle.BundleError) as e:
        nerf_bundle.Bundle.open(MODELS / "lego-ngp", device="cuda:1")
    message = str(e.value)
    assert "cuda:1" in message and "no CUDAExecutionProvider" in message
    assert "onnxruntime-gpu==1.31.1" in message and "setup.sh --gpu" in message and "venv-gpu" in message


def test_a_session_that_is_not_on_the_gpu_is_refused(monkeypatch):
    """onnxruntime hands back a CPU session when the CUDA provider cannot start: the package
    checks the session's providers and names the graph file."""
    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"])
    real = ort.InferenceSession

    def cpu_only(model, opts, providers=None, **kw):
        assert providers == [("CUDAExecutionProvider", {"device_id": 0, "use_tf32": 0})], "TF32 off, GPU 0"
        assert kw.get("enable_fallback") == 0, "onnxruntime's fall-back to the CPU is off"
        return real(model, opts, providers=["CPUExecutionProvider"])

    monkeypatch.setattr(ort, "InferenceSession", cpu_only)
    with pytest.raises(nerf_bundle.BundleError) as e:
        nerf_bundle.Bundle.open(MODELS / "lego-ngp", device="cuda")
    assert "field.onnx" in str(e.value) and "did not start its CUDA provider" in str(e.value)

    def failing(model, opts, providers=None, **kw):
        raise RuntimeError("CUDA failure 100: no CUDA-capable device is detected")

    monkeypatch.setattr(ort, "InferenceSession", failing)
    with pytest.raises(nerf_bundle.BundleError) as e:
        nerf_bundle.Bundle.open(MODELS / "lego-ngp", device="cuda")
    assert "field.onnx" in str(e.value) and "no CUDA-capable device" in str(e.value)


def test_bad_devices_and_options():
    for bad in ["gpu", "cuda:x", "cuda:-1", "CUDA", "cuda:", "cuda:+1"]:
        with pytest.raises(ValueError, match="expected cpu, cuda or cuda:N"):
            nerf_bundle.Bundle.open(MODELS / "spheres", device=bad)
    with pytest.raises(ValueError, match="pass one of them"):
        nerf_bundle.Bundle.open(MODELS / "spheres", device="cpu", providers=["CPUExecutionProvider"])
    assert nerf_bundle.Bundle.open(MODELS / "spheres", device="cpu", threads=1).device == "cpu"


def run_cli(*args: str) -> subprocess.CompletedProcess:
    env = {"PYTHONPATH": str(REPO / "python"), "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-m", "nerf_bundle", *args], capture_output=True, text=True, env=env, cwd=REPO)


def test_bench_prints_the_split_and_parity_as_json():
    done = run_cli("bench", str(MODELS / "lego-ngp"), "--width", "24", "--repeat", "2", "--threads", "1", "--parity", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["device"] == "cpu" and (out["width"], out["height"]) == (24, 24) and len(out["frames"]) == 2
    for f in out["frames"]:
        assert f["onnxruntime_s"] > 0 and abs(f["total_s"] - f["onnxruntime_s"] - f["outside_s"]) < 2e-4
        assert sum(f["stages_s"].values()) <= f["outside_s"] + 1e-3 and f["stages_s"]["march"] > 0
    assert out["parity_vs_cpu"]["max_abs"] == 0.0, "the CPU provider against itself"
    from nerf_bundle import _native
    if _native.available():
        assert (out["loop"], out["encoding"]) == ("native", "rust")
    done = run_cli("bench", str(MODELS / "lego-ngp"), "--width", "24", "--repeat", "1", "--loop", "numpy", "--whole-graph", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert (out["loop"], out["encoding"]) == ("numpy", "graph")
    assert out["frames"][0]["stages_s"]["composite"] > 0, "the numpy loop's stages apart"


@pytest.mark.skipif(CUDA, reason="this onnxruntime has the CUDA provider")
def test_bench_on_cuda_without_the_gpu_wheel_is_an_error_without_a_traceback():
    done = run_cli("bench", str(MODELS / "lego-ngp"), "--device", "cuda")
    assert done.returncode == 1 and done.stderr.startswith("error: device cuda:0") and "Traceback" not in done.stderr
    done = run_cli("bench", str(MODELS / "lego-ngp"), "--device", "tpu")
    assert done.returncode == 2 and "expected cpu, cuda or cuda:N" in done.stderr and "Traceback" not in done.stderr


def test_op_types_tell_the_bitwise_lowering_from_the_portable_one():
    """What `device="cuda"` warns about: the default lowering's BitwiseXor (no CUDA kernel)."""
    from nerf_bundle._onnx import op_types
    root = Path(__file__).resolve().parents[2]
    bitwise = op_types((root / "models/lego-ngp/field.onnx").read_bytes())
    portable = op_types((root / "viewer/tests/fixtures/ngp-portable/field.onnx").read_bytes())
    assert "BitwiseXor" in bitwise and {"Gather", "MatMul"} <= bitwise
    assert "BitwiseXor" not in portable and {"Gather", "MatMul"} <= portable


def test_without_cupy_the_loop_stays_on_the_cpu_and_says_so(monkeypatch):
    sessions_that_say_cuda(monkeypatch)
    monkeypatch.setitem(sys.modules, "cupy", None)  # `import cupy` fails
    with pytest.warns(UserWarning, match="CuPy is not installed.*runs on the CPU"):
        bundle = nerf_bundle.Bundle.open(MODELS / "lego-ngp", device="cuda")
    assert bundle._gpu_loop is None
    assert bundle.render(bundle.poses("test")[0], 16).rgb.shape == (16, 16, 3)


def test_kernels_that_cannot_start_leave_the_loop_in_numpy(monkeypatch):
    """A CuPy whose compiler fails (no NVRTC, an old driver): a warning with its error."""
    from nerf_bundle import _gpu

    sessions_that_say_cuda(monkeypatch)
    monkeypatch.setattr(_gpu, "cupy_or_none", lambda: object())

    def failing(self, cupy, gpu, grid):
        raise RuntimeError("nvrtc: libnvrtc.so.13 not found")

    monkeypatch.setattr(_gpu.GpuLoop, "__init__", failing)
    with pytest.warns(UserWarning, match="kernels cannot start.*libnvrtc.so.13"):
        bundle = nerf_bundle.Bundle.open(MODELS / "lego-ngp", device="cuda")
    assert bundle._gpu_loop is None
