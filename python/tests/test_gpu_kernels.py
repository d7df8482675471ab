"""The GPU loop's kernels (``nerf_bundle/march.cu``) compiled for the CPU with the system's C++
compiler (no fused multiply-adds, as NVRTC is told) and launched thread by thread through a
numpy stand-in for CuPy: :class:`_gpu.GpuLoop` then renders the frame of the numpy loop
(:func:`_render.march_grid`), sample for sample and bit for bit. So the kernels and the loop
around them are tested where there is no GPU; test_gpu_loop.py runs them on one."""
from __future__ import annotations

import ctypes
import shutil
import subprocess
import types
from pathlib import Path

import numpy as np
import pytest

import nerf_bundle
from nerf_bundle import _gpu
from nerf_bundle import _render as R
from conftest import MODELS

CXX = shutil.which("g++") or shutil.which("c++")
pytestmark = pytest.mark.skipif(CXX is None, reason="needs a C++ compiler")

# CUDA's names for the thread index and qualifiers, on the CPU: one "thread" per call.
_PRELUDE = """
#include <math.h>
#define __device__
#define __global__
#define __forceinline__ inline
struct Dim { int x; };
static Dim blockIdx = {0}, blockDim = {1}, threadIdx = {0};
extern "C" void set_thread(int i) { threadIdx.x = i; }
"""


class _Kernel:
    def __init__(self, lib: ctypes.CDLL, name: str) -> None:
        self.lib, self.fn = lib, getattr(lib, name)

    def __call__(self, grid: tuple, block: tuple, args: tuple) -> None:
        converted = []
        for a in args:
            if isinstance(a, np.ndarray):
                converted.append(ctypes.c_void_p(a.ctypes.data))
            elif isinstance(a, np.float32):
                converted.append(ctypes.c_float(a))
            elif isinstance(a, np.int32):
                converted.append(ctypes.c_int(a))
            else:
                raise TypeError(f"kernel argument of type {type(a)}")
        for i in range(grid[0] * block[0]):
            self.lib.set_thread(i)
            self.fn(*converted)


def _fake_cupy(tmp: Path) -> types.SimpleNamespace:
    """numpy under CuPy's names, with RawModule compiling for the CPU."""

    class RawModule:
        def __init__(self, code: str, options: tuple) -> None:
            assert "--fmad=false" in options, "no fused multiply-adds: the float32 arithmetic of the CPU loop"
            src, lib = tmp / "kernels.cpp", tmp / "kernels.so"
            src.write_text(_PRELUDE + code)
            subprocess.run([CXX, "-O1", "-ffp-contract=off", "-shared", "-fPIC", "-o", str(lib), str(src)], check=True)
            self.lib = ctypes.CDLL(str(lib))

        def get_function(self, name: str) -> _Kernel:
            return _Kernel(self.lib, name)

    class Device:
        def __init__(self, gpu: int) -> None:
            pass

        def __enter__(self) -> "Device":
            return self

        def __exit__(self, *exc: object) -> None:
            pass

    stream = types.SimpleNamespace(synchronize=lambda: None)
    cuda = types.SimpleNamespace(Device=Device, get_current_stream=lambda: stream)
    return types.SimpleNamespace(RawModule=RawModule, cuda=cuda, asarray=np.asarray, asnumpy=np.asarray, zeros=np.zeros,
                                 ones=np.ones, empty=np.empty, arange=np.arange, cumsum=np.cumsum, float32=np.float32,
                                 int32=np.int32, int64=np.int64, bool_=np.bool_)


def _numpy_field(loop: _gpu.GpuLoop, graph, points, dirs, colour, sigma, total: int) -> None:
    rgb, s = graph(points[:total], dirs[:total])
    colour[:total], sigma[:total] = rgb, s
    graph.evaluated += 0  # graph() counted them


def test_the_kernels_render_the_numpy_loops_frame(tmp_path, monkeypatch):
    bundle = nerf_bundle.Bundle.open(MODELS / "lego-ngp", threads=1, loop="numpy")
    loop = _gpu.GpuLoop(_fake_cupy(tmp_path), 0, bundle.grid)
    monkeypatch.setattr(_gpu.GpuLoop, "_field", _numpy_field)
    pose = bundle.poses("test")[0]
    expected = bundle.render(pose, 48)
    evaluated = bundle.graphs["field"].evaluated
    bundle._gpu_loop = loop
    got = bundle.render(pose, 48)
    assert bundle.graphs["field"].evaluated == 2 * evaluated, "the same samples"
    assert evaluated > 48 * 48, "the view sees the model"
    np.testing.assert_array_equal(got.raw, expected.raw)


def test_the_kernels_march_degenerate_rays_as_the_numpy_loop(tmp_path, monkeypatch):
    """Rays without a direction, along axes and cell faces, outside the cube, random: the
    samples of every interval tested (:func:`_render.occupied_samples`) and equal pixels."""
    bundle = nerf_bundle.Bundle.open(MODELS / "lego-ngp", threads=1, loop="numpy")
    monkeypatch.setattr(_gpu.GpuLoop, "_field", _numpy_field)
    rng = np.random.default_rng(3)
    # From a sphere of radius 4 towards points near the model.
    o = rng.normal(size=(600, 3))
    o *= 4 / np.linalg.norm(o, axis=1, keepdims=True)
    o = o.astype(np.float32)
    d = rng.uniform(-0.6, 0.6, (600, 3)) - o
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    d[:8] = 0.0
    d[8:16, 1:] = 0.0
    o[16:24] = 100.0
    b, r = float(bundle.grid.bound), bundle.grid.resolution
    o[24:40, 0] = np.float32(-b + 2 * b * (r // 3) / r)
    d[24:40, 0] = 0.0
    o[40:48, 1] = np.float32(-b + 2 * b * (r // 2) / r)
    d[40:48, 1] = 0.0
    expected = bundle.render_rays(o, d)
    bundle._gpu_loop = _gpu.GpuLoop(_fake_cupy(tmp_path), 0, bundle.grid)
    got = bundle.render_rays(o, d, chunk=128)  # batches of rays, one after the other
    for x, y in ((expected.rgb, got.rgb), (expected.depth, got.depth), (expected.acc, got.acc)):
        np.testing.assert_array_equal(x, y)
    near, far, steps = bundle.near, bundle.far, bundle.march_steps
    packed = R.occupied_samples(bundle.grid, o, d, near, far, steps)
    assert (np.diff(packed.offsets) > 0).sum() > 100, "many rays have samples"
