"""Vectorised rendering: the same float32 arithmetic as ``core/src/render`` (grid.rs,
packed.rs, compositing.rs, dense.rs, sample/stratified.rs), over packed samples (a flat array
of distances with per-ray offsets) instead of per-ray loops."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, List, Optional, Tuple

import numpy as np

F32 = np.float32
#: Samples per ray per field call when marching front to back (``MARCH_SEGMENT``).
MARCH_SEGMENT = 16
#: Early-termination threshold (``DEFAULT_MIN_TRANSMITTANCE``).
MIN_TRANSMITTANCE = F32(1e-4)
LAST_DELTA = F32(1e10)
TRANSMITTANCE_EPS = F32(1e-10)
#: Consecutive steps a ray tests at once when marching (:meth:`Marcher.next`).
WINDOW = 16

FieldFn = Callable[[np.ndarray, np.ndarray], Tuple[np.ndarray, np.ndarray]]


def expf(x: np.ndarray) -> np.ndarray:
    """float32 exp rounded from float64, i.e. correctly rounded like glibc's ``expf`` (which
    Rust's ``f32::exp`` calls); numpy's own float32 SIMD exp can be an ulp off, enough to move
    an importance sample across a CDF step."""
    return np.exp(x.astype(np.float64)).astype(F32)


def lengths(d: np.ndarray) -> np.ndarray:
    """‖d‖ per row, float32, as ``length``: sqrt(x·x + y·y + z·z)."""
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])


def unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` normalised as glam's ``normalize``: v · (1 / ‖v‖)."""
    return (v * (F32(1) / lengths(v))[:, None]).astype(F32)


#: Empty radii (in cells) of the skip table's levels 1, 2, ...: level 1 is an empty cell
#: (radius 0), level 6 a cell with no occupied cell within 16 cells along every axis.
SKIP_RADII = (0, 1, 2, 4, 8, 16)


def _dilated(x: np.ndarray, shift: int) -> np.ndarray:
    """``x`` [R, R, R] bool OR-ed with itself shifted by ±``shift`` along each axis (no wrap).
    When ``x`` is a grid dilated by ``radius`` ≥ ``shift`` − 1 cells (Chebyshev distance), the
    result is the grid dilated by ``radius + shift``."""
    out = x
    for axis in range(3):
        src = out
        out = src.copy()
        n = src.shape[axis]
        if shift >= n:
            continue
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, n - shift), slice(shift, n)
        out[tuple(hi)] |= src[tuple(lo)]
        out[tuple(lo)] |= src[tuple(hi)]
    return out


