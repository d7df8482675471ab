"""Vectorised rendering: the same float32 arithmetic as ``core/src/render`` (grid.rs,
packed.rs, compositing.rs, dense.rs, sample/stratified.rs), over packed samples (a flat array
of distances with per-ray offsets) instead of per-ray loops."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

F32 = np.float32
#: Samples per ray per field call when marching front to back (``MARCH_SEGMENT``).
MARCH_SEGMENT = 16
#: Early-termination threshold (``DEFAULT_MIN_TRANSMITTANCE``).
MIN_TRANSMITTANCE = F32(1e-4)
LAST_DELTA = F32(1e10)
TRANSMITTANCE_EPS = F32(1e-10)
#: Steps tested one by one, with the exact float32 cell, where a probe falls within the margin
#: of its box (:class:`Marcher`).
WINDOW = 4
#: Steps past the last that :class:`Marcher` gives a time (a window's, a lane's past a ray's
#: last sample).
PAST = WINDOW + MARCH_SEGMENT
#: Samples a round evaluates and composites at a time (whole chunks), so their arrays stay in cache.
ROUND_BLOCK = 32768
#: Rays probed together (a working set small enough to stay in a core's cache).
MARCH_BLOCK = 16384
#: The working set takes rays from the queue once at most this fraction of it is still marching.
MARCH_REFILL = 0.5
#: Steps a probe in a contracted grid's shell tests at once (no boxes there: every step is tested).
SHELL_WINDOW = 16
#: The most segments a contracted march has (``MAX_SEGMENTS``).
MAX_SEGMENTS = 8

FieldFn = Callable[[np.ndarray, np.ndarray], Tuple[np.ndarray, np.ndarray]]


def expf(x: np.ndarray) -> np.ndarray:
    """float32 exp rounded from float64, i.e. correctly rounded like glibc's ``expf`` (which
    Rust's ``f32::exp`` calls); numpy's own float32 SIMD exp can be an ulp off, enough to move
    an importance sample across a CDF step."""
    e = x.astype(np.float64)
    np.exp(e, out=e)
    return e.astype(F32)


def lengths(d: np.ndarray) -> np.ndarray:
    """‖d‖ per row, float32, as ``length``: sqrt(x·x + y·y + z·z)."""
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])


def contract(p: np.ndarray) -> None:
    """``Contraction::Linf.apply`` in place on ``p`` [3, ...] float32, in its order: n = max(|x|,
    |y|, |z|) (a NaN operand skipped, as ``f32::max``), m = n if n > 1 else 1, r = 1/m,
    f = (2 − r)·r, c = x·f. Inside the cube ±1, f = 1: points stay as they are, bit for bit."""
    n = np.fmax(np.fmax(np.abs(p[0]), np.abs(p[1])), np.abs(p[2]))
    r = F32(1) / np.where(n > F32(1), n, F32(1))
    f = F32(2) - r
    f *= r
    p *= f


def march_segments(near: np.float32, far: np.float32, steps: int, contraction: Optional[str]) -> List[Tuple[np.float32, np.float32, int]]:
    """``march_segments``: (start, interval, steps) of the stretches marching steps through.
    Uncontracted: one, ``steps`` intervals over [near, far]. Contracted: n = max(steps/4, 1)
    intervals each, the first interval 2/n, each next one 4× the last, each start the last
    plus n × its interval (float32), while a start lies before ``far`` (at most
    ``MAX_SEGMENTS``).

    Example: near 0.1, far 200, 1024 steps → intervals 2/256, 1/32, 1/8, 1/2, 2 from 0.1, 2.1,
    10.1, 42.1, 170.1."""
    near, far = F32(near), F32(far)
    if contraction is None:
        return [(near, F32((far - near) / F32(steps)), steps)]
    n = max(steps // 4, 1)
    start, interval = near, F32(2) / F32(n)
    segments = []
    while True:
        segments.append((start, interval, n))
        start = F32(start + F32(n) * interval)
        interval = F32(interval * F32(4))
        if not start < far or len(segments) == MAX_SEGMENTS:
            return segments


def _step_times(segments: List[Tuple[np.float32, np.float32, int]], past: int, dtype: type) -> np.ndarray:
    """Each step's t = start + (k + 0.5)·interval in ``dtype`` (float32: ``March::t``; float64:
    the real t), segment after segment, then ``past`` more steps of the last segment."""
    parts = []
    for j, (start, interval, n) in enumerate(segments):
        k = np.arange(n + (past if j == len(segments) - 1 else 0), dtype=dtype)
        k += dtype(0.5)
        k *= dtype(interval)
        parts.append(dtype(start) + k)
    return np.concatenate(parts)


def unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` normalised as glam's ``normalize``: v · (1 / ‖v‖)."""
    return (v * (F32(1) / lengths(v))[:, None]).astype(F32)


