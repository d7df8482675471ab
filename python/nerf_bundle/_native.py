"""nerf-render's CPU work in Rust, where ``nerf_bundle_native`` is installed (``scripts/setup.sh``
builds it from ``python/native``): the marching loop (nerf-core's ``grid::render_rays_in``, the
loop nerf-render runs; its samples, field calls and compositing are :func:`_render.march_grid`'s,
only the field's calls run in Python, the rest with the GIL released) and the hash encoding of
a split hash-grid graph (:func:`hash_encoder`)."""
from __future__ import annotations

import time
from typing import Any, Optional

import numpy as np

from . import _render as R
from ._validate import BundleError

F32 = np.float32
#: The version of ``nerf_bundle_native``'s functions this module calls (its ``INTERFACE``).
INTERFACE = 1
#: Rays the Rust loop marches at a time, as two halves taking turns: one half marches and
#: composites while the field evaluates the other's round. Its rounds' arrays (≈ 16 MB) stay
#: near the caches; the whole frame at once was slower (lego-ngp, 400×400, AMD EPYC, one run each:
#: loop 0.10–0.18 s at 32,768 rays, 0.11–0.16 s at 16,384, 0.19–0.25 s at 4,096 without halves,
#: 0.24–0.30 s the whole frame at once without halves).
PASS_RAYS = 32768


def _load() -> Optional[Any]:
    try:
        import nerf_bundle_native as ext
    except ImportError:
        return None
    return ext if getattr(ext, "INTERFACE", None) == INTERFACE else None


_EXT = _load()
#: How to get the native loop (errors name it).
HOW_TO_BUILD = ("`bash scripts/setup.sh` builds it into the project's venv; elsewhere, cargo build --release --manifest-path "
                "python/native/Cargo.toml and copy libnerf_bundle_native.so into site-packages as nerf_bundle_native.abi3.so")


def available() -> bool:
    """Whether the native loop is installed (and of the interface this package calls)."""
    return _EXT is not None


def hash_encoder(path: str, model: bytes) -> Optional[Any]:
    """The ``HashEncoder`` of the field graph ``model`` (read from ``path``): a hash-grid graph
    split as nerf-render splits it, the hash grid and the harmonics in Rust (the core's
    encodings, which training uses) and the head for onnxruntime, whose ``Gather`` of the
    table's rows is most of the whole graph's time on a CPU; None without the native module or
    where the graph is not a hash-grid field that can be cut (it runs whole)."""
    if _EXT is None:
        return None
    try:
        return _EXT.HashEncoder.of_graph(path, model)
    except ValueError as e:
        raise BundleError(str(e)) from None


def _native_grid(grid: R.Grid) -> Any:
    """``grid`` as the extension's Grid, made once per grid (its skip tables are kept with it)."""
    with R._GRID_CACHE_LOCK:
        made = grid.__dict__.get("_native")
        if made is None:
            made = grid.__dict__["_native"] = _EXT.Grid(np.ascontiguousarray(grid.occupied, bool), grid.resolution,
                                                        float(grid.bound), grid.contraction)
        return made


def march_grid(field: R.FieldFn, grid: R.Grid, o: np.ndarray, d: np.ndarray, view: np.ndarray, near: np.float32,
               far: np.float32, steps: int, min_transmittance: Optional[float], white_background: bool, batch: int,
               stages: Optional[R.Stages] = None) -> R.Marched:
    """:func:`_render.march_grid` in Rust, for rays ``o``, ``d`` [n, 3] whose field directions
    are ``view`` [n, 3] (not yet normalised: Rust normalises them as nerf-render does), in
    passes of ``PASS_RAYS`` rays. A round's points reach ``field`` in blocks of at most ``batch``
    × ``MARCH_SEGMENT`` and ``ROUND_BLOCK``, as in numpy. ``stages``: the field calls under
    ``field``, the rest of the loop (marching, packing, compositing) under ``march``."""
    if _EXT is None:
        raise RuntimeError(f"the native loop (nerf_bundle_native, interface {INTERFACE}) is not installed: {HOW_TO_BUILD}")
    stages = stages if stages is not None else R.Stages()
    stages.native = True
    block = max(1, min(batch * R.MARCH_SEGMENT, R.ROUND_BLOCK))
    in_field = 0.0

    def call(points: np.ndarray, dirs: np.ndarray) -> Any:
        nonlocal in_field
        start = time.perf_counter()
        n = len(points)
        if n <= block:
            c, sg = field(points, dirs)
            out = (np.ascontiguousarray(c, F32), np.ascontiguousarray(sg, F32).reshape(-1))
        else:
            rgb, sigma = np.empty((n, 3), F32), np.empty(n, F32)
            for s in range(0, n, block):
                rgb[s:s + block], sigma[s:s + block] = field(points[s:s + block], dirs[s:s + block])
            out = (rgb, sigma)
        in_field += time.perf_counter() - start
        return out

    start = time.perf_counter()
    min_t = None if min_transmittance is None else float(min_transmittance)
    rgb, depth, acc = _EXT.march_grid(call, _native_grid(grid), np.asarray(o, F32), np.asarray(d, F32), np.asarray(view, F32),
                                      float(near), float(far), int(steps), min_t, bool(white_background), PASS_RAYS, True)
    stages.field += in_field
    stages.march += time.perf_counter() - start - in_field
    return R.Marched(rgb, depth, acc, None)
