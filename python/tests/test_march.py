"""The marching (``nerf_bundle._render``): the skip table, the lazy marcher on hand-computed
rays, bit-for-bit equality with testing every interval on random rays (as core/src/render/grid.rs's
tests), compositing, and the field calls of a frame (the same batches as chunk by chunk)."""
from __future__ import annotations

import numpy as np
import pytest

from nerf_bundle import _render as R
from conftest import assert_same_points

F32 = np.float32


def grid_of(resolution: int, bound: float, cells) -> R.Grid:
    occ = np.zeros((resolution,) * 3, bool)
    for c in cells:
        occ[c] = True
    return R.Grid(occ.reshape(-1), resolution, F32(bound))


def every_interval(grid: R.Grid, o: np.ndarray, d: np.ndarray, near, far, steps: int) -> R.Packed:
    """The reference: every interval's middle tested with ``OccupancyGrid::is_occupied``'s
    float32 arithmetic, one ray at a time."""
    near, far = F32(near), F32(far)
    interval = F32((far - near) / F32(steps))
    tk = (near + (np.arange(steps, dtype=F32) + F32(0.5)) * interval).astype(F32)
    b, r = grid.bound, grid.resolution
    ts, offsets = [], [0]
    with np.errstate(invalid="ignore", over="ignore"):
        for i in range(len(o)):
            p = (o[i][None, :] + tk[:, None] * d[i][None, :]).astype(F32)
            u = (p + b) / (F32(2) * b) * F32(r)
            inside = ((u >= 0) & (u < r)).all(axis=1)
            cell = np.where(inside[:, None], u, 0).astype(np.int64)
            keep = inside & grid.occupied[(cell[:, 0] * r + cell[:, 1]) * r + cell[:, 2]]
            ts.append(tk[keep])
            offsets.append(offsets[-1] + int(keep.sum()))
    delta = np.repeat(interval * R.lengths(d), np.diff(offsets))
    return R.Packed(np.concatenate(ts), delta.astype(F32), np.array(offsets))


def test_corner_table_levels_by_hand():
    # One occupied cell at (2, 3, 4) of 8³: an empty cell's level is 1 + the index in
    # CORNER_SIDES (1, 2, 3, 4, 6, ...) of the largest side s whose cube, with the cell at its
    # corner and reaching along the octant's directions, holds no occupied cell.
    assert R.octant_signs(7) == (1, 1, 1) and R.octant_signs(0) == (-1, -1, -1) and R.octant_signs(4) == (1, -1, -1)
    g = grid_of(8, 1.0, [(2, 3, 4)])
    up, down = (g.corner_table(q).reshape(10, 10, 10) for q in (7, 0))

    def level(table, i, j, k):
        return int(table[i + 1, j + 1, k + 1])

    every = len(R.CORNER_SIDES)
    assert level(up, 2, 3, 4) == R.OCCUPIED and level(down, 2, 3, 4) == R.OCCUPIED, "occupied, side 1"
    assert level(up, 1, 1, 1) == 3, "+: cells 1..3 empty, 1..4 hold (2, 3, 4): side 3"
    assert level(up, 0, 3, 4) == 2, "+: i 0..1 empty, 0..2 holds it: side 2"
    assert level(down, 1, 1, 1) == every, "−: nothing below (1, 1, 1)"
    assert level(up, 3, 3, 4) == every, "+: nothing above i = 3"
    assert level(down, 3, 3, 4) == 1, "−: i 2..3 holds it: side 1"
    # The padding (outside the cube, empty) has levels as any cell; past it all is empty.
    assert level(up, -1, 3, 4) == 3, "+: i −1..1 empty, −1..2 holds it: side 3"
    assert level(up, 8, 8, 8) == every and level(down, 8, 8, 8) == 5, "−: side 6 (i 3..8) misses it, 8 holds it"
    assert level(g.corner_table(4).reshape(10, 10, 10), 0, 5, 6) == 2, "+x−y−z: side 3 (i 0..2, j 3..5, k 4..6) holds it"
    # An occupied cell's level is OCCUPIED + the index of the largest side whose cube is all
    # occupied: a 3 × 3 × 3 block at 1..3 (the padding around the grid is empty).
    g = grid_of(4, 1.0, [(i, j, k) for i in range(1, 4) for j in range(1, 4) for k in range(1, 4)])
    up, down = (g.corner_table(q).reshape(6, 6, 6) for q in (7, 0))
    assert level(up, 1, 1, 1) == R.OCCUPIED + 2 and level(down, 3, 3, 3) == R.OCCUPIED + 2, "side 3"
    assert level(up, 2, 2, 2) == R.OCCUPIED + 1 and level(down, 1, 2, 3) == R.OCCUPIED, "side 2; side 1"
    assert level(up, 3, 3, 3) == R.OCCUPIED, "+: (4, 4, 4) is the padding"