#: Sides (in cells) of the corner tables' empty cubes, levels 1, 2, ...: level 1 is an empty
#: cell, the last a cube of 32 cells a side. Each side at most doubles the one before, so a
#: table is three shifted ANDs of the grid per level.
CORNER_SIDES = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32)
#: A corner table's levels from here on are occupied cells (:meth:`Grid.corner_table`).
OCCUPIED = 128
#: Guards the grids' cached tables: loops side by side march one grid.
_GRID_CACHE_LOCK = threading.RLock()


def octant_signs(octant: int) -> Tuple[int, int, int]:
    """The direction (+1 or −1) along x, y, z of ``octant`` 0..7 (bit 2: x, bit 1: y, bit 0:
    z; a set bit is +)."""
    return tuple(1 if octant >> (2 - axis) & 1 else -1 for axis in range(3))  # type: ignore[return-value]


def _corner_sides(cells: np.ndarray, octant: int) -> np.ndarray:
    """For ``cells`` [n, n, n] bool: per cell, how many sides of ``CORNER_SIDES`` have their
    cube with the cell at its corner, reaching along ``octant``, all true (past the array counts
    as true; 0 where the cell is false), uint8."""
    cube = cells.copy()
    count = cube.astype(np.uint8)
    side = 1
    for target in CORNER_SIDES[1:]:
        # The cube of side + shift at c is the 8 cubes of side at c + shift·{0, 1}³ (shift ≤ side).
        shift = target - side
        for axis, sign in enumerate(octant_signs(octant)):
            n = cube.shape[axis]
            if shift >= n:
                continue
            near, far = [slice(None)] * 3, [slice(None)] * 3
            near[axis], far[axis] = (slice(0, n - shift), slice(shift, n)) if sign > 0 else (slice(shift, n), slice(0, n - shift))
            cube[tuple(near)] &= cube[tuple(far)]
        side = target
        count += cube
    return count


