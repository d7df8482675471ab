"""The marching loop on a GPU (``_gpu``, CuPy) against the CPU loop: the same samples (points
evaluated) and the same pixels to 1e-5. Needs onnxruntime's CUDA build, CuPy and a GPU (the
device machine; CI has none: skipped there, with the reason)."""
from __future__ import annotations

import os
import warnings

import numpy as np
import onnxruntime as ort
import pytest

import nerf_bundle
from nerf_bundle import _gpu
from conftest import MODELS

pytestmark = pytest.mark.skipif("CUDAExecutionProvider" not in ort.get_available_providers() or _gpu.cupy_or_none() is None,
                                reason="needs onnxruntime's CUDA build, CuPy and a GPU")
#: A hash-grid bundle (the portable lowering runs wholly on the GPU; the default one works too).
BUNDLE = os.environ.get("NERF_GPU_BUNDLE", str(MODELS / "lego-ngp"))


def _open(device: str) -> nerf_bundle.Bundle:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the bitwise lowering's note on a GPU
        return nerf_bundle.Bundle.open(BUNDLE, device=device)


def test_the_gpu_loop_renders_the_cpu_loops_frame():
    cpu, gpu = _open("cpu"), _open("cuda")
    assert gpu._gpu_loop is not None, "CuPy is there: the loop runs on the GPU"
    pose = cpu.poses("test")[0]
    a = cpu.render(pose, 160)
    b = gpu.render(pose, 160)
    assert cpu.graphs["field"].evaluated == gpu.graphs["field"].evaluated, "the same samples"
    assert np.abs(a.raw - b.raw).max() <= 1e-5


def test_degenerate_and_missing_rays_match():
    cpu, gpu = _open("cpu"), _open("cuda")
    rng = np.random.default_rng(7)
    o = rng.uniform(-4, 4, (4096, 3)).astype(np.float32)
    d = rng.normal(size=(4096, 3)).astype(np.float32)
    d[:8] = 0.0  # no direction: one point, tested at every step
    d[8:16, 1:] = 0.0  # along an axis
    o[16:24] = 100.0  # far outside the cube
    b, r = float(gpu.grid.bound), gpu.grid.resolution
    o[24:32, 0] = np.float32(-b + 2 * b * (r // 3) / r)  # on a cell face
    d[24:32, 0] = 0.0  # and staying on it
    a = cpu.render_rays(o, d)
    b = gpu.render_rays(o, d)
    for x, y in ((a.rgb, b.rgb), (a.depth, b.depth), (a.acc, b.acc)):
        assert np.allclose(x, y, atol=1e-5, rtol=0, equal_nan=True)
    assert cpu.graphs["field"].evaluated == gpu.graphs["field"].evaluated
