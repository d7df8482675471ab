"""The marching loop on a GPU (CuPy, where it is installed): :func:`_render.march_grid`'s
samples, field calls and compositing, with the rays' state, the field's inputs and its outputs
kept in GPU memory (onnxruntime's IO binding), so a frame moves nothing between host and
device but its rays and its pixels.

Each round, one GPU thread per live ray steps through its intervals, testing each with the
exact float32 cell of ``OccupancyGrid::cell`` (no skip tables: a GPU tests a frame's 330 M
intervals in about a millisecond), up to its next ``MARCH_SEGMENT`` occupied samples; the
samples are packed ray by ray, the field evaluates them in one call (pieces of
``points_per_run``), and one thread per ray composites its samples in order with
``RayAccumulator::add``'s float32 operations (compiled without fused multiply-adds, ``exp``
in double rounded to float as :func:`_render.expf`). A ray goes on while T ≥
``min_transmittance`` and its segment was full: the samples, calls and pixels of the CPU loop.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Optional

import numpy as np

from . import _render as R
from ._validate import BundleError

F32 = np.float32

#: The kernels (shared with nerf-render's GPU loop), compiled after ``#define SEGMENT``.
KERNELS = Path(__file__).with_name("march.cu")


_THREADS = 128


def cupy_or_none() -> Optional[Any]:
    """The ``cupy`` module, or None where it is not installed or sees no GPU."""
    try:
        import cupy
    except ImportError:
        return None
    try:
        cupy.cuda.runtime.getDeviceCount()
    except Exception:  # cupy's CUDA errors: no driver, no device
        return None
    return cupy


class GpuLoop:
    """The kernels (compiled once per process by NVRTC, cached on disk by CuPy) and the padded
    grid on GPU ``gpu``."""

    def __init__(self, cupy: Any, gpu: int, grid: R.Grid) -> None:
        if grid.contraction is not None:
            raise ValueError("the GPU loop does not march contracted grids yet")
        self.cp = cupy
        self.gpu = gpu
        with cupy.cuda.Device(gpu):
            source = f"#define SEGMENT {R.MARCH_SEGMENT}\n" + KERNELS.read_text()
            module = cupy.RawModule(code=source, options=("--fmad=false",))
            self.kernels = {name: module.get_function(name) for name in ("march", "emit", "composite")}
            self.padded = cupy.asarray(grid.padded().reshape(-1).astype(np.uint8))
        self.side = grid.resolution + 2
        self.bound = F32(grid.bound)
        self.resolution = F32(grid.resolution)

    def _launch(self, name: str, m: int, *args: Any) -> None:
        self.kernels[name](((m + _THREADS - 1) // _THREADS,), (_THREADS,), args)

    def march_grid(self, graph: Any, o: np.ndarray, d: np.ndarray, viewdirs: np.ndarray, near: np.float32, far: np.float32,
                   steps: int, min_transmittance: Optional[float], white_background: bool,
                   stages: Optional[R.Stages] = None) -> R.Marched:
        """:func:`_render.march_grid` for rays ``o``, ``d`` and unit ``viewdirs`` [n, 3] on the GPU,
        the field ``graph`` (a :class:`_field.Graph` on the same GPU) evaluated through IO
        binding, a call per round."""
        cp, stages = self.cp, stages if stages is not None else R.Stages()
        n = len(o)
        interval = F32((far - near) / F32(steps))
        delta = (interval * R.lengths(d)).astype(F32)
        min_t = F32(-np.inf) if min_transmittance is None else F32(min_transmittance)
        now = time.perf_counter()
        with cp.cuda.Device(self.gpu):
            o_g, d_g, v_g = (cp.asarray(np.ascontiguousarray(a, F32)) for a in (o, d, viewdirs))
            delta_g = cp.asarray(delta)
            cursor = cp.zeros(n, cp.int32)
            trans = cp.ones(n, cp.float32)
            rgb = cp.zeros((n, 3), cp.float32)
            depth = cp.zeros(n, cp.float32)
            acc = cp.zeros(n, cp.float32)
            most = n * R.MARCH_SEGMENT
            ks = cp.empty(most, cp.int32)
            points, dirs = cp.empty((most, 3), cp.float32), cp.empty((most, 3), cp.float32)
            ts, sigma, colour = cp.empty(most, cp.float32), cp.empty(most, cp.float32), cp.empty((most, 3), cp.float32)
            active = cp.arange(n, dtype=cp.int32)
            grid_args = (self.padded, np.int32(self.side), self.bound, F32(2) * self.bound, self.resolution)
            while active.size:
                m = int(active.size)
                counts = cp.empty(m, cp.int32)
                self._launch("march", m, active, np.int32(m), o_g, d_g, cursor, np.int32(steps), F32(near), interval,
                             *grid_args, ks, counts)
                offsets = cp.zeros(m + 1, cp.int64)
                offsets[1:] = cp.cumsum(counts, dtype=cp.int64)
                total = int(offsets[-1])  # waits for the marching
                now = stages.lap("march", now)
                if total == 0:
                    break
                self._launch("emit", m, active, np.int32(m), ks, counts, offsets, o_g, d_g, v_g, F32(near), interval,
                             points, dirs, ts)
                cp.cuda.get_current_stream().synchronize()
                now = stages.lap("gather", now)
                self._field(graph, points, dirs, colour, sigma, total)
                now = stages.lap("field", now)
                keep = cp.empty(m, cp.bool_)
                self._launch("composite", m, active, np.int32(m), counts, offsets, sigma, colour, ts, delta_g, trans, rgb,
                             depth, acc, min_t, keep)
                active = active[keep]  # waits for the compositing
                now = stages.lap("composite", now)
            out = cp.asnumpy(rgb)
            depth_h, acc_h = cp.asnumpy(depth), cp.asnumpy(acc)
        if white_background:
            out += (F32(1) - acc_h)[:, None]
        stages.lap("composite", now)
        return R.Marched(out, depth_h, acc_h, None)

    def _field(self, graph: Any, points: Any, dirs: Any, colour: Any, sigma: Any, total: int) -> None:
        """The graph on the first ``total`` rows of the GPU buffers, pieces of
        ``graph.points_per_run`` points, outputs written in place."""
        start = time.perf_counter()
        session, piece = graph.sessions[0], graph.points_per_run
        for s in range(0, total, piece):
            k = min(piece, total - s)
            io = session.io_binding()
            for name, buf, width in (("points", points, 3), ("viewdirs", dirs, 3)):
                io.bind_input(name, "cuda", self.gpu, np.float32, (k, width), buf[s:s + k].data.ptr)
            io.bind_output("rgb", "cuda", self.gpu, np.float32, (k, 3), colour[s:s + k].data.ptr)
            io.bind_output("sigma", "cuda", self.gpu, np.float32, (k, 1), sigma[s:s + k].data.ptr)
            try:
                session.run_with_iobinding(io)
            except Exception as err:  # onnxruntime's own types
                raise BundleError(f"{graph.path}: onnxruntime failed on GPU {self.gpu} ({k} points): {err}") from None
        graph.seconds += time.perf_counter() - start
        graph.evaluated += total