@dataclass
class Grid:
    """Occupancy grid: ``occupied`` [R³] flat bool (cell (i, j, k) at (i·R + j)·R + k) over the
    cube ±``bound``; with ``contraction`` ("linf"), over the contracted world (bound 2): a point
    is contracted (:func:`contract`) before its cell is found."""

    occupied: np.ndarray
    resolution: int
    bound: np.float32
    contraction: Optional[str] = None

    def inner_cells(self) -> Tuple[int, int]:
        """The cells lo..hi − 1 per axis that lie inside the cube ±1 of a contracted grid, where
        the contraction leaves points as they are (cell i spans −2 + 4i/R .. −2 + 4(i + 1)/R)."""
        r = self.resolution
        return (r + 3) // 4, 3 * r // 4

    def padded(self) -> np.ndarray:
        """[R + 2]³ bool, cached: the grid with one empty cell on every side (outside the cube
        nothing is occupied)."""
        with _GRID_CACHE_LOCK:
            cached = self.__dict__.get("_padded")
            if cached is None:
                r = self.resolution
                cached = np.zeros((r + 2,) * 3, bool)
                cached[1:-1, 1:-1, 1:-1] = self.occupied.reshape(r, r, r)
                self.__dict__["_padded"] = cached
            return cached

    def corner_table(self, octant: int) -> np.ndarray:
        """[(R + 2)³] uint8, cached per octant, over the :meth:`padded` grid: for each cell, the
        largest side s in ``CORNER_SIDES`` such that the cube of s cells a side with this cell
        at its corner, reaching along the octant's directions (:func:`octant_signs`), is all
        empty (cells past the padding are) or all occupied, as its cell is: an empty cell's
        level is 1 + the index of s, an occupied cell's ``OCCUPIED`` + the index. A ray heading
        into that octant crosses the cube from the cell onwards.

        Example: one occupied cell, (2, 3, 4); for octant +x+y+z the cube at (1, 1, 1) of side 3
        (cells 1..3 per axis) is empty, that of side 4 holds (2, 3, 4): level 1 + 2 = 3; for
        octant −x−y−z every cube at (1, 1, 1) is empty: level 10; (2, 3, 4) itself: 128."""
        cells = (self.resolution + 2) ** 3
        return self.corner_tables([octant])[octant * cells:(octant + 1) * cells]

    def corner_tables(self, octants: Sequence[int]) -> np.ndarray:
        """[8·(R + 2)³] uint8, cached: the :meth:`corner_table` of octant q at q·(R + 2)³, made
        for ``octants`` (and any asked before); the others unset (their memory is not touched)."""
        cells = (self.resolution + 2) ** 3
        occupied = self.padded()
        with _GRID_CACHE_LOCK:
            tables = self.__dict__.get("_corner_tables")
            if tables is None:
                tables = self.__dict__["_corner_tables"] = np.empty(8 * cells, np.uint8)
                self.__dict__["_octants"] = set()
            made = self.__dict__["_octants"]
            for q in octants:
                if q not in made:
                    empty = _corner_sides(~occupied, q)
                    full = _corner_sides(occupied, q)
                    full += OCCUPIED - 1
                    tables[q * cells:(q + 1) * cells] = np.where(occupied, full, empty).reshape(-1)
                    made.add(q)
            return tables

    def occupied_along(self, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Whether the points o + t·d (float32, as ``point_at``) lie in occupied cells, for
        ``o``, ``d`` [3, m] and ``t`` [w, m] → [w, m] bool. The cell is
        ``OccupancyGrid::cell``'s, bit for bit: u = (v + b) / (2b) · R per axis (v contracted
        first on a contracted grid); outside the cube (or NaN) falls in the padding, which is
        empty."""
        b, r = self.bound, self.resolution
        two_b, rf, side = F32(2) * b, F32(r), r + 2
        u = t * d[:, None, :]  # [3, w, m]
        u += o[:, None, :]
        if self.contraction is not None:
            contract(u)
        u += b
        u /= two_b
        u *= rf
        # fmax/fmin turn NaN into -1 (the padding) as Rust's `!(u >= 0)` rejects it.
        np.fmax(u, F32(-1), out=u)
        np.fmin(u, rf, out=u)
        np.floor(u, out=u)
        cell = u.astype(np.int32)
        index = cell[0] * side
        index += cell[1]
        index *= side
        index += cell[2]
        # +1 per axis for the padding.
        index += side * side + side + 1
        return self.padded().reshape(-1).take(index)

    def t_range(self, o: np.ndarray, d: np.ndarray, half: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray]:
        """A conservative [t0, t1] per ray outside which no point lies in the cube (of half-side
        ``half``, default the grid's bound), for ``o``, ``d`` [3, n] float64."""
        b = np.float64(self.bound if half is None else half) * (1 + 1e-3) + 1e-6
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (-b - o) / d
            c = (b - o) / d
        lo, hi = np.fmin(a, c), np.fmax(a, c)
        # An axis the ray runs along: inside the slab is all t, outside none.
        parallel = d == 0
        if parallel.any():
            inslab = np.abs(o) <= b
            lo[parallel] = np.where(inslab, -np.inf, np.inf)[parallel]
            hi[parallel] = np.where(inslab, np.inf, -np.inf)[parallel]
        lo[np.isnan(lo)] = -np.inf
        hi[np.isnan(hi)] = np.inf
        return np.maximum(np.maximum(lo[0], lo[1]), lo[2]), np.minimum(np.minimum(hi[0], hi[1]), hi[2])


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
    step, the ray's cell and its :meth:`Grid.corner_table` level (for the octant the ray heads
    into) give a box of cells that is all occupied or all empty (the cube of cells with this
    one at its corner, reaching along the ray); the steps from the probe to where the
    ray leaves that box, shrunk by a margin far above float32 rounding, are then all occupied
    samples or all skipped, without testing each. A probe within the margin of the box (a ray
    along a cell face, non-finite values) tests a window of steps with the exact float32 cell
    instead. So the samples are those of testing every step, bit for bit.

    On a contracted grid the steps are those of :func:`march_segments` (intervals growing 4×
    a segment; δ = the sample's own interval · ‖d‖), every step of every segment is marched
    (the grid covers the world), boxes are used only inside the cube ±1, where contraction
    leaves points as they are, and in the shell every step is tested with the contracted
    float32 cell, ``SHELL_WINDOW`` at a time (as ``RayMarch`` does).

    The rays probe together, one numpy operation per step of the loop over a working set of
    rays (:meth:`_march`).

    # Shapes
    ``o``, ``d`` [n, 3] float32."""

    def __init__(self, grid: Grid, o: np.ndarray, d: np.ndarray, near: np.float32, far: np.float32, steps: int) -> None:
        self.grid = grid
        segments = march_segments(near, far, steps, grid.contraction)
        self.steps = sum(n for _, _, n in segments)
        # Step k samples t = start + (k + 0.5)·interval of its segment, the segments one after
        # the other; past `steps` (windows, lanes past a ray's last sample) only ever masked out.
        past = PAST if grid.contraction is None else SHELL_WINDOW + MARCH_SEGMENT
        self.t = _step_times(segments, past, F32)
        self.t_real = _step_times(segments, past, np.float64)
        self.o = np.ascontiguousarray(o.T, F32)  # [3, n]
        self.d = np.ascontiguousarray(d.T, F32)
        if grid.contraction is None:
            self.interval, self.intervals = segments[0][1], None
            self.delta = (self.interval * lengths(d)).astype(F32)
        else:
            # δ = the sample's segment's interval · ‖d‖ (:meth:`deltas`).
            self.interval, self.norm = None, lengths(d).astype(F32)
            self.intervals = np.concatenate([np.full(n, i, F32) for _, i, n in segments] + [np.full(past, segments[-1][1], F32)])
        self._boxes(self.o.astype(np.float64), self.d.astype(np.float64), near)
        self.tests = 0  # steps tested one by one so far (for measuring)
        self.probes = 0  # probes so far (for measuring)

    def _boxes(self, o: np.ndarray, d: np.ndarray, near: np.float32) -> None:
        """From ``o``, ``d`` [3, n] float64: each ray's first and end step (``cursor``, ``end``:
        the conservative cube range, :meth:`Grid.t_range`); in cell units u = (x + b)/(2b)·R =
        α + β·t per axis, ``coef`` [n, 19] = α, β, then per axis 1/β, |1/β| and the terms of the
        t at which the ray enters and leaves a box of cells shrunk by the margin m, and the
        ray's offset into ``table`` (:meth:`Grid.corner_tables`, at the octant it heads into);
        and on a contracted grid, per axis, the terms of the cells from a probe's to the far
        face of the cube ±1 (columns 19..24). Rays a block at a time, so the temporaries stay in
        cache."""
        grid, n = self.grid, o.shape[1]
        r = grid.resolution
        near64 = np.float64(near)
        self.coef = np.empty((n, 19 if grid.contraction is None else 25))
        self.cursor = np.empty(n, np.intp)
        self.end = np.empty(n, np.intp)
        octant = np.empty(n, np.intp)
        usable = np.empty(n, bool)
        for s in range(0, n, MARCH_BLOCK):
            e = min(s + MARCH_BLOCK, n)
            octant[s:e], usable[s:e] = self._boxes_of(o[:, s:e], d[:, s:e], near64, s)
        # The corner tables of the octants the rays head into; each ray's offset into them (+1
        # per axis for the padding) in the last column.
        used = [int(q) for q in np.unique(octant[usable])] or [0]
        self.table = grid.corner_tables(used)
        octant[~usable] = used[0]  # only ever test windows, but read a table that is made
        offset = octant * float((r + 2) ** 3)
        offset += (r + 2) ** 2 + (r + 2) + 1
        self.coef[:, 18] = offset

    def _boxes_of(self, o: np.ndarray, d: np.ndarray, near64: np.float64, first: int) -> Tuple[np.ndarray, np.ndarray]:
        """:meth:`_boxes` for the rays ``first``, ``first + 1``, ... (``o``, ``d`` [3, m]); returns
        their octants and whether the boxes can handle them."""
        grid, steps = self.grid, self.steps
        r, b = grid.resolution, np.float64(grid.bound)
        scale_u = r / (2.0 * b)
        rows = slice(first, first + o.shape[1])
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            if self.intervals is None:
                interval = np.float64(self.interval)
                t_max = float(np.abs(self.t_real[[0, steps - 1]]).max()) if steps else 0.0
                t0, t1 = grid.t_range(o, d)
                k0 = np.floor((t0 - near64) / interval - 0.5) - 1
                k1 = np.ceil((t1 - near64) / interval - 0.5) + 2
                steps_ok = np.isfinite(interval) and interval > 0
            else:
                k0, k1, t_max = self._contracted_range(o, d)
                t = self.t_real
                steps_ok = bool(np.isfinite(t).all() and (np.diff(t) > 0).all())
            scale = np.abs(o) + t_max * np.abs(d)
            np.maximum(scale, float(b), out=scale)
            scale = np.maximum(np.maximum(scale[0], scale[1]), scale[2])
            # As core's march_ray: far above the float32 error of a sample's position and cell.
            margin = (1e-3 * 2.0 * b / r + 64.0 * float(np.finfo(F32).eps) * scale) * scale_u
            coef = np.empty((18, o.shape[1]))
            alpha, beta, inv, per_r, enter, leave = (coef[3 * i:3 * i + 3] for i in range(6))
            np.multiply(o + b, scale_u, out=alpha)
            np.multiply(d, scale_u, out=beta)
            np.divide(1.0, beta, out=inv)
            np.abs(inv, out=per_r)
            frac = alpha - np.floor(alpha)
            flat = beta == 0
            # The box reaches along the ray; along a coordinate that never changes, towards the
            # side of the cell the ray is nearer.
            up = (beta > 0) | (flat & (frac >= 0.5))
            np.multiply(np.where(up, margin - alpha, (1.0 - margin) - alpha), inv, out=enter)
            np.multiply(np.where(up, -margin - alpha, (1.0 + margin) - alpha), inv, out=leave)
            if flat.any():
                # Inside the box on that axis for every t, or never (within the margin of a
                # face) unless the box reaches a cell past the face.
                safe = (frac >= margin) & (frac <= 1.0 - margin)
                inv[flat] = 0.0
                enter[flat] = -1e300
                per_r[flat] = np.where(safe, 0.0, 2e300)[flat]
                leave[flat] = np.where(safe, 1e300, -3e300)[flat]
            # Rays the boxes cannot handle (non-finite, a non-positive interval) only test windows.
            usable = np.isfinite(coef).all(axis=0) & np.isfinite(scale) & (margin < 0.25)
        if not steps_ok:
            usable[:] = False
        if not usable.all():
            coef[:, ~usable] = 0.0
            enter[:, ~usable] = np.inf
            leave[:, ~usable] = -np.inf
        # Ray by ray: a ray's coefficients are one row to fetch.
        self.coef[rows, :18] = coef.T
        if self.intervals is not None:
            # Cells to the inner cube's far face along the ray: hi − cell heading up, cell + 1 − lo down.
            lo, hi = grid.inner_cells()
            self.coef[rows, 19:22] = np.where(up, -1.0, 1.0).T
            self.coef[rows, 22:25] = np.where(up, float(hi), float(1 - lo)).T
        self.cursor[rows] = np.clip(np.nan_to_num(k0, nan=0, posinf=steps, neginf=0), 0, steps)
        self.end[rows] = np.clip(np.nan_to_num(k1, nan=steps, posinf=steps, neginf=0), 0, steps)
        return up[0] * 4 + up[1] * 2 + up[2], usable

    def _contracted_range(self, o: np.ndarray, d: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A contracted grid covers the whole world: every step is marched (first 0, end
        ``steps``). Boxes are used inside the cube ±1 only, so the rounding to cover is that of
        the steps there: per ray, the largest |t| of a step inside it (conservatively)."""
        m, t = o.shape[1], self.t_real
        t0, t1 = self.grid.t_range(o, d, 1.0)
        lo, hi = np.maximum(t0, t[0]), np.minimum(t1, t[self.steps - 1])
        t_max = np.where(lo <= hi, np.maximum(np.abs(lo), np.abs(hi)), abs(t[0]))
        return np.zeros(m), np.full(m, float(self.steps)), t_max

    def deltas(self, k: np.ndarray, ray: np.ndarray) -> np.ndarray:
        """δ of the samples at steps ``k`` of rays ``ray`` (alike shapes): interval · ‖d‖, float32."""
        if self.intervals is None:
            return self.delta.take(ray)
        return self.intervals.take(k) * self.norm.take(ray)

    def next(self, rays: np.ndarray, n: int = MARCH_SEGMENT) -> Tuple[np.ndarray, np.ndarray]:
        """The next (at most) ``n`` occupied steps of each of ``rays`` (indices, any order):
        steps [len(rays), n] int (row i's first ``counts[i]`` are valid, in order) and counts
        [len(rays)]; fewer than ``n`` means the ray has no more. Moves the rays on."""
        steps, live, found = self.advance(rays, n)
        out = np.zeros((len(rays), n), np.intp)
        out[live] = steps.T
        return out, found

    def advance(self, rays: np.ndarray, n: int = MARCH_SEGMENT) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`next`, lane-major and for the rays that found samples only: steps [n, L]
        (sample j of every such ray is row j; past a ray's count, the steps after its last),
        their places ``live`` [L] in ``rays``, and the counts [len(rays)] of all."""
        m = len(rays)
        found = np.zeros(m, np.intp)
        cursor, end = self.cursor[rays], self.end[rays]
        pos = np.flatnonzero(cursor < end)
        runs: List[Tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        if pos.size:
            self._march(rays, pos, cursor, end, found, runs, n)
            self.cursor[rays] = cursor
        live = np.flatnonzero(found)
        # A ray's samples are runs of consecutive steps. Each run writes (first step − its
        # lane) at its first lane; that grows from run to run, so a running maximum down the
        # lanes plus the lane gives every sample's step.
        steps = np.zeros((n, len(live)), np.intp)
        if runs:
            column = np.zeros(m, np.intp)
            column[live] = np.arange(len(live))
            row, lane, value = (np.concatenate(x) for x in zip(*runs))
            steps[lane, column.take(row)] = value
        np.maximum.accumulate(steps, axis=0, out=steps)
        steps += np.arange(n)[:, None]
        return steps, live, found

    def _march(self, rays: np.ndarray, queue: np.ndarray, cursor: np.ndarray, end: np.ndarray, found: np.ndarray,
               runs: list, n: int) -> None:
        """Move ``rays[queue]`` on to their next ``n`` occupied steps (or their end): a loop of
        probes over a working set of up to ``MARCH_BLOCK`` rays, refilled from the queue as its
        rays finish. Writes ``cursor`` and ``found``, and appends the runs of samples found to
        ``runs`` as (ray's place, first lane, first step − first lane)."""
        table, sides = self.table, np.ones(256)
        sides[1:1 + len(CORNER_SIDES)] = sides[OCCUPIED:OCCUPIED + len(CORNER_SIDES)] = CORNER_SIDES
        res, side = self.grid.resolution, self.grid.resolution + 2
        # Cell (i, j, k) → its place in a table (the ray's offset added).
        place = np.array([side * side, side, 1], np.float64)
        contracted = self.intervals is not None
        if not contracted:
            inv_interval, t0 = 1.0 / np.float64(self.interval), self.t_real[0]
        size = min(len(queue), MARCH_BLOCK)
        pos, queue = queue[:size], queue[size:]
        c = np.ascontiguousarray(self.coef.take(rays[pos], axis=0).T)
        k, e = cursor[pos], end[pos]
        f = np.zeros(size, np.intp)
        alive = np.ones(size, bool)
        # Scratch, reused (sliced to the working set) rather than allocated each probe.
        scratch = np.empty((11, size))
        index_buf = np.empty(size, np.intp)
        level_buf = np.empty(size, table.dtype)
        live = size
        while True:
            w = len(k)
            self.probes += live
            u, box = scratch[0:3, :w], scratch[3:6, :w]
            t, reach, enter, leave, index = (scratch[i, :w] for i in range(6, 11))
            self.t_real.take(k, out=t)
            np.multiply(c[3:6], t, out=u)
            u += c[0:3]
            np.floor(u, out=u)
            np.clip(u, -1, res, out=u)
            np.dot(place, u, out=index)
            index += c[18]
            np.copyto(index_buf[:w], index, casting="unsafe")
            level = table.take(index_buf[:w], out=level_buf[:w])
            sides.take(level, out=reach)
            if contracted:
                inner, reach = self._inner_box(c, u, reach)
            # The box's faces in t per axis: the cell's (u·inv), the far one `reach` cells on
            # (reach·|inv|), shrunk by the margin.
            u *= c[6:9]
            np.add(u, c[12:15], out=box)
            np.maximum(box[0], box[1], out=enter)
            np.maximum(enter, box[2], out=enter)
            np.multiply(c[9:12], reach, out=box)
            box += c[15:18]
            box += u
            np.minimum(box[0], box[1], out=leave)
            np.minimum(leave, box[2], out=leave)
            sure = enter <= t
            sure &= t <= leave
            sure &= alive
            if contracted:
                sure &= inner
                # The segments' steps are not evenly spaced: the last at or before the exit.
                move = np.searchsorted(self.t_real, leave, side="right")
                np.clip(move, k + 1, e, out=move)
            else:
                # Steps to the first past the box (at least one), within the ray's end.
                last = leave
                last -= t0
                last *= inv_interval
                np.floor(last, out=last)
                np.clip(last, k, e - 1, out=last)
                move = last.astype(np.intp)
                move += 1
            move -= k
            # An occupied box gives its steps as samples, as many as the ray still needs; an
            # empty box is skipped.
            occupied = level >= OCCUPIED
            np.minimum(move, n - f, out=move, where=occupied)
            move *= sure
            fill = np.flatnonzero(sure & occupied)
            if fill.size:
                runs.append((pos[fill], f[fill], k[fill] - f[fill]))
                f[fill] += move[fill]
            k += move
            # Within the margin of the box's faces: test a window of steps exactly.
            unsure = np.flatnonzero(alive & ~sure)
            if contracted:
                # In the shell every step is tested, many at a time.
                shell = ~inner[unsure]
                self._window(rays, unsure[shell], pos, k, e, f, runs, n, SHELL_WINDOW)
                unsure = unsure[~shell]
            if unsure.size:
                self._window(rays, unsure, pos, k, e, f, runs, n, WINDOW)
            alive &= f < n
            alive &= k < e
            live = int(np.count_nonzero(alive))
            if live <= w * MARCH_REFILL:
                done = ~alive
                cursor[pos[done]] = k[done]
                found[pos[done]] = f[done]
                if queue.size:
                    # Rays from the queue take the finished rays' places.
                    slots = np.flatnonzero(done)[:len(queue)]
                    more, queue = queue[:len(slots)], queue[len(slots):]
                    fresh = self.coef.take(rays[more], axis=0)
                    for row in range(len(c)):
                        c[row, slots] = fresh[:, row]
                    k[slots], e[slots], f[slots], pos[slots] = cursor[more], end[more], 0, more
                    alive[slots] = True
                    live += len(slots)
                elif not live:
                    return
                else:
                    # The queue is empty: finished rays leave the working set.
                    c, k, e, f, pos = c[:, alive], k[alive], e[alive], f[alive], pos[alive]
                    alive = np.ones(live, bool)

    def _inner_box(self, c: np.ndarray, cell: np.ndarray, reach: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """On a contracted grid, boxes stay inside the cube ±1 (where contraction is the
        identity, so cells are world boxes): for probes in ``cell`` [3, w] (cell coordinates),
        whether the cell lies inside it, and the box's reach per axis [3, w], cut at its far face."""
        lo, hi = self.grid.inner_cells()
        limit = c[19:22] * cell
        limit += c[22:25]
        inner = ((limit >= 1) & (limit <= hi - lo)).all(axis=0)
        np.minimum(limit, reach, out=limit)
        return inner, limit

    def _window(self, rays: np.ndarray, rows: np.ndarray, pos: np.ndarray, k: np.ndarray, e: np.ndarray, f: np.ndarray,
                runs: list, n: int, width: int) -> None:
        """Test the next ``width`` (``WINDOW`` or ``SHELL_WINDOW``) steps of the marching rays ``rows`` with the
        exact float32 cell; record the occupied ones (as many as needed) as runs of one step and
        move the rays on."""
        if not rows.size:
            return
        ray = rays[pos[rows]]
        # Lane-major: step j of every ray in row j.
        kk = k[rows] + np.arange(width)[:, None]
        occupied = self.grid.occupied_along(self.o[:, ray], self.d[:, ray], self.t[kk])
        self.tests += kk.size
        occupied &= kk < e[rows]
        rank = np.cumsum(occupied, axis=0)
        need = n - f[rows]
        take = occupied & (rank <= need)
        step, col = np.nonzero(take)
        lane = f[rows[col]] + rank[step, col] - 1
        runs.append((pos[rows[col]], lane, kk[step, col] - lane))
        got = np.minimum(rank[-1], need)
        f[rows] += got
        # Past the window; a ray that got all it needs resumes after its last sample.
        moved = kk[-1] + 1
        full = np.flatnonzero(got == need)
        moved[full] = kk[np.argmax(rank[:, full] >= need[full], axis=0), full] + 1
        k[rows] = moved


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
    steps = np.empty(offsets[-1], np.intp)
    filled = offsets[:-1].copy()
    for live, k, valid in parts:
        cnt = valid.sum(axis=1)
        where = (filled[live][:, None] + np.arange(k.shape[1])[None, :])[valid]
        steps[where] = k[valid]
        filled[live] += cnt
    t[:] = marcher.t[steps]
    return Packed(t, marcher.deltas(steps, np.repeat(rays, counts)), offsets)


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
    ``composite`` (α, compositing, bookkeeping). Where ``loops`` loops ran side by side, each
    stage is their mean. ``native``: the loop ran in Rust (:mod:`_native`), where marching,
    gathering and compositing are one pass: ``march`` holds all three."""

    rays: float = 0.0
    march: float = 0.0
    gather: float = 0.0
    field: float = 0.0
    composite: float = 0.0
    loops: int = 1
    native: bool = False

    def add_mean(self, parts: Sequence["Stages"]) -> None:
        """Add the mean of the stages of ``parts``, loops that ran side by side."""
        for name in ("rays", "march", "gather", "field", "composite"):
            setattr(self, name, getattr(self, name) + sum(getattr(p, name) for p in parts) / len(parts))
        self.loops = max(self.loops, len(parts))
        self.native = self.native or any(p.native for p in parts)

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
    x = np.maximum(sigma, F32(0))
    x *= delta
    np.negative(x, out=x)
    return F32(1) - expf(x)


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
    round and composited (:func:`composite_lanes`); a ray stops once T < ``min_transmittance``
    (``None``: never) or when it has no more samples.

    The rays are marched together, a round at a time; a round's samples go to the field in
    blocks of at most ``batch`` × ``MARCH_SEGMENT`` points (the points ``batch`` rays send
    nerf-render's field in a round) and about ``ROUND_BLOCK`` (so a block's arrays stay in
    cache). A point's output does not depend on the others in its call, so the pixels are those
    of nerf-render's calls, chunk by chunk."""
    stages = stages if stages is not None else Stages()
    n = len(o)
    trans = np.ones(n, F32)
    rgb = np.zeros((3, n), F32)
    depth = np.zeros(n, F32)
    acc = np.zeros(n, F32)
    min_t = F32(-np.inf) if min_transmittance is None else F32(min_transmittance)
    now = time.perf_counter()
    marcher = Marcher(grid, o, d, near, far, steps)
    state = (trans, rgb, depth, acc)
    most = max(1, min(batch * MARCH_SEGMENT, ROUND_BLOCK))
    active = np.arange(n)
    while active.size:
        k, live, cnt = marcher.advance(active)
        active, cnt = active[live], cnt[live]
        now = stages.lap("march", now)
        if not active.size:
            break
        # Blocks of consecutive rays with at most `most` samples.
        ends = np.cumsum(cnt)
        bounds = [0]
        while bounds[-1] < len(active):
            first = bounds[-1]
            limit = (ends[first - 1] if first else 0) + most
            bounds.append(max(first + 1, int(np.searchsorted(ends, limit, side="right"))))
        going = []
        for a, b in zip(bounds[:-1], bounds[1:]):
            rays, now = _round_block(field, marcher, viewdirs, k[:, a:b], cnt[a:b], active[a:b], state, min_t, stages, now)
            going.append(rays)
        active = np.concatenate(going)
    out = np.ascontiguousarray(rgb.T)
    if white_background:
        out += (F32(1) - acc)[:, None]
    return Marched(out, depth, acc, None)


def _round_block(field: FieldFn, marcher: Marcher, viewdirs: np.ndarray, k: np.ndarray, cnt: np.ndarray, active: np.ndarray,
                 state: Tuple[np.ndarray, ...], min_t: np.float32, stages: Stages, now: float) -> Tuple[np.ndarray, float]:
    """One round of :func:`march_grid` for a block of rays: the field's inputs for the
    ``active`` rays' next samples (steps ``k`` [S, m], ``cnt`` [m] ≥ 1), one field call, and
    the compositing into ``state`` (trans, rgb, depth, acc); returns the rays that go on (T ≥
    ``min_t`` and a full segment) and the time of the last lap.

    The rays are ordered by their count, most first (stable), so that sample j of every ray
    that has one is a prefix of the rays: lane j's samples are the first ``lanes[j]`` rays'
    and every per-lane operation works on contiguous slices. The field sees the samples lane
    after lane."""
    s = len(k)
    order = np.argsort((s - cnt).astype(np.uint8), kind="stable")  # a radix sort
    rays, cnt = active.take(order), cnt.take(order)
    k = k.take(order, axis=1)
    # lanes[j]: the rays with more than j samples (cnt is descending); their samples from at[j].
    lanes = np.searchsorted(-cnt, -np.arange(s), side="left")
    at = np.zeros(s + 1, np.intp)
    np.cumsum(lanes, out=at[1:])
    t_lanes = marcher.t.take(k)
    d, o, v = marcher.d.take(rays, axis=1), marcher.o.take(rays, axis=1), viewdirs.take(rays, axis=0)
    delta_lanes = marcher.deltas(k, np.broadcast_to(rays, k.shape))
    total = int(at[-1])
    points = np.empty((total, 3), F32)
    dirs = np.empty((total, 3), F32)
    t = np.empty(total, F32)
    delta = np.empty(total, F32)
    for j in range(s):
        m = int(lanes[j])
        if not m:
            break
        a, b = at[j], at[j + 1]
        t[a:b] = t_lanes[j, :m]
        delta[a:b] = delta_lanes[j, :m]
        p = points[a:b].T
        np.multiply(t[a:b], d[:, :m], out=p)
        p += o[:, :m]
        dirs[a:b] = v[:m]
    now = stages.lap("gather", now)
    colour, sigma = field(points, dirs)
    now = stages.lap("field", now)
    alpha = alpha_of(sigma, delta)
    trans, rgb, depth, acc = state
    tr, rg, de, ac = trans.take(rays), rgb.take(rays, axis=1), depth.take(rays), acc.take(rays)
    composite_lanes(alpha, colour, t, at, tr, rg, de, ac)
    trans[rays], rgb[:, rays], depth[rays], acc[rays] = tr, rg, de, ac
    return rays[(tr >= min_t) & (cnt == s)], stages.lap("composite", now)


def composite_lanes(alpha: np.ndarray, colour: np.ndarray, t: np.ndarray, at: np.ndarray, trans: np.ndarray, rgb: np.ndarray,
                    depth: np.ndarray, acc: np.ndarray) -> None:
    """:func:`composite` over samples packed lane after lane: lane j's samples ``at[j]:at[j + 1]``
    of ``alpha``, ``t`` [N] and ``colour`` [N, 3] belong to the first ``at[j + 1] − at[j]`` rays of
    the state (each ray's samples in order, one lane after the other)."""
    factor = (F32(1) - alpha) + TRANSMITTANCE_EPS
    for j in range(len(at) - 1):
        a, b = at[j], at[j + 1]
        m = b - a
        if not m:
            break
        w = alpha[a:b] * trans[:m]
        for c in range(3):
            rgb[c, :m] += w * colour[a:b, c]
        depth[:m] += w * t[a:b]
        acc[:m] += w
        trans[:m] *= factor[a:b]


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
