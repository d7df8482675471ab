"""The native module (``nerf_bundle_native``). Its marching loop (nerf-core's, in Rust) against
the numpy loop: the same points evaluated, pixels equal to float32 rounding (the loops' exp:
glibc's ``expf`` in Rust, float64 rounded in numpy, at most an ulp apart), on bundles and on
awkward rays; errors from the field and bad arrays reach the caller. Its hash encoder (a
hash-grid graph split as nerf-render splits it) against the whole graph. (Against nerf-render:
test_native.py and test_contracted.py, which render with the defaults.)"""
from __future__ import annotations

import os

import numpy as np
import pytest

import nerf_bundle
from nerf_bundle import _native
from nerf_bundle import _render as R
from conftest import MODELS, REPO, assert_same_points

F32 = np.float32
CONTRACTED = REPO / "viewer" / "tests" / "fixtures" / "ngp-contracted"
#: Pixels of the two loops (rgb, depth, acc): float32 rounding of an α an ulp apart.
TOL = 2e-6

needs_native = pytest.mark.skipif(not _native.available() and os.environ.get("NERF_REQUIRE_NATIVE") != "1",
                                  reason="nerf_bundle_native is not installed (scripts/setup.sh builds it)")


def test_the_native_loop_is_there_where_setup_built_it():
    """scripts/test.sh sets NERF_REQUIRE_NATIVE=1: there, a missing or stale module fails."""
    if os.environ.get("NERF_REQUIRE_NATIVE") != "1":
        pytest.skip("NERF_REQUIRE_NATIVE is not set")
    assert _native.available(), _native.HOW_TO_BUILD
    assert nerf_bundle.Bundle.open(MODELS / "spheres", threads=1).loop == "native"


class Recording:
    """``graph`` with the points of each call logged."""

    def __init__(self, graph, log: list) -> None:
        self.graph, self.sessions, self.log = graph, graph.sessions, log

    def __call__(self, points, dirs):
        self.log.append(np.concatenate([points, dirs], axis=1))
        return self.graph(points, dirs)


@needs_native
@pytest.mark.parametrize("bundle_path,width,chunk", [
    (MODELS / "lego-ngp", 60, 500),
    (MODELS / "lego-ngp", 40, 4096),
    (MODELS / "spheres", 48, 300),
    (CONTRACTED, 48, 700),
])
def test_both_loops_evaluate_the_same_points_and_give_the_same_pixels(bundle_path, width, chunk, monkeypatch):
    frames, calls = {}, {}
    for loop in ("numpy", "native"):
        bundle = nerf_bundle.Bundle.open(bundle_path, threads=1, loop=loop, whole_graph=True)
        graph = bundle._graph("fine" if bundle.n_fine > 0 else "coarse")
        calls[loop] = []
        monkeypatch.setattr(bundle, "_graph", lambda stage, g=graph, log=calls[loop]: Recording(g, log))
        frames[loop] = bundle.render(bundle.poses("test")[0], width, chunk=chunk)
        assert frames[loop].stages.native == (loop == "native")
    assert_same_points(calls["native"], calls["numpy"], min(chunk * R.MARCH_SEGMENT, R.ROUND_BLOCK))
    diff = np.abs(frames["native"].raw - frames["numpy"].raw).max()
    assert diff <= TOL, diff
    assert frames["native"].acc.max() > 0.5, "the view sees the scene"
    assert frames["native"].stages.march > 0 and frames["native"].field_seconds > 0


