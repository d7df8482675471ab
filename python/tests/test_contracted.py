"""Contracted bundles (``nerf-rs-scene-3``, ``NERFOCC2``): the contraction and the marching
segments by hand, marching equal bit for bit to testing every step of every segment one ray at a
time (core/src/render/grid.rs's tests), the grid file and scene.json checks, and the fixture's
frames against nerf-render --npy."""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import nerf_bundle
from nerf_bundle import BundleError
from nerf_bundle import _render as R
from nerf_bundle._validate import read_grid
from conftest import REPO, assert_same_points, sessions_that_say_cuda

F32 = np.float32
FIXTURE = REPO / "viewer" / "tests" / "fixtures" / "ngp-contracted"
TOL = 1e-5


# -- the reference: every step of every segment, one ray at a time -------------------------------

def rust_max(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``f32::max``: a NaN operand gives the other."""
    return np.where(np.isnan(a), b, np.where(np.isnan(b), a, np.maximum(a, b)))


def contracted(p: np.ndarray) -> np.ndarray:
    """``Contraction::Linf.apply`` of points [S, 3], float32 in its order."""
    a = np.abs(p)
    n = rust_max(rust_max(a[:, 0], a[:, 1]), a[:, 2])
    m = np.where(n > 1, n, F32(1)).astype(F32)
    r = (F32(1) / m).astype(F32)
    f = ((F32(2) - r) * r).astype(F32)
    return (p * f[:, None]).astype(F32)


def segments_by_rule(near, far, steps: int) -> list:
    """``march_segments`` over a contracted grid, written out again."""
    n = max(steps // 4, 1)
    start, interval, out = F32(near), F32(F32(2) / F32(n)), []
    while True:
        out.append((start, interval, n))
        start = F32(start + F32(n) * interval)
        interval = F32(interval * F32(4))
        if not start < F32(far) or len(out) == 8:
            return out


def every_interval(grid: R.Grid, o: np.ndarray, d: np.ndarray, near, far, steps: int) -> R.Packed:
    """``march_ray_every_interval``: each step's point o + t·d contracted and tested with
    ``OccupancyGrid::cell``'s float32 arithmetic; δ = its segment's interval · ‖d‖."""
    b, r = grid.bound, grid.resolution
    ts, deltas, offsets = [], [], [0]
    with np.errstate(invalid="ignore", over="ignore"):
        for i in range(len(o)):
            x, y, z = d[i]
            norm = np.sqrt(F32(F32(x * x) + F32(y * y)) + F32(z * z))
            kept = 0
            for start, interval, n in segments_by_rule(near, far, steps):
                tk = (start + (np.arange(n, dtype=F32) + F32(0.5)) * interval).astype(F32)
                c = contracted((o[i][None, :] + tk[:, None] * d[i][None, :]).astype(F32))
                u = (c + b) / (F32(2) * b) * F32(r)
                inside = ((u >= 0) & (u < r)).all(axis=1)
                cell = np.where(inside[:, None], u, 0).astype(np.int64)
                keep = inside & grid.occupied[(cell[:, 0] * r + cell[:, 1]) * r + cell[:, 2]]
                ts.append(tk[keep])
                deltas.append(np.full(int(keep.sum()), F32(interval * norm), F32))
                kept += int(keep.sum())
            offsets.append(offsets[-1] + kept)
    return R.Packed(np.concatenate(ts), np.concatenate(deltas), np.array(offsets))


def assert_same_samples(grid: R.Grid, o, d, near, far, steps: int) -> R.Packed:
    with np.errstate(invalid="ignore", over="ignore"):
        got = R.occupied_samples(grid, o, d, F32(near), F32(far), steps)
    want = every_interval(grid, o, d, near, far, steps)
    assert np.array_equal(got.offsets, want.offsets), "samples per ray"
    assert np.array_equal(got.t, want.t), "sample distances, bit for bit"
    assert np.array_equal(got.delta, want.delta), "δ: the sample's segment's interval · ‖d‖"
    return want


def sparse_contracted_grid(seed: int, r: int = 32) -> R.Grid:
    """Occupied cells in a third of the blocks of 4³ cells, a fifth of those blocks' cells, over
    the contracted cube ±2: the inner cube and the shell both hold empty and occupied blocks."""
    rng = np.random.default_rng(seed)
    blocks = rng.random((r // 4 + 1,) * 3) < 0.35
    block = np.kron(blocks, np.ones((4, 4, 4), bool))[:r, :r, :r]
    return R.Grid((block & (rng.random((r,) * 3) < 0.2)).reshape(-1), r, F32(2), "linf")


# -- by hand ------------------------------------------------------------------------------------

def test_the_contraction_by_hand():
    p = np.array([[0.3, -1.0, 0.999], [2.0, -1.0, 0.5], [0.0, 0.0, -4.0], [1e30, -1e30, 0.0], [np.nan, 0.0, 0.0]], F32).T.copy()
    inside = p[:, 0].copy()
    R.contract(p)
    assert np.array_equal(p[:, 0], inside), "inside the cube ±1: unchanged, bit for bit"
    # ‖x‖∞ = 2: f = (2 − 0.5)·0.5 = 0.75; ‖x‖∞ = 4: f = 0.4375; far away: onto the face at 2.
    assert p[:, 1].tolist() == [1.5, -0.75, 0.375] and p[:, 2].tolist() == [0.0, 0.0, -1.75]
    assert p[:, 3].tolist() == [2.0, -2.0, 0.0] and np.isnan(p[0, 4])
    # A contracted grid of 4³ cells of side 1: (3, 0, 0) → (5/3, 0, 0) is cell (3, 2, 2); the
    # same point on an uncontracted grid of bound 2 lies outside.
    g = R.Grid(np.zeros(64, bool), 4, F32(2), "linf")
    g.occupied[(3 * 4 + 2) * 4 + 2] = True
    o, d = np.zeros((3, 1), F32), np.array([[1.0], [0.0], [0.0]], F32)
    assert g.occupied_along(o, d, np.array([[3.0], [0.5], [-3.0]], F32))[:, 0].tolist() == [True, False, False]
    flat = R.Grid(g.occupied, 4, F32(2))
    assert flat.occupied_along(o, d, np.array([[3.0], [1.5]], F32))[:, 0].tolist() == [False, True]


def test_segments_by_hand():
    # 1024 steps → segments of 256; the first interval 2/256; starts 0.1, 2.1, 10.1, 42.1, 170.1
    # (the next, 682.1, lies past far = 200).
    segs = R.march_segments(F32(0.1), F32(200), 1024, "linf")
    assert [s[1] for s in segs] == [0.0078125, 0.03125, 0.125, 0.5, 2.0]
    assert all(n == 256 for _, _, n in segs)
    assert np.allclose([s[0] for s in segs], [0.1, 2.1, 10.1, 42.1, 170.1], atol=1e-4, rtol=0)
    # Each start is the last plus 256 × its interval, in float32.
    assert segs[1][0] == F32(F32(0.1) + F32(2)) and segs[4][0] == F32(segs[3][0] + F32(128))
    assert segs == segments_by_rule(0.1, 200, 1024)
    assert R.march_segments(F32(0.1), F32(200), 1024, None) == [(F32(0.1), F32(F32(199.9) / F32(1024)), 1024)]
    assert len(R.march_segments(F32(0), F32(np.inf), 2, "linf")) == R.MAX_SEGMENTS
    assert R.march_segments(F32(0), F32(np.nan), 8, "linf") == [(0.0, 1.0, 2)]
    # The fixture's: near 1/30, far 100, 512 steps: 4 segments of 128, intervals 1/64 ... 1.
    fixture = R.march_segments(F32(0.033333335), F32(100), 512, "linf")
    assert [(s[1], s[2]) for s in fixture] == [(0.015625, 128), (0.0625, 128), (0.25, 128), (1.0, 128)]


def test_marching_steps_and_deltas_by_hand():
    # near 0, far 100, 8 steps: segments of 2 with intervals 1, 4, 16, 64 from 0, 2, 10, 42 (the
    # next, 170, lies past far). Steps at t = 0.5, 1.5 | 4, 8 | 18, 34 | 74, 138.
    g = R.Grid(np.ones(64, bool), 4, F32(2), "linf")
    o = np.array([[0.0, 0.5, 0.5]], F32)
    d = np.array([[2.0, 0.0, 0.0]], F32)
    m = R.Marcher(g, o, d, F32(0), F32(100), 8)
    assert m.steps == 8 and m.t[:8].tolist() == [0.5, 1.5, 4, 8, 18, 34, 74, 138]
    # Every point lies in the contracted cube: all kept; δ = interval · ‖d‖ = 2, 2, 8, 8, 32, ...
    p = R.occupied_samples(g, o, d, F32(0), F32(100), 8)
    assert p.t.tolist() == [0.5, 1.5, 4, 8, 18, 34, 74, 138]
    assert p.delta.tolist() == [2, 2, 8, 8, 32, 32, 128, 128]
    # Along x from (0, 0.5, 0.5) (x = t): only t = 0.5 lies in cell (2, 2, 2) (x in [0, 1));
    # every later point contracts into (3, 2, 2) (x = 1.5 → 1.5·8/9, y = 0.5·8/9: u = 3.33, 2.44).
    d = np.array([[1.0, 0.0, 0.0]], F32)
    for cell, t in [(2, [0.5]), (3, [1.5, 4, 8, 18, 34, 74, 138])]:
        occ = np.zeros(64, bool)
        occ[(cell * 4 + 2) * 4 + 2] = True
        p = R.occupied_samples(R.Grid(occ, 4, F32(2), "linf"), o, d, F32(0), F32(100), 8)
        assert p.t.tolist() == t and p.delta.tolist() == [1, 4, 4, 16, 16, 64, 64][-len(t):] if cell == 3 else [1]


# -- against the reference ----------------------------------------------------------------------

@pytest.mark.parametrize("seed", range(4))
def test_contracted_marching_equals_every_interval_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    r = int(rng.choice([32, 33, 64]))
    # Sparse blocks (large empty cubes), or a third of the cells at random (where a box in the
    # shell, reading the cells of uncontracted points, would be caught).
    grid = sparse_contracted_grid(seed, r) if seed % 2 == 0 else R.Grid(rng.random(r ** 3) < 0.3, r, F32(2), "linf")
    n = 500

    def u(*shape):
        return rng.uniform(-1, 1, shape)

    # Cameras inside the inner cube looking anywhere, and a quarter from far outside it, half
    # of those aimed into the inner cube (through the shell towards it).
    far_out = np.arange(n) % 4 == 0
    o = np.where(far_out[:, None], u(n, 3) * 30, u(n, 3)).astype(F32)
    d = (u(n, 3) * 1.3).astype(F32)
    aimed = np.arange(n) % 8 == 0
    d[aimed] = ((u(n, 3)[aimed] - o[aimed]) / 20).astype(F32)
    # A few degenerate rays: no direction, NaN, infinite.
    d[1], o[2, 0], d[3, 1] = 0, np.nan, np.inf
    far = float(rng.choice([100.0, 200.0]))
    want = assert_same_samples(grid, o, d, 0.05, far, (256, 512, 1024, 2048)[seed])
    # Few steps: segments of one or two intervals.
    for steps in (1, 7):
        assert_same_samples(grid, o, d, 0.05, far, steps)
    assert len(want.t) > 5_000, len(want.t)
    assert (want.t > 10).sum() > 500, "the shell is marched"
    assert len(np.unique(want.delta)) > 10, "δ varies with the segment"


def test_rays_along_the_inner_cube_faces_and_cell_faces():
    """Where boxes stop: rays on the inner cube's faces and edges, and on the faces of cells
    inside it, axis-aligned or at tiny slopes."""
    grid = sparse_contracted_grid(5)
    fixed = [([-0.5, 1.0, 0.2], [1.0, 0.0, 0.0]), ([1.0, 1.0, -3.0], [0.0, 0.0, 1.0]), ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
             ([0.999, -0.3, 0.0], [0.001, 0.0, -1.0]), ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]), ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])]
    rng = np.random.default_rng(11)
    rays = []
    for _ in range(300):
        o = rng.uniform(-1, 1, 3)
        d = rng.uniform(-1, 1, 3)
        a = rng.integers(0, 3)
        # On a face of the inner cube (±1) or of a cell (a multiple of 1/8), the ray along it or
        # leaving it at a slope of 1e-9 .. 1e-3.
        o[a] = rng.choice([-1.0, 1.0]) if rng.random() < 0.5 else -2 + rng.integers(8, 25) / 8
        d[a] = 0.0 if rng.random() < 0.5 else rng.choice([-1, 1]) * 10.0 ** rng.uniform(-9, -3)
        rays.append((o, d))
    o = np.array([f[0] for f in fixed] + [r[0] for r in rays], F32)
    d = np.array([f[1] for f in fixed] + [r[1] for r in rays], F32)
    want = assert_same_samples(grid, o, d, 0.05, 200.0, 512)
    assert len(want.t) > 2_000


def test_skipping_works_inside_the_inner_cube_and_every_shell_step_is_tested():
    # One occupied cell of 32³ over ±2 (the centre cell, (16, 16, 16)); rays along x through it
    # from x = −0.9: segment 0 (256 steps over t in [0, 2]) lies inside the inner cube up to
    # x = 1 (243 steps), the rest in the shell.
    r = 32
    occ = np.zeros(r ** 3, bool)
    occ[(16 * r + 16) * r + 16] = True
    grid = R.Grid(occ, r, F32(2), "linf")
    n = 50
    s = np.arange(n, dtype=F32) / F32(n)
    o = np.stack([np.full(n, -0.9), np.full(n, 0.07), 0.07 + 0.01 * s], axis=1).astype(F32)
    d = np.tile(np.array([[1.0, 0.0, 0.0]], F32), (n, 1))
    m = R.Marcher(grid, o, d, F32(0), F32(10), 1024)
    total = m.steps
    live = np.arange(n)
    found = 0
    while live.size:
        _, cnt = m.next(live)
        found += int(cnt.sum())
        live = live[cnt == R.MARCH_SEGMENT]
    # x = −0.9 + t in the cell's [0, 0.125) at t = (k + 0.5)/128 for k = 115 .. 130.
    assert found == n * 16, "each ray's 16 steps in the cell"
    assert total == 512
    assert m.tests >= n * (512 - 243), f"{m.tests}: the shell's steps are each tested"
    assert m.tests < n * (512 - 243 + 60), f"{m.tests} tests: the inner cube's 243 steps mostly skipped"


class Ball:
    """σ = 40 inside radius 0.5, colour by position; records each call's points."""

    def __init__(self) -> None:
        self.calls = []

    def __call__(self, points, viewdirs):
        self.calls.append(points.copy())
        inside = (points * points).sum(axis=1) < F32(0.25)
        # A faint fog everywhere else: rays reach the shell before they stop.
        return (np.abs(points) % F32(1)).astype(F32), np.where(inside, F32(40), F32(0.02)).astype(F32)


def test_a_contracted_frame_composites_with_each_samples_delta():
    """march_grid (lazy, in rounds) against march_front_to_back over the reference's samples
    and δ: the same pixels bit for bit and the same points."""
    grid = sparse_contracted_grid(3)
    grid.occupied.reshape(32, 32, 32)[12:20, 12:20, 12:20] = True
    rng = np.random.default_rng(4)
    n, chunk = 600, 128
    o = np.tile(np.array([[0.2, -0.1, 0.95]], F32), (n, 1))
    d = np.concatenate([rng.uniform(-0.8, 0.8, (n, 2)), -np.ones((n, 1))], axis=1).astype(F32)
    view = R.unit(d)
    near, far, steps = F32(0.05), F32(100), 256
    new, old = Ball(), Ball()
    got = R.march_grid(new, grid, o, d, view, near, far, steps, float(R.MIN_TRANSMITTANCE), True, chunk)
    parts = []
    for s in range(0, n, chunk):
        sl = slice(s, s + chunk)
        samples = every_interval(grid, o[sl], d[sl], near, far, steps)
        parts.append(R.march_front_to_back(old, o[sl], d[sl], view[sl], samples, float(R.MIN_TRANSMITTANCE), True))
    for key in ("rgb", "depth", "acc"):
        assert np.array_equal(getattr(got, key), np.concatenate([getattr(p, key) for p in parts])), key
    assert_same_points(new.calls, old.calls, chunk * R.MARCH_SEGMENT)
    assert got.depth.max() > 10, "some rays reach the shell"
    assert got.acc.max() > 0.99 and got.acc.min() < 0.9


# -- the files ----------------------------------------------------------------------------------

def fixture_copy(to: Path) -> Path:
    shutil.copytree(FIXTURE, to)
    return to


def edit_scene(b: Path, edit) -> Path:
    scene = json.loads((b / "scene.json").read_text())
    edit(scene)
    (b / "scene.json").write_text(json.dumps(scene))
    return b


def refused(bundle: Path, *needles: str, **open_args) -> str:
    with pytest.raises(BundleError) as e:
        nerf_bundle.Bundle.open(bundle, threads=1, **open_args)
    text = str(e.value)
    for n in needles:
        assert n in text, f"{text!r} should mention {n!r}"
    return text


def test_the_nerfocc2_grid_is_read_and_checked(tmp_path):
    density, bound, threshold, contraction = read_grid(str(FIXTURE / "occupancy.bin"))
    assert (density.shape, bound, contraction) == ((32, 32, 32), 2.0, "linf") and np.isfinite(threshold)
    cells = (FIXTURE / "occupancy.bin").read_bytes()

    def grid(name: str, data: bytes) -> Path:
        b = fixture_copy(tmp_path / name)
        (b / "occupancy.bin").write_bytes(data)
        return b

    word = np.array([7], "<u4").tobytes()
    refused(grid("code-7", cells[:20] + word + cells[24:]), "occupancy.bin: unknown contraction 7 in the NERFOCC2 header")
    half = np.array([1.5], "<f4").tobytes()
    refused(grid("bound", cells[:12] + half + cells[16:]), "occupancy.bin: a contracted grid covers [-2, 2]^3, the header says bound 1.5")
    refused(grid("cut", cells[:-4]), "occupancy.bin: 131092 bytes, expected 131096 for a 32³ grid (truncated?)")
    refused(grid("header", cells[:22]), "occupancy.bin: not an occupancy grid (missing NERFOCC1 or NERFOCC2 header")
    # The same cells as NERFOCC1 (no contraction word) under a contracted scene.json, and the
    # contracted grid under an uncontracted one: both name scene.json and the grid file.
    plain = grid("plain", b"NERFOCC1" + cells[8:20] + cells[24:])
    text = refused(plain, "scene.json: occupancy: the grid file", "contraction is none, scene.json's 'linf'")
    assert str(plain / "occupancy.bin") in text
    uncontracted = edit_scene(fixture_copy(tmp_path / "scene-2"), lambda j: (j.pop("contraction"), j.__setitem__("format", "nerf-rs-scene-2")))
    refused(uncontracted, "scene.json: occupancy: the grid file", "contraction is 'linf', scene.json's none")
    # Without the grid (dense) the header is not read, as nerf-render --dense.
    nerf_bundle.Bundle.open(plain, threads=1, skip_empty_space=False)


def test_scene_json_contraction_is_checked(tmp_path):
    def edited(name, edit):
        return edit_scene(fixture_copy(tmp_path / name), edit)

    refused(edited("no-contraction", lambda j: j.pop("contraction")),
            "scene.json: contraction: None with format 'nerf-rs-scene-3': a contracted field is 'nerf-rs-scene-3', and only it")
    refused(edited("null", lambda j: j.__setitem__("contraction", None)), "scene.json: contraction: None with format 'nerf-rs-scene-3'")
    refused(edited("scene-2", lambda j: j.__setitem__("format", "nerf-rs-scene-2")),
            "scene.json: contraction: 'linf' with format 'nerf-rs-scene-2'")
    for value in ("l2", 1, ["linf"], {"linf": 1}):
        refused(edited(f"unknown-{type(value).__name__}", lambda j: j.__setitem__("contraction", value)),
                "scene.json: contraction:", "is not a contraction this version knows (expected one of 'linf')")
    refused(edited("definition", lambda j: j.__setitem__("contraction_definition", 3)),
            "scene.json: contraction_definition: expected a string, got the number 3")
    b = nerf_bundle.Bundle.open(edited("no-definition", lambda j: j.pop("contraction_definition")), threads=1)
    assert b.grid.contraction == "linf"


def test_the_gpu_loop_declines_a_contracted_grid(monkeypatch):
    """As nerf-render's: a warning, and the numpy loop."""
    from nerf_bundle import _gpu

    sessions_that_say_cuda(monkeypatch)
    monkeypatch.setattr(_gpu, "cupy_or_none", lambda: pytest.fail("CuPy asked for a contracted grid"))
    with pytest.warns(UserWarning, match="does not march contracted grids"):
        bundle = nerf_bundle.Bundle.open(FIXTURE, device="cuda")
    assert bundle._gpu_loop is None


# -- against nerf-render ------------------------------------------------------------------------

def check(frame: nerf_bundle.Frame, native: np.ndarray) -> float:
    assert frame.raw.shape == native.shape
    diff = np.abs(frame.raw - native).max(axis=(0, 1))
    print(f"max |Δ| r g b depth acc: {diff}")
    assert diff.max() <= TOL, diff
    assert native[..., 4].max() > 0.5, "the view sees the scene"
    return float(diff.max())


@pytest.mark.parametrize("view,dense", [(0, False), (1, False), (0, True)])
def test_the_fixture_matches_nerf_render(nerf_render, tmp_path, view, dense):
    bundle = FIXTURE
    if view:
        # nerf-render renders the first test pose (--limit 1): this one first.
        bundle = edit_scene(fixture_copy(tmp_path / "reordered"), lambda j: j["poses"]["test"].reverse())
    b = nerf_bundle.Bundle.open(bundle, skip_empty_space=not dense)
    name = b.pose_names("test")[0]
    native = nerf_render(bundle, "--split", "test", *(["--dense"] if dense else []), name=name)
    check(b.render(b.poses("test")[0]), native)


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