def test_marcher_by_hand():
    # Bound 1, 4 cells of 0.5 per axis; a ray along +x at y = z = −0.25 (cell 1), t over
    # [0, 4] in 8 steps: samples at t = 0.25, 0.75, ..., 3.75, i.e. x = −1.75 ... 1.75, in
    # cells x = −, −, 0, 1, 2, 3, −, −. Cells (2, 1, 1) and (3, 1, 1) occupied: t = 2.25, 2.75.
    g = grid_of(4, 1.0, [(2, 1, 1), (3, 1, 1)])
    o = np.array([[-2.0, -0.25, -0.25]], F32)
    d = np.array([[1.0, 0.0, 0.0]], F32)
    p = R.occupied_samples(g, o, d, F32(0), F32(4), 8)
    assert p.t.tolist() == [2.25, 2.75] and p.offsets.tolist() == [0, 2] and p.delta.tolist() == [0.5, 0.5]
    # Lazily, one at a time: steps 4, then 5, then nothing.
    m = R.Marcher(g, o, d, F32(0), F32(4), 8)
    for expected in ([4], [5], []):
        steps, counts = m.next(np.array([0]), 1)
        assert counts.tolist() == [len(expected)] and steps[0, :counts[0]].tolist() == expected


def test_a_ray_along_a_cell_face_is_tested_exactly():
    # y = 0 is the face between cells 1 and 2 (u = 2.0 exactly, cell 2 by the float32 rule):
    # only (2, 2, 1) is hit, whichever side a box would round to.
    g = grid_of(4, 1.0, [(2, 2, 1)])
    o = np.array([[-2.0, 0.0, -0.25]], F32)
    d = np.array([[1.0, 0.0, 0.0]], F32)
    assert R.occupied_samples(g, o, d, F32(0), F32(4), 8).t.tolist() == [2.25]
    g = grid_of(4, 1.0, [(2, 1, 1)])
    assert R.occupied_samples(g, o, d, F32(0), F32(4), 8).t.tolist() == []