def awkward_rays(bound: float, resolution: int):
    """Rays without a direction, along axes and cell faces, from outside the cube, and random
    ones towards the model (as test_gpu_kernels' degenerate rays)."""
    rng = np.random.default_rng(5)
    o = rng.normal(size=(700, 3))
    o *= 4 / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.6, 0.6, (700, 3)) - o
    o, d = o.astype(F32), d.astype(F32)
    d[:8] = 0.0
    d[8:16, 1:] = 0.0
    o[16:24] = 100.0
    o[24:40, 0] = F32(-bound + 2 * bound * (resolution // 3) / resolution)
    d[24:40, 0] = 0.0
    d[40:48] *= F32(1e-6)
    return o, d


def stand_in_field(points, dirs):
    """A field of numpy arithmetic only: dense shells, colours from position and direction."""
    sigma = (np.sin(points.sum(axis=1) * F32(9)) * F32(40)).astype(F32)
    rgb = np.abs(np.cos(points * F32(3) + dirs)).astype(F32)
    return rgb, sigma


@needs_native
@pytest.mark.parametrize("contraction", [None, "linf"])
def test_awkward_rays_march_alike(contraction):
    rng = np.random.default_rng(11)
    r = 16
    bound = F32(2) if contraction else F32(1.5)
    grid = R.Grid(rng.uniform(size=r ** 3) < 0.3, r, bound, contraction)
    o, d = awkward_rays(float(bound), r)
    logs = {"numpy": [], "native": []}

    def field(name):
        def call(points, dirs):
            # A ray without a direction has none to see along (NaN), in both loops.
            logs[name].append(np.nan_to_num(np.concatenate([points, dirs], axis=1), nan=9.0))
            return stand_in_field(points, dirs)
        return call

    with np.errstate(all="ignore"):
        want = R.march_grid(field("numpy"), grid, o, d, R.unit(d), F32(0.1), F32(8), 128, float(R.MIN_TRANSMITTANCE), False, 64)
    got = _native.march_grid(field("native"), grid, o, d, d, F32(0.1), F32(8), 128, float(R.MIN_TRANSMITTANCE), False, 64)
    assert_same_points(logs["native"], logs["numpy"], 64 * R.MARCH_SEGMENT)
    for a, b in ((got.rgb, want.rgb), (got.depth, want.depth), (got.acc, want.acc)):
        assert np.array_equal(np.isnan(a), np.isnan(b))
        assert np.nanmax(np.abs(a - b)) <= TOL
    assert (got.acc > 0.5).sum() > 50, "rays cross occupied cells"


@needs_native
def test_overlap_and_passes_do_not_move_a_pixel():
    """The Rust loop's passes and its two halves taking turns give the same pixels, bit for bit."""
    ext = _native._EXT
    rng = np.random.default_rng(2)
    grid = R.Grid(rng.uniform(size=12 ** 3) < 0.4, 12, F32(1.5))
    o, d = awkward_rays(1.5, 12)
    native_grid = ext.Grid(grid.occupied, 12, 1.5, None)
    frames = [ext.march_grid(stand_in_field, native_grid, o, d, d, 0.1, 8.0, 96, 1e-4, True, rays, overlap)
              for rays, overlap in ((700, False), (700, True), (64, True), (1, False))]
    for frame in frames[1:]:
        for a, b in zip(frame, frames[0]):
            assert np.array_equal(a, b, equal_nan=True)


@needs_native
def test_field_errors_and_bad_arrays_reach_the_caller():
    grid = R.Grid(np.ones(8, bool), 2, F32(1.5))
    o = np.zeros((4, 3), F32)
    d = np.tile(np.array([[0, 0, 1]], F32), (4, 1))
    o[:, 2] = -4

    def broken(points, dirs):
        raise KeyError("the field broke")

    with pytest.raises(KeyError, match="the field broke"):
        _native.march_grid(broken, grid, o, d, d, F32(0.1), F32(8), 64, 1e-4, False, 16)
    with pytest.raises(ValueError, match=r"the field gave rgb \[3, 3\]"):
        _native.march_grid(lambda p, v: (np.zeros((3, 3), F32), np.zeros(len(p), F32)), grid, o, d, d, F32(0.1), F32(8), 64,
                           1e-4, False, 16)
    ext = _native._EXT
    with pytest.raises(ValueError, match="origins"):
        ext.march_grid(stand_in_field, ext.Grid(grid.occupied, 2, 1.5, None), o[:, :2], d, d, 0.1, 8.0, 64, 1e-4, False, 16, False)
    with pytest.raises(ValueError, match="one of each per ray"):
        ext.march_grid(stand_in_field, ext.Grid(grid.occupied, 2, 1.5, None), o, d[:3], d, 0.1, 8.0, 64, 1e-4, False, 16, False)
    with pytest.raises(ValueError, match="7 occupancy flags for a 2³ grid"):
        ext.Grid(np.ones(7, bool), 2, 1.5, None)
    with pytest.raises(ValueError, match="only \"linf\""):
        ext.Grid(np.ones(8, bool), 2, 1.5, "l2")
    with pytest.raises(ValueError, match="bound"):
        ext.Grid(np.ones(8, bool), 2, float("nan"), None)


def test_the_loop_option(monkeypatch):
    with pytest.raises(ValueError, match="loop='fast'"):
        nerf_bundle.Bundle.open(MODELS / "spheres", loop="fast")
    assert nerf_bundle.Bundle.open(MODELS / "spheres", threads=1, loop="numpy").loop == "numpy"
    monkeypatch.setattr(_native, "_EXT", None)
    with pytest.raises(ValueError, match="not installed.*scripts/setup.sh"):
        nerf_bundle.Bundle.open(MODELS / "spheres", loop="native")
    assert nerf_bundle.Bundle.open(MODELS / "spheres", threads=1).loop == "numpy", "without it, numpy"


@needs_native
def test_the_split_field_is_the_whole_graph():
    """The hash grid and harmonics in Rust, the head in onnxruntime: the whole graph's outputs,
    on points inside the box and past it, along any direction."""
    split = nerf_bundle.Bundle.open(MODELS / "lego-ngp", threads=2)
    whole = nerf_bundle.Bundle.open(MODELS / "lego-ngp", threads=2, whole_graph=True)
    assert split.graphs["field"].encoder is not None and whole.graphs["field"].encoder is None
    head = {i.name for i in split.graphs["field"].sessions[0].get_inputs()}
    assert head == {_native._EXT.HashEncoder.FEATURES, _native._EXT.HashEncoder.SH}
    rng = np.random.default_rng(4)
    points = rng.uniform(-2.0, 2.0, (5000, 3)).astype(F32)
    dirs = R.unit(rng.normal(size=(5000, 3)).astype(F32))
    (rgb_a, sigma_a), (rgb_b, sigma_b) = split.field(points, dirs), whole.field(points, dirs)
    assert np.abs(rgb_a - rgb_b).max() <= 1e-6
    assert np.abs(sigma_a - sigma_b).max() <= 1e-6 * max(1.0, float(np.abs(sigma_b).max()))
    assert sigma_b.max() > 10, "some points lie in the model"
    pose = split.poses("test")[0]
    assert np.abs(split.render(pose, 40).raw - whole.render(pose, 40).raw).max() <= 1e-5
    # Not a hash grid: the MLP bundle's graphs run whole.
    assert all(g.encoder is None for g in nerf_bundle.Bundle.open(MODELS / "lego", threads=1).graphs.values())
    with pytest.raises(ValueError, match="points"):
        split.graphs["field"].encoder.encode(points[:, :2], dirs)