@dataclass
class Grid:
    """Occupancy grid: ``occupied`` [R³] flat bool (cell (i, j, k) at (i·R + j)·R + k) over the
    cube ±``bound``."""

    occupied: np.ndarray
    resolution: int
    bound: np.float32

    def skip_table(self) -> np.ndarray:
        """[(R + 2)³] uint8, cached: the grid padded by one empty cell on every side, each cell
        0 where occupied, else 1 + the index in ``SKIP_RADII`` of the largest radius r such that
        no occupied cell lies within r cells along every axis (so a point in that cell can move
        r cells' length in any direction and stay in empty cells).

        Example: one occupied cell; a cell 3 cells from it along x (and 0 along y, z) has no
        occupied cell within 2 but one within 4: level 1 + 2 = 3 (radius 2)."""
        cached = self.__dict__.get("_skip_table")
        if cached is not None:
            return cached
        r = self.resolution
        occupied = self.occupied.reshape(r, r, r)
        dilated = occupied.copy()
        level = np.where(occupied, 0, 1).astype(np.uint8)
        radius = 0
        for target in SKIP_RADII[1:]:
            dilated = _dilated(dilated, target - radius)
            radius = target
            level += ~dilated
        table = np.ones((r + 2,) * 3, np.uint8)
        table[1:-1, 1:-1, 1:-1] = level
        self.__dict__["_skip_table"] = table.reshape(-1)
        return self.__dict__["_skip_table"]

    def levels_along(self, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The :meth:`skip_table` level (0: occupied) of the points o + t·d (float32, as
        ``point_at``) for ``o``, ``d`` [3, m, 1] and ``t`` [m, w] → [m, w]. The cell is
        ``OccupancyGrid::cell``'s, bit for bit: u = (v + b) / (2b) · R per axis; outside the
        cube (or NaN) falls in the padding, which is empty."""
        b, r = self.bound, self.resolution
        two_b, rf, side = F32(2) * b, F32(r), r + 2
        index = np.zeros(t.shape, np.int32)
        for axis in range(3):
            u = o[axis] + t * d[axis]
            u += b
            u /= two_b
            u *= rf
            # fmax/fmin turn NaN into -1 (the padding) as Rust's `!(u >= 0)` rejects it.
            np.fmax(u, F32(-1), out=u)
            np.fmin(u, rf, out=u)
            np.floor(u, out=u)
            index *= side
            index += u.astype(np.int32)
        # +1 per axis for the padding.
        index += side * side + side + 1
        return self.skip_table().take(index)

    def t_range(self, o: np.ndarray, d: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """A conservative [t0, t1] (float64) per ray outside which no point lies in the cube."""
        b = np.float64(self.bound) * (1 + 1e-3) + 1e-6
        o64, d64 = o.astype(np.float64), d.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (-b - o64) / d64
            c = (b - o64) / d64
        lo, hi = np.fmin(a, c), np.fmax(a, c)
        # An axis the ray runs along: inside the slab is all t, outside none.
        parallel = d64 == 0
        inslab = np.abs(o64) <= b
        lo = np.where(parallel, np.where(inslab, -np.inf, np.inf), lo)
        hi = np.where(parallel, np.where(inslab, np.inf, -np.inf), hi)
        lo = np.where(np.isnan(lo), -np.inf, lo)
        hi = np.where(np.isnan(hi), np.inf, hi)
        return lo.max(axis=1), hi.min(axis=1)


@dataclass
class Packed:
    """Samples of a batch of rays, flat and ray by ray, front to back: ray ``r``'s samples are
    ``offsets[r]:offsets[r + 1]`` of ``t`` and ``delta`` (the interval in world units)."""

    t: np.ndarray
    delta: np.ndarray
    offsets: np.ndarray


class Marcher:
    """The occupied samples of rays, produced lazily front to back (``occupied_samples``'
    samples: ``steps`` equal intervals over [near, far], a sample at each middle, kept where it
    lies in an occupied cell; δ = interval · ‖d‖). :meth:`next` gives each asked ray its next
    samples, so a ray that terminates early never marches the rest.

    A ray starts where it may enter the grid's cube (a conservative slab test). At each probe
    step, the ray's cell and its :meth:`Grid.skip_table` level give a box of cells that is all
    occupied (the cell) or all empty (the cell grown by the level's radius); the steps from the
    probe to where the ray leaves that box, shrunk by a margin far above float32 rounding, are
    then all occupied samples or all skipped, without testing each. A probe within the margin
    of the box (a ray along a cell face, non-finite values) tests a window of steps with the
    exact float32 cell instead. So the samples are those of testing every step, bit for bit.

    # Shapes
    ``o``, ``d`` [n, 3] float32."""

    def __init__(self, grid: Grid, o: np.ndarray, d: np.ndarray, near: np.float32, far: np.float32, steps: int) -> None:
        self.grid = grid
        self.steps = steps
        self.interval = F32((far - near) / F32(steps))
        # Step k samples t = near + (k + 0.5)·interval; past `steps` only ever masked out.
        self.t = (near + (np.arange(steps + WINDOW, dtype=F32) + F32(0.5)) * self.interval).astype(F32)
        self.o = np.ascontiguousarray(o.T, F32)[:, :, None]  # [3, n, 1]
        self.d = np.ascontiguousarray(d.T, F32)[:, :, None]
        self.delta = (self.interval * lengths(d)).astype(F32)
        t0, t1 = grid.t_range(o, d)
        with np.errstate(invalid="ignore", over="ignore"):
            k0 = np.floor((t0 - np.float64(near)) / np.float64(self.interval) - 0.5) - 1
            k1 = np.ceil((t1 - np.float64(near)) / np.float64(self.interval) - 0.5) + 2
        self.cursor = np.clip(np.nan_to_num(k0, nan=0, posinf=steps, neginf=0), 0, steps).astype(np.int32)
        self.end = np.clip(np.nan_to_num(k1, nan=steps, posinf=steps, neginf=0), 0, steps).astype(np.int32)
        self._boxes(o, d, near)
        self.tests = 0  # steps tested one by one so far (for measuring)
        self.probes = 0  # probes so far (for measuring)

    def _boxes(self, o: np.ndarray, d: np.ndarray, near: np.float32) -> None:
        """Per ray, in cell units u = (x + b)/(2b)·R = α + β·t per axis: ``coef`` [12, n] =
        α, β, then per axis the terms of the t at which the ray enters and leaves a box of
        cells shrunk by the margin m (``_box_range``); and the real t of each step."""
        grid = self.grid
        r, b = grid.resolution, np.float64(grid.bound)
        scale_u = r / (2.0 * b)
        o64, d64 = o.astype(np.float64), d.astype(np.float64)
        interval = np.float64(self.interval)
        self.t_real = np.float64(near) + (np.arange(self.steps + WINDOW, dtype=np.float64) + 0.5) * interval
        t_max = float(np.abs(self.t_real[[0, self.steps - 1]]).max()) if self.steps else 0.0
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            scale = np.maximum(np.abs(o64) + t_max * np.abs(d64), float(b)).max(axis=1)
            # As core's march_ray: far above the float32 error of a sample's position and cell.
            margin = (1e-3 * 2.0 * b / r + 64.0 * float(np.finfo(F32).eps) * scale) * scale_u
            alpha = (o64 + b) * scale_u
            beta = d64 * scale_u
            inv = 1.0 / beta
            m = margin[:, None]
            up = beta > 0
            enter = np.where(up, m - alpha, 1.0 - m - alpha) * inv
            leave = np.where(up, 1.0 - m - alpha, m - alpha) * inv
            per_r = np.abs(inv)
            # A coordinate that never changes: inside a cell's shrunk box on that axis for every
            # t, or never (within the margin of a face) unless the box is grown by a cell.
            flat = beta == 0
            frac = alpha - np.floor(alpha)
            safe = (frac >= m) & (frac <= 1.0 - m)
            inv = np.where(flat, 0.0, inv)
            per_r = np.where(flat, np.where(safe, 0.0, 2e300), per_r)
            enter = np.where(flat, np.where(safe, -1e300, 1e300), enter)
            leave = np.where(flat, np.where(safe, 1e300, -1e300), leave)
        # Rays the boxes cannot handle (non-finite, a non-positive interval) only test windows.
        usable = np.isfinite(o64).all(axis=1) & np.isfinite(d64).all(axis=1) & np.isfinite(scale) & (margin < 0.25)
        if not (np.isfinite(interval) and interval > 0):
            usable[:] = False
        enter[~usable] = np.inf
        self.coef = np.ascontiguousarray(np.concatenate([alpha.T, beta.T, inv.T, per_r.T, enter.T, leave.T]))
        self.coef = np.nan_to_num(self.coef, nan=0.0)
        self.coef[12:15, ~usable] = np.inf
        self.coef[15:18, ~usable] = -np.inf

    def next(self, rays: np.ndarray, n: int = MARCH_SEGMENT) -> Tuple[np.ndarray, np.ndarray]:
        """The next (at most) ``n`` occupied steps of each of ``rays`` (indices, any order):
        steps [len(rays), n] int32 (row i's first ``counts[i]`` are valid, in order) and counts
        [len(rays)] int32; fewer than ``n`` means the ray has no more. Moves the rays on."""
        m = len(rays)
        steps = np.zeros((m, n), np.int32)
        found = np.zeros(m, np.int32)
        cursor, end = self.cursor[rays], self.end[rays]
        doubt = np.zeros(m, bool)
        runs: List[Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # rows, first step, count, lane
        table, radii = self.grid.skip_table(), np.array((0,) + SKIP_RADII, np.float64)
        res, side = self.grid.resolution, self.grid.resolution + 2
        inv_interval, t0 = 1.0 / np.float64(self.interval), self.t_real[0]
        pending = np.nonzero(cursor < end)[0]
        while pending.size:
            k = cursor[pending]
            c = self.coef[:, rays[pending]]
            t = self.t_real[k]
            index = np.zeros(len(k), np.int64)
            cells = []
            for axis in range(3):
                u = c[3 + axis] * t
                u += c[axis]
                np.floor(u, out=u)
                np.clip(u, -1, res, out=u)
                cells.append(u)
                index *= side
                index += u.astype(np.int64)
            level = table.take(index + (side * side + side + 1))
            r = radii.take(level)
            enter, leave = np.full(len(k), -np.inf), np.full(len(k), np.inf)
            for axis in range(3):
                centre = cells[axis] * c[6 + axis]
                grow = r * c[9 + axis]
                np.maximum(enter, centre - grow + c[12 + axis], out=enter)
                np.minimum(leave, centre + grow + c[15 + axis], out=leave)
            self.probes += len(k)
            sure = (enter <= t) & (t <= leave)
            # The last step inside the box (at least the probe's own step).
            with np.errstate(invalid="ignore"):
                last = np.floor((leave - t0) * inv_interval)
            np.clip(last, k, end[pending] - 1, out=last)
            through = last.astype(np.int32) + 1
            # Occupied box: its steps are samples, as many as the ray still needs.
            fill = sure & (level == 0)
            rows = pending[fill]
            count = np.minimum(through[fill] - k[fill], n - found[rows])
            runs.append((rows, k[fill], count, found[rows]))
            found[rows] += count
            cursor[rows] = k[fill] + count
            # Empty box: skip its steps.
            empty = sure & (level != 0)
            cursor[pending[empty]] = through[empty]
            # Within the margin of the box's faces: test the step exactly (a window of steps
            # for rays whose probe was already unsure, e.g. along a cell face).
            unsure = pending[~sure]
            if unsure.size:
                again = doubt[unsure]
                doubt[pending] = False
                doubt[unsure] = True
                self._window(rays, unsure[~again], cursor, end, found, n, runs, 1)
                self._window(rays, unsure[again], cursor, end, found, n, runs, WINDOW)
            else:
                doubt[pending] = False
            pending = pending[(found[pending] < n) & (cursor[pending] < end[pending])]
        self.cursor[rays] = cursor
        if runs:
            rows, first, count, offset = (np.concatenate(x) for x in zip(*runs))
            total = int(count.sum())
            run = np.repeat(np.arange(len(count)), count)
            within = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
            steps[rows[run], offset[run] + within] = first[run] + within
        return steps, found

    def _window(self, rays: np.ndarray, rows: np.ndarray, cursor: np.ndarray, end: np.ndarray, found: np.ndarray, n: int,
                runs: list, width: int) -> None:
        """Test the next ``width`` (≤ ``WINDOW``) steps of ``rows`` with the exact float32 cell;
        record the occupied ones (as many as needed) as runs of one step and move the rows on."""
        if not rows.size:
            return
        ray = rays[rows]
        k = cursor[rows][:, None] + np.arange(width, dtype=np.int32)
        level = self.grid.levels_along(self.o[:, ray], self.d[:, ray], self.t[k])
        self.tests += k.size
        occupied = (level == 0) & (k < end[rows][:, None])
        rank = np.cumsum(occupied, axis=1, dtype=np.int32)
        need = n - found[rows]
        take = occupied & (rank <= need[:, None])
        row, col = np.nonzero(take)
        runs.append((rows[row], k[row, col].astype(np.int32), np.ones(len(row), np.int32), found[rows[row]] + rank[row, col] - 1))
        got = np.minimum(rank[:, -1], need)
        found[rows] += got
        full = got == need
        # Past the window; a ray that got all it needs resumes after its last sample.
        moved = k[:, -1] + 1
        last_taken = np.argmax(rank >= need[:, None], axis=1)
        moved[full] = k[full, last_taken[full]] + 1
        cursor[rows] = moved


def occupied_samples(grid: Grid, o: np.ndarray, d: np.ndarray, near: np.float32, far: np.float32, steps: int) -> Packed:
    """All of ``occupied_samples``' samples of the rays, packed (what :class:`Marcher` gives
    lazily)."""
    marcher = Marcher(grid, o, d, near, far, steps)
    rays = np.arange(len(o))
    parts, counts = [], np.zeros(len(o), np.int64)
    live = rays
    while live.size:
        k, cnt = marcher.next(live)
        valid = np.arange(k.shape[1])[None, :] < cnt[:, None]
        parts.append((live, k, valid))
        counts[live] += cnt
        live = live[cnt == k.shape[1]]
    offsets = np.zeros(len(o) + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    t = np.empty(offsets[-1], F32)
    filled = offsets[:-1].copy()
    for live, k, valid in parts:
        cnt = valid.sum(axis=1)
        where = (filled[live][:, None] + np.arange(k.shape[1])[None, :])[valid]
        t[where] = marcher.t[k[valid]]
        filled[live] += cnt
    return Packed(t, np.repeat(marcher.delta, counts), offsets)


@dataclass
class Marched:
    """Per-ray rgb [R, 3], depth [R], acc [R] and per-sample weights (0 where not evaluated;
    ``None`` from :func:`march_grid`, which never forms all samples)."""

    rgb: np.ndarray
    depth: np.ndarray
    acc: np.ndarray
    weights: Optional[np.ndarray]


@dataclass
class Stages:
    """Wall seconds per stage of rendering, summed over calls: ``rays`` (camera rays, NDC),
    ``march`` (finding samples), ``gather`` (the field's inputs), ``field`` (the field calls),
    ``composite`` (α, compositing, bookkeeping)."""

    rays: float = 0.0
    march: float = 0.0
    gather: float = 0.0
    field: float = 0.0
    composite: float = 0.0

    def lap(self, stage: str, since: float) -> float:
        """Add the time from ``since`` to now to ``stage``; returns now."""
        now = time.perf_counter()
        setattr(self, stage, getattr(self, stage) + now - since)
        return now


def composite(alpha: np.ndarray, colour: np.ndarray, t: np.ndarray, trans: np.ndarray, rgb: np.ndarray,
              depth: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Composite each ray's next samples front to back in float32, one sample at a time as
    ``RayAccumulator::add``: w = α·T, rgb += w·c, depth += w·t, acc += w, T ← T·(1 − α + 1e-10).
    Padding (α = 0) adds exactly nothing: 1 − 0 + 1e-10 rounds to 1.

    # Shapes
    ``alpha``, ``t`` [S, A] and ``colour`` [S, 3, A], lane-major (sample j of every ray is row
    j); the state ``trans``, ``depth``, ``acc`` [A] and ``rgb`` [3, A] is updated in place;
    returns the weights [S, A].

    Example: α = 0.5, 0.5 (colour 1, t = 1, 2) from T = 1: w = 0.5, 0.25; rgb 0.75; depth
    1.0; acc 0.75; T = 0.25."""
    weights = np.empty_like(alpha)
    factor = (F32(1) - alpha) + TRANSMITTANCE_EPS
    for j in range(len(alpha)):
        w = np.multiply(alpha[j], trans, out=weights[j])
        rgb += w * colour[j]
        depth += w * t[j]
        acc += w
        trans *= factor[j]
    return weights


def alpha_of(sigma: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``alpha_from_density``: α = 1 − exp(−relu(σ)·δ) in float32 (``expf``)."""
    return F32(1) - expf(-np.maximum(sigma, F32(0)) * delta)


def _lane_major(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Flat per-sample ``values`` [N] or [N, 3] (rows' valid lanes in order) → [S, A] or
    [S, 3, A] with zeros where ``valid`` [A, S] is False."""
    a, s = valid.shape
    if values.ndim == 1:
        out = np.zeros((s, a), F32)
        out.T[valid] = values
    else:
        out = np.zeros((s, values.shape[1], a), F32)
        out.transpose(2, 0, 1)[valid] = values
    return out


def march_grid(field: FieldFn, grid: Grid, o: np.ndarray, d: np.ndarray, viewdirs: np.ndarray, near: np.float32,
               far: np.float32, steps: int, min_transmittance: Optional[float], white_background: bool, batch: int,
               stages: Optional[Stages] = None) -> Marched:
    """``grid::render_rays`` for ``o``, ``d``, unit ``viewdirs`` [n, 3]: the rays' occupied
    samples (:class:`Marcher`), evaluated front to back ``MARCH_SEGMENT`` per active ray per
    field call and composited (:func:`composite`); a ray stops once T < ``min_transmittance``
    (``None``: never) or when it has no more samples.

    The rays are marched together, a round at a time, while the field sees the batches
    nerf-render gives it: each run of ``batch`` rays (a chunk) gets its own call per round,
    with its active rays' next samples in ray order."""
    stages = stages if stages is not None else Stages()
    n = len(o)
    trans = np.ones(n, F32)
    rgb = np.zeros((3, n), F32)
    depth = np.zeros(n, F32)
    acc = np.zeros(n, F32)
    min_t = F32(-np.inf) if min_transmittance is None else F32(min_transmittance)
    now = time.perf_counter()
    marcher = Marcher(grid, o, d, near, far, steps)
    active = np.arange(n)
    lane = np.arange(MARCH_SEGMENT)
    edges = np.arange(0, n + batch, batch)
    while active.size:
        k, cnt = marcher.next(active)
        live = cnt > 0
        active, k, cnt = active[live], k[live], cnt[live]
        now = stages.lap("march", now)
        if not active.size:
            break
        valid = lane[None, :] < cnt[:, None]
        t = marcher.t[k[valid]]
        points = np.repeat(o[active], cnt, axis=0)
        points += t[:, None] * np.repeat(d[active], cnt, axis=0)
        dirs = np.repeat(viewdirs[active], cnt, axis=0)
        # The samples of each chunk's rays, a slice each (rays in order).
        ends = np.zeros(len(active) + 1, np.int64)
        np.cumsum(cnt, out=ends[1:])
        cuts = ends[np.searchsorted(active, edges)]
        cuts = cuts[np.r_[True, cuts[1:] > cuts[:-1]]]
        now = stages.lap("gather", now)
        colour = np.empty((len(t), 3), F32)
        sigma = np.empty(len(t), F32)
        for a, b in zip(cuts[:-1], cuts[1:]):
            colour[a:b], sigma[a:b] = field(points[a:b], dirs[a:b])
        now = stages.lap("field", now)
        alpha = alpha_of(sigma, np.repeat(marcher.delta[active], cnt))
        tr, rg, de, ac = trans[active], rgb[:, active], depth[active], acc[active]
        composite(_lane_major(alpha, valid), _lane_major(colour, valid), _lane_major(t, valid), tr, rg, de, ac)
        trans[active], rgb[:, active], depth[active], acc[active] = tr, rg, de, ac
        active = active[(tr >= min_t) & (cnt == MARCH_SEGMENT)]
        now = stages.lap("composite", now)
    out = np.ascontiguousarray(rgb.T)
    if white_background:
        out += (F32(1) - acc)[:, None]
    return Marched(out, depth, acc, None)


def dense_packed(t: np.ndarray, d: np.ndarray) -> Packed:
    """``PackedSamples::from_dense``: all of ``t`` [R, n] with the reference δ (gap to the next
    sample, the last 1e10, times ‖d‖)."""
    n_rays, n = t.shape
    norm = lengths(d)
    delta = np.empty_like(t)
    delta[:, :-1] = (t[:, 1:] - t[:, :-1]) * norm[:, None]
    delta[:, -1] = LAST_DELTA * norm
    return Packed(t.reshape(-1), delta.reshape(-1), np.arange(n_rays + 1, dtype=np.int64) * n)


def march_front_to_back(field: FieldFn, o: np.ndarray, d: np.ndarray, viewdirs: np.ndarray, samples: Packed,
                        min_transmittance: Optional[float], white_background: bool, segment: int = MARCH_SEGMENT) -> Marched:
    """``march_front_to_back``: every active ray's next ``segment`` samples go into one field
    call, are composited in order (:func:`composite`), and a ray stops once T <
    ``min_transmittance`` (``None``: never)."""
    n = len(o)
    trans = np.ones(n, F32)
    rgb = np.zeros((3, n), F32)
    depth = np.zeros(n, F32)
    acc = np.zeros(n, F32)
    weights = np.zeros(len(samples.t), F32)
    nxt = samples.offsets[:-1].copy()
    end = samples.offsets[1:]
    active = np.nonzero(end > nxt)[0]
    lane = np.arange(segment)
    min_t = F32(-np.inf) if min_transmittance is None else F32(min_transmittance)
    while active.size:
        cnt = np.minimum(end[active] - nxt[active], segment)
        valid = lane[None, :] < cnt[:, None]
        flat = (nxt[active][:, None] + lane[None, :])[valid]
        ray = np.repeat(active, cnt)
        tt = samples.t[flat]
        c, sigma = field(o[ray] + tt[:, None] * d[ray], viewdirs[ray])
        alpha = alpha_of(sigma, samples.delta[flat])
        tr, rg, de, ac = trans[active], rgb[:, active], depth[active], acc[active]
        w = composite(_lane_major(alpha, valid), _lane_major(c, valid), _lane_major(tt, valid), tr, rg, de, ac)
        trans[active], rgb[:, active], depth[active], acc[active] = tr, rg, de, ac
        weights[flat] = w.T[valid]
        nxt[active] += cnt
        active = active[(tr >= min_t) & (nxt[active] < end[active])]
    out = np.ascontiguousarray(rgb.T)
    if white_background:
        out += (F32(1) - acc)[:, None]
    return Marched(out, depth, acc, weights)


def stratified(near: np.float32, far: np.float32, n: int, lindisp: bool) -> np.ndarray:
    """The deterministic coarse distances [n] (``stratified`` without jitter)."""
    s = np.arange(n, dtype=F32) / F32(n - 1) if n > 1 else np.zeros(n, F32)
    one = F32(1)
    if lindisp:
        return (one / (one / near * (one - s) + one / far * s)).astype(F32)
    return (near * (one - s) + far * s).astype(F32)


def importance(t: np.ndarray, weights: np.ndarray, n_fine: int) -> np.ndarray:
    """``importance`` without jitter, for all rays at once: inverse CDF of weights[1:-1] + 1e-5
    over the midpoints of ``t`` [R, n], at u = k/(n_fine − 1), right-side search → [R, n_fine]."""
    mids = F32(0.5) * (t[:, :-1] + t[:, 1:])
    w = weights[:, 1:-1] + F32(1e-5)
    total = np.cumsum(w, axis=1)[:, -1:]
    cdf = np.zeros((len(t), w.shape[1] + 1), F32)
    np.cumsum(w / total, axis=1, out=cdf[:, 1:])
    u = np.arange(n_fine, dtype=F32) / F32(n_fine - 1) if n_fine > 1 else np.zeros(n_fine, F32)
    above = (cdf[:, None, :] <= u[None, :, None]).sum(axis=2)
    below = np.maximum(above - 1, 0)
    above = np.minimum(above, cdf.shape[1] - 1)
    c0 = np.take_along_axis(cdf, below, axis=1)
    c1 = np.take_along_axis(cdf, above, axis=1)
    b0 = np.take_along_axis(mids, below, axis=1)
    b1 = np.take_along_axis(mids, above, axis=1)
    gap = c1 - c0
    denom = np.where(gap < F32(1e-5), F32(1), gap)
    frac = (u[None, :] - c0) / denom
    return (b0 + frac * (b1 - b0)).astype(F32)