def random_rays(rng: np.random.Generator, n: int, bound: float, resolution: int) -> tuple:
    """Rays of every kind the marcher must get right: random, axis-aligned, on cell faces,
    at tiny slopes to a lattice plane, from inside the cube, zero and non-finite."""
    o = rng.uniform(-2.5 * bound, 2.5 * bound, (n, 3)).astype(F32)
    target = rng.uniform(-bound, bound, (n, 3)).astype(F32)
    d = (target - o).astype(F32)
    cell = 2 * bound / resolution
    kind = rng.integers(0, 7, n)
    axis = rng.integers(0, 3, n)
    for i in np.nonzero(kind == 1)[0]:  # axis-aligned, the other coordinates on a face or not
        d[i] = 0
        d[i, axis[i]] = rng.choice([-1, 1]) * rng.uniform(0.5, 2)
        for a in range(3):
            if a != axis[i] and rng.random() < 0.5:
                o[i, a] = F32(-bound + cell * rng.integers(0, resolution + 1))
    for i in np.nonzero(kind == 2)[0]:  # hugging a lattice plane at a tiny slope
        a = axis[i]
        o[i, a] = F32(-bound + cell * rng.integers(1, resolution))
        d[i, a] = F32(rng.choice([-1, 1]) * 10.0 ** rng.uniform(-9, -3))
    for i in np.nonzero(kind == 3)[0]:  # starting inside the cube
        o[i] = rng.uniform(-bound, bound, 3)
    d[kind == 4] = 0
    bad = np.nonzero(kind == 5)[0]
    o[bad[: len(bad) // 2], 0] = np.nan
    d[bad[len(bad) // 2:], 1] = np.inf
    return o, d


@pytest.mark.parametrize("seed", range(6))
def test_marching_equals_testing_every_interval_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    resolution = int(rng.choice([4, 16, 33]))
    bound = float(rng.choice([1.0, 1.5, 0.37]))
    occ = rng.random((resolution,) * 3) < rng.choice([0.02, 0.1, 0.4])
    # A solid blob as well, so rays cross long occupied runs and large empty regions.
    c = resolution // 2
    occ[c - resolution // 6:c + resolution // 6 + 1, c - 1:c + 2, :] = True
    grid = R.Grid(occ.reshape(-1), resolution, F32(bound))
    o, d = random_rays(rng, 400, bound, resolution)
    near, far = F32(rng.uniform(0, 1)), F32(rng.uniform(2, 8))
    steps = int(rng.choice([7, 64, 333, 1024]))
    with np.errstate(invalid="ignore", over="ignore"):
        got = R.occupied_samples(grid, o, d, near, far, steps)
    want = every_interval(grid, o, d, near, far, steps)
    assert np.array_equal(got.offsets, want.offsets), "samples per ray"
    assert np.array_equal(got.t, want.t), "sample distances, bit for bit"
    assert np.array_equal(got.delta, want.delta)


@pytest.mark.parametrize("seed", range(3))
def test_marching_sparse_grids_with_large_empty_cubes_bit_for_bit(seed):
    # A few occupied cells in a large grid: the corner cubes reach their largest sides (32),
    # rays cross the padding and jump far; every sample still as testing every interval.
    rng = np.random.default_rng(100 + seed)
    resolution = int(rng.choice([40, 64]))
    bound = float(rng.choice([1.0, 1.5]))
    occ = np.zeros(resolution ** 3, bool)
    occ[rng.choice(resolution ** 3, int(rng.integers(1, 12)), replace=False)] = True
    grid = R.Grid(occ, resolution, F32(bound))
    o, d = random_rays(rng, 300, bound, resolution)
    # A third aimed at an occupied cell's centre.
    cells = np.stack(np.unravel_index(np.flatnonzero(occ), (resolution,) * 3), axis=1)
    centre = (cells[rng.integers(0, len(cells), 100)] + 0.5) / resolution * 2 * bound - bound
    d[:100] = (centre - o[:100]).astype(F32)
    near, far = F32(rng.uniform(0, 1)), F32(rng.uniform(2, 8))
    steps = int(rng.choice([512, 2048]))
    with np.errstate(invalid="ignore", over="ignore"):
        got = R.occupied_samples(grid, o, d, near, far, steps)
    want = every_interval(grid, o, d, near, far, steps)
    assert np.array_equal(got.offsets, want.offsets), "samples per ray"
    assert np.array_equal(got.t, want.t), "sample distances, bit for bit"
    assert np.diff(want.offsets).max() > 0, "some rays hit an occupied cell"


def test_composite_by_hand():
    # The docstring's example: α = 0.5, 0.5 (colour 1, t = 1, 2) from T = 1.
    alpha = np.array([[0.5], [0.5]], F32)
    colour = np.ones((2, 3, 1), F32)
    t = np.array([[1.0], [2.0]], F32)
    trans, rgb, depth, acc = np.ones(1, F32), np.zeros((3, 1), F32), np.zeros(1, F32), np.zeros(1, F32)
    w = R.composite(alpha, colour, t, trans, rgb, depth, acc)
    assert w[:, 0].tolist() == [0.5, 0.25]
    assert rgb[:, 0].tolist() == [0.75] * 3 and depth.tolist() == [1.0] and acc.tolist() == [0.75]
    # 1 − 0.5 + 1e-10 rounds to 0.5 in float32.
    assert trans.tolist() == [0.25]


class Ball:
    """σ = 40 inside radius 0.5, colour by position; records each call's points."""

    def __init__(self) -> None:
        self.calls = []

    def __call__(self, points, viewdirs):
        self.calls.append(points.copy())
        inside = (points * points).sum(axis=1) < F32(0.25)
        return (points + F32(0.5)).astype(F32), np.where(inside, F32(40), F32(0)).astype(F32)


def test_a_frame_is_marched_with_the_points_of_chunk_by_chunk():
    """march_grid over all rays equals marching each chunk alone with every sample known
    first (the old path): the same pixels bit for bit, the same points evaluated (in other
    calls: a round's samples lane after lane), none past a chunk's points per call."""
    rng = np.random.default_rng(7)
    r = 24
    centre = (np.indices((r,) * 3).reshape(3, -1).T + 0.5) / r * 2 - 1
    grid = R.Grid((np.linalg.norm(centre, axis=1) < 0.6) | (rng.random(r ** 3) < 0.01), r, F32(1))
    n, chunk = 700, 128
    o = np.tile(np.array([[0.3, -0.2, 3.0]], F32), (n, 1))
    d = np.concatenate([rng.uniform(-0.35, 0.35, (n, 2)), -np.ones((n, 1))], axis=1).astype(F32)
    view = R.unit(d)
    near, far, steps = F32(2), F32(6), 256
    new = Ball()
    got = R.march_grid(new, grid, o, d, view, near, far, steps, float(R.MIN_TRANSMITTANCE), True, chunk)
    old = Ball()
    parts = []
    for s in range(0, n, chunk):
        sl = slice(s, s + chunk)
        samples = every_interval(grid, o[sl], d[sl], near, far, steps)
        parts.append(R.march_front_to_back(old, o[sl], d[sl], view[sl], samples, float(R.MIN_TRANSMITTANCE), True))
    assert np.array_equal(got.rgb, np.concatenate([p.rgb for p in parts]))
    assert np.array_equal(got.depth, np.concatenate([p.depth for p in parts]))
    assert np.array_equal(got.acc, np.concatenate([p.acc for p in parts]))
    assert got.acc.max() > 0.99 and got.acc.min() < 0.01, "some rays hit the ball, some miss"
    assert_same_points(new.calls, old.calls, chunk * R.MARCH_SEGMENT)
    assert len(old.calls) > n // chunk, "more than one round"


def test_rays_whose_samples_run_to_the_last_step_are_marched_as_chunk_by_chunk():
    """Rays that end inside the ball (far = 3.1), so their last round has fewer than 16
    samples up to the very last step: the same pixels and points as the old path."""
    r = 16
    grid = R.Grid(np.ones(r ** 3, bool), r, F32(1))
    n = 90
    rng = np.random.default_rng(3)
    o = np.tile(np.array([[0.0, 0.0, 3.0]], F32), (n, 1))
    d = np.concatenate([rng.uniform(-0.1, 0.1, (n, 2)), -np.ones((n, 1))], axis=1).astype(F32)
    view = R.unit(d)
    near, far, steps = F32(2), F32(3.1), 83
    new, old = Ball(), Ball()
    got = R.march_grid(new, grid, o, d, view, near, far, steps, None, False, 64)
    samples = every_interval(grid, o, d, near, far, steps)
    last = R.Marcher(grid, o, d, near, far, steps).t[steps - 1]
    assert (np.diff(samples.offsets) % R.MARCH_SEGMENT != 0).all(), "every ray ends between rounds"
    assert samples.t.max() == last, "at the last step"
    parts = []
    for s in range(0, n, 64):
        sl = slice(s, s + 64)
        packed = every_interval(grid, o[sl], d[sl], near, far, steps)
        parts.append(R.march_front_to_back(old, o[sl], d[sl], view[sl], packed, None, False))
    assert np.array_equal(got.rgb, np.concatenate([p.rgb for p in parts]))
    assert_same_points(new.calls, old.calls, 64 * R.MARCH_SEGMENT)
