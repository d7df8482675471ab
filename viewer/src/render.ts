// Sampling, compositing and the two render paths of tests/python/render_rays.py (render: coarse
// + importance-sampled fine; march: equal steps through the occupancy grid with early
// termination), vectorised over batches of points for the field. Pure: the field is a callback.

import { norm3 } from "./camera";
import { ContractedMarch } from "./contracted";
import { marchSegments } from "./contraction";
import { type Grid, type Marcher, RayMarch } from "./march";

const f = Math.fround;

/** At most this many points per field (onnxruntime) call: WASM memory caps one call near 64k. */
export const MAX_POINTS = 65536;

/** rgb [N,3] and sigma [N] for points [N,3] and unit viewdirs [N,3]. */
export type Field = (points: Float32Array, viewdirs: Float32Array, n: number) => Promise<{ rgb: Float32Array; sigma: Float32Array }>;

export interface Sampling { near: number; far: number; n_coarse: number; n_fine: number; lindisp: boolean }


/** The output of a frame: rgb [N,3], depth [N], acc [N], and the number of points evaluated. */
export interface Frame { rgb: Float32Array; depth: Float32Array; acc: Float32Array; points: number }

/** Coarse sample distances t_k (test time: no jitter; lindisp in 1/t). */
export function coarseT(s: Sampling): Float32Array {
  const n = s.n_coarse, near = f(s.near), far = f(s.far), t = new Float32Array(n);
  const div = f(Math.max(n - 1, 1));
  for (let k = 0; k < n; k++) {
    const u = f(k / div), v = f(1 - u);
    t[k] = s.lindisp ? f(1 / f(f(f(1 / near) * v) + f(f(1 / far) * u))) : f(f(near * v) + f(far * u));
  }
  return t;
}

// expAlpha's table: 2^(i/32) for i in −EXP_STEPS..0 (−EXP_STEPS/32 < −104/ln 2).
const EXP_STEPS = 4832, EXP_TABLE = new Float64Array(EXP_STEPS + 1);
for (let i = 0; i <= EXP_STEPS; i++) EXP_TABLE[i] = 2 ** ((i - EXP_STEPS) / 32);
// ln 2 / 32 in two parts (fdlibm's ln2_hi, exact in a product with |n| < 2²¹, and ln2_lo).
const LN2_32_HI = 6.93147180369123816490e-01 / 32, LN2_32_LO = 1.90821492927058770002e-10 / 32, PER_LN2_32 = 32 / Math.LN2;

/** exp(x) for compositing's x = −σ·δ ≤ 0, within 3e-15 (relative) of Math.exp, which V8 calls
 *  out of line (13 ns a sample here, against 7): 2^(n/32) from a table times a degree-5
 *  polynomial of the remainder, |r| < ln 2 / 32. Below −104 the float32 α is 1 either way;
 *  anything else (x > 0, NaN) takes Math.exp. */
export function expAlpha(x: number): number {
  if (!(x > -104 && x <= 0)) return Math.exp(x);
  const n = (x * PER_LN2_32 - 0.5) | 0; // rounds: x·32/ln 2 ≤ 0
  const r = x - n * LN2_32_HI - n * LN2_32_LO;
  return EXP_TABLE[n + EXP_STEPS] * (1 + r * (1 + r * (0.5 + r * (1 / 6 + r * (1 / 24 + r / 120)))));
}

/** weights_of for one ray: t [S], sigma [S] → w [S] (delta·|d|, last 1e10·|d|, exclusive cumprod). */
export function weightsOf(t: ArrayLike<number>, sigma: ArrayLike<number>, dnorm: number, out: Float32Array): Float32Array {
  const S = t.length;
  let trans = 1;
  for (let k = 0; k < S; k++) {
    const delta = f((k + 1 < S ? f(t[k + 1] - t[k]) : 1e10) * dnorm);
    const alpha = f(1 - f(Math.exp(f(-Math.max(sigma[k], 0) * delta))));
    out[k] = f(alpha * trans);
    trans = f(trans * f(f(1 - alpha) + f(1e-10)));
  }
  return out;
}

/** The deterministic quantiles k/(n-1) in f32, as nerf-render (numpy's linspace differs in ulps). */
export function linspace01(n: number): Float32Array {
  const u = new Float32Array(n), step = 1 / (n - 1);
  for (let i = 0; i < n; i++) u[i] = f(i) / f(n - 1);
  if (n > 1) u[n - 1] = 1;
  if (n === 1) u[0] = 0;
  return u;
}

/** sample_pdf for one ray: inverse CDF of weights + 1e-5 over bins at u = linspace(0, 1, n), right-side search. */
export function samplePdf(bins: ArrayLike<number>, weights: ArrayLike<number>, u: Float32Array, out: Float32Array): Float32Array {
  const nw = weights.length, w = new Float32Array(nw);
  for (let k = 0; k < nw; k++) w[k] = f(weights[k] + f(1e-5));
  // Summed in order as nerf-render's sample_pdf_ray (numpy sums pairwise: ulps apart).
  let total = 0;
  for (let k = 0; k < nw; k++) total = f(total + w[k]);
  const cdf = new Float32Array(nw + 1);
  for (let k = 0; k < nw; k++) cdf[k + 1] = f(cdf[k] + f(w[k] / total));
  for (let q = 0; q < u.length; q++) {
    // searchsorted(side="right"): the number of cdf entries <= u.
    let lo = 0, hi = cdf.length;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (cdf[mid] <= u[q]) lo = mid + 1; else hi = mid; }
    const below = Math.max(lo - 1, 0), above = Math.min(lo, cdf.length - 1);
    const c0 = cdf[below], c1 = cdf[above];
    const gap = f(c1 - c0), denom = gap < 1e-5 ? 1 : gap;
    out[q] = f(bins[below] + f(f(f(u[q] - c0) / denom) * f(bins[above] - bins[below])));
  }
  return out;
}

/** Unit view directions (float32) of view [N,3]. */
export function viewDirs(view: Float32Array): Float32Array {
  const out = new Float32Array(view.length);
  for (let r = 0; r < view.length / 3; r++) {
    const n = norm3(view[3 * r], view[3 * r + 1], view[3 * r + 2]);
    for (let a = 0; a < 3; a++) out[3 * r + a] = f(view[3 * r + a] / n);
  }
  return out;
}

/** Cancellation: a render polls this between field calls and stops when it returns true. */
export type Cancelled = () => boolean;

/** render(): coarse stage, then (n_fine > 0) the fine stage at importance samples; rays in
 *  batches of at most MAX_POINTS points. o, d: sampling rays (NDC-warped if any); view: world d. */
export async function renderDense(s: Sampling, white: boolean, coarse: Field, fine: Field | null,
  o: Float32Array, d: Float32Array, view: Float32Array, cancelled: Cancelled = () => false): Promise<Frame | null> {
  const n = o.length / 3, nc = s.n_coarse, nf = fine ? s.n_fine : 0, S = nc + nf;
  const rgbOut = new Float32Array(3 * n), depth = new Float32Array(n), acc = new Float32Array(n);
  const tc = coarseT(s), vd = viewDirs(view), u = nf > 0 ? linspace01(nf) : new Float32Array(0);
  const perBatch = Math.max(1, Math.floor(MAX_POINTS / S));
  let points = 0;
  const stage = async (field: Field, t: Float32Array, r0: number, m: number, ns: number) => {
    const pts = new Float32Array(3 * m * ns), dirs = new Float32Array(3 * m * ns);
    for (let r = 0; r < m; r++) for (let k = 0; k < ns; k++) {
      const p = r * ns + k, tt = t[p];
      for (let a = 0; a < 3; a++) {
        pts[3 * p + a] = f(o[3 * (r0 + r) + a] + f(tt * d[3 * (r0 + r) + a]));
        dirs[3 * p + a] = vd[3 * (r0 + r) + a];
      }
    }
    points += m * ns;
    return field(pts, dirs, m * ns);
  };
  for (let r0 = 0; r0 < n; r0 += perBatch) {
    if (cancelled()) return null;
    const m = Math.min(perBatch, n - r0);
    let ns = nc, t = new Float32Array(m * nc);
    for (let r = 0; r < m; r++) t.set(tc, r * nc);
    let out = await stage(coarse, t, r0, m, nc);
    let w = new Float32Array(m * ns);
    const dn = new Float32Array(m);
    for (let r = 0; r < m; r++) {
      const q = 3 * (r0 + r);
      dn[r] = norm3(d[q], d[q + 1], d[q + 2]);
      weightsOf(t.subarray(r * ns, (r + 1) * ns), out.sigma.subarray(r * ns, (r + 1) * ns), dn[r], w.subarray(r * ns, (r + 1) * ns));
    }
    if (nf > 0 && fine) {
      const t2 = new Float32Array(m * S), mids = new Float32Array(nc - 1), extra = new Float32Array(nf);
      for (let r = 0; r < m; r++) {
        const tr = t.subarray(r * nc, (r + 1) * nc);
        for (let k = 0; k < nc - 1; k++) mids[k] = f(0.5 * f(tr[k + 1] + tr[k]));
        samplePdf(mids, w.subarray(r * nc + 1, (r + 1) * nc - 1), u, extra);
        const row = t2.subarray(r * S, (r + 1) * S);
        row.set(tr); row.set(extra, nc); row.sort();
      }
      if (cancelled()) return null;
      t = t2; ns = S;
      out = await stage(fine, t, r0, m, ns);
      w = new Float32Array(m * ns);
      for (let r = 0; r < m; r++)
        weightsOf(t.subarray(r * ns, (r + 1) * ns), out.sigma.subarray(r * ns, (r + 1) * ns), dn[r], w.subarray(r * ns, (r + 1) * ns));
    }
    for (let r = 0; r < m; r++) {
      const R = r0 + r;
      // Sums front to back, as nerf-render's RayAccumulator (numpy's pairwise sums differ in ulps).
      let cr = 0, cg = 0, cb = 0, z = 0, a = 0;
      for (let k = 0; k < ns; k++) {
        const p = r * ns + k, wk = w[p];
        cr = f(cr + f(wk * out.rgb[3 * p])); cg = f(cg + f(wk * out.rgb[3 * p + 1])); cb = f(cb + f(wk * out.rgb[3 * p + 2]));
        z = f(z + f(wk * t[p])); a = f(a + wk);
      }
      const bg = white ? f(1 - a) : 0;
      rgbOut[3 * R] = f(cr + bg); rgbOut[3 * R + 1] = f(cg + bg); rgbOut[3 * R + 2] = f(cb + bg);
      depth[R] = z; acc[R] = a;
    }
  }
  return { rgb: rgbOut, depth, acc, points };
}

/** Where a marched frame's time outside the field went, in ms: marching and packing the
 *  samples, and compositing them. */
export interface MarchTiming { marchMs: number; compositeMs: number }

/** renderMarch's queue of rays waiting for their next samples (a ring from `head`, `queued`
 *  long), and the points the last gathered call holds. */
interface Ring { head: number; queued: number; points: number }

/** Gather the next occupied samples of as many queued rays as fit in one field call (each at
 *  most `chunk`, MAX_POINTS in all): positions into `pts`, view directions into `dirs`, steps
 *  into `ks`; the rays and their counts into `rays`, `counts`. Rays with no samples left leave
 *  the queue. Returns how many rays; `ring.points` the samples. A plain function, as sumPass. */
function gatherCall(march: Marcher, vd: Float32Array, chunk: number, queue: Int32Array, ring: Ring, pts: Float32Array,
  dirs: Float32Array, ks: Int32Array, rays: Int32Array, counts: Int32Array): number {
  const n = queue.length;
  let m = 0, batch = 0, head = ring.head, queued = ring.queued;
  while (queued > 0 && m + chunk <= MAX_POINTS) {
    const r = queue[head];
    head = head + 1 === n ? 0 : head + 1; queued--;
    const c = march.next(r, chunk, pts, ks, m);
    if (c === 0) continue; // no samples left: done
    const vx = vd[3 * r], vy = vd[3 * r + 1], vz = vd[3 * r + 2];
    for (let p = m; p < m + c; p++) { dirs[3 * p] = vx; dirs[3 * p + 1] = vy; dirs[3 * p + 2] = vz; }
    rays[batch] = r; counts[batch] = c; batch++; m += c;
  }
  ring.head = head; ring.queued = queued; ring.points = m;
  return batch;
}

/** What compositing a marched frame's field calls keeps between them (renderMarch's arrays). */
interface MarchState {
  rgb: Float32Array; depth: Float32Array; acc: Float32Array; trans: Float32Array; done: Int32Array;
  stepLen: Float32Array; dNorm: Float32Array; t: Float32Array; stepInterval: Float32Array | null;
  cursor: Int32Array; end: Int32Array; queue: Int32Array; segment: number; minTransmittance: number;
  alphas: Float32Array;
}

/** α of one field call's samples (`counts[q]` for ray `rays[q]`, q < `batch`, their steps in
 *  `ks`) into `st.alphas`: compositing's first pass. Each hot loop around the field is a
 *  function of its own (here, in march.ts and hashgrid.ts): V8 compiles a long loop alone during
 *  a first call (on-stack replacement), before the code after it has run; later calls enter that
 *  code again and fall out of it where the next loop starts, until the whole function is
 *  compiled (Node's --trace-deopt on a replayed lego-ngp frame: at the sums' loop 2 to 50 times
 *  in the first two frames, when α and the sums were one function). */
function alphaPass(st: MarchState, sig: Float32Array, ks: Int32Array, rays: Int32Array, counts: Int32Array, batch: number): void {
  const { stepLen, dNorm, stepInterval, alphas } = st;
  let p = 0;
  for (let q = 0; q < batch; q++) {
    const r = rays[q], e = p + counts[q], len = stepLen[r], dn = dNorm[r];
    if (stepInterval === null) for (; p < e; p++) alphas[p] = f(1 - f(expAlpha(f(-Math.max(sig[p], 0) * len))));
    else for (; p < e; p++) alphas[p] = f(1 - f(expAlpha(f(-Math.max(sig[p], 0) * f(stepInterval[ks[p]] * dn)))));
  }
}

/** Composite one field call's samples (`counts[q]` for ray `rays[q]`, q < `batch`, their steps
 *  in `ks`, their α from alphaPass) into their rays in order, with RayAccumulator's float32
 *  arithmetic; the segment count runs over a ray's occupied samples, and a ray stops after the
 *  segment where its transmittance falls below the threshold, or after its last. The rays that
 *  go on join the queue (ring of `queue.length`, from `head`); returns its new length. A plain
 *  function rather than part of renderMarch's async loop: V8 optimises a hot loop of a function
 *  it has called a few times, while one inside an async function waits for that function's own
 *  optimisation (a page's first frame composited at half speed). */
function sumPass(st: MarchState, col: Float32Array, ks: Int32Array, rays: Int32Array,
  counts: Int32Array, batch: number, head: number, queued: number): number {
  const { rgb, depth, acc, trans, done, t, cursor, end, queue, segment, minTransmittance } = st;
  const n = queue.length, alphas = st.alphas;
  let p = 0;
  for (let q = 0; q < batch; q++) {
    const r = rays[q], p0 = p;
    let T = trans[r], stopped = false, cr = rgb[3 * r], cg = rgb[3 * r + 1], cb = rgb[3 * r + 2], z = depth[r], a = acc[r], nd = done[r];
    // Samples to the end of the ray's current segment (a countdown, not a modulo per sample).
    let toSegmentEnd = segment - (nd % segment);
    for (let c = 0; c < counts[q]; c++, p++) {
      const alpha = alphas[p];
      const w = f(alpha * T);
      cr = f(cr + f(w * col[3 * p])); cg = f(cg + f(w * col[3 * p + 1])); cb = f(cb + f(w * col[3 * p + 2]));
      z = f(z + f(w * t[ks[p]]));
      a = f(a + w);
      T = f(T * f(f(1 - alpha) + f(1e-10)));
      nd++;
      if (--toSegmentEnd === 0) {
        toSegmentEnd = segment;
        if (T < minTransmittance) { stopped = true; break; }
      }
    }
    rgb[3 * r] = cr; rgb[3 * r + 1] = cg; rgb[3 * r + 2] = cb; depth[r] = z; acc[r] = a; done[r] = nd;
    p = p0 + counts[q];
    trans[r] = T;
    // A ray also stops after its last (partial) segment; cursor at the end means no samples left.
    if (!stopped && cursor[r] < end[r]) { queue[(head + queued) % n] = r; queued++; }
  }
  return queued;
}

/** Per ray of directions `d` [n, 3]: |d| into dNorm, a step's length interval·|d| into stepLen. */
function rayLengths(d: Float32Array, interval: number, dNorm: Float32Array, stepLen: Float32Array): void {
  for (let r = 0; r < dNorm.length; r++) {
    dNorm[r] = norm3(d[3 * r], d[3 * r + 1], d[3 * r + 2]);
    stepLen[r] = f(interval * dNorm[r]);
  }
}

/** The rays with steps left (cursor < end) into `queue`, in order; returns how many. */
function queueLive(cursor: Int32Array, end: Int32Array, queue: Int32Array): number {
  let queued = 0;
  for (let r = 0; r < cursor.length; r++) if (cursor[r] < end[r]) queue[queued++] = r;
  return queued;
}

/** A white background: each ray's rgb + (1 − acc). */
function addWhite(rgb: Float32Array, acc: Float32Array): void {
  for (let r = 0; r < acc.length; r++) { const bg = f(1 - acc[r]); for (let a = 0; a < 3; a++) rgb[3 * r + a] = f(rgb[3 * r + a] + bg); }
}

/** march(): march_steps equal intervals over [near, far] (a contracted grid: the segments of
 *  contraction.ts's marchSegments, δ of each sample its segment's), a sample at each middle, only samples in
 *  occupied cells evaluated (marched lazily with empty-space skipping, see march.ts), front to
 *  back in segments of `segment` occupied samples per ray; a ray stops after the segment where
 *  its transmittance falls below `minTransmittance`. Rays take turns in a queue, each handing
 *  the field its next `chunk` occupied samples, so every call carries up to MAX_POINTS.
 *  `timing`, when given, receives the split of the time outside the field. */
export async function renderMarch(s: Sampling, steps: number, white: boolean, grid: Grid, field: Field,
  o: Float32Array, d: Float32Array, view: Float32Array, cancelled: Cancelled = () => false,
  segment = 16, minTransmittance = 1e-4, chunk = segment, timing?: MarchTiming): Promise<Frame | null> {
  const n = o.length / 3, near = f(s.near), far = f(s.far);
  const interval = f(f(far - near) / f(steps));
  const clock = { marchMs: 0, compositeMs: 0 };
  let t0 = performance.now();
  const vd = viewDirs(view);
  const march: Marcher = grid.contracted ? new ContractedMarch(grid, o, d, marchSegments(near, far, steps, true))
    : new RayMarch(grid, o, d, near, interval, steps);
  const t = march.t, cursor = march.cursor, end = march.end;
  // Contracted: each step's own interval (null: every step's is `interval`, in stepLen).
  const stepInterval = march instanceof ContractedMarch ? march.interval : null;
  const rgb = new Float32Array(3 * n), depth = new Float32Array(n), acc = new Float32Array(n);
  const done = new Int32Array(n), trans = new Float32Array(n).fill(1), stepLen = new Float32Array(n), dNorm = new Float32Array(n);
  rayLengths(d, interval, dNorm, stepLen);
  // A ring of the rays waiting for their next samples: each ray is in it at most once.
  const queue = new Int32Array(Math.max(n, 1));
  const ring: Ring = { head: 0, queued: queueLive(cursor, end, queue), points: 0 };
  const pts = new Float32Array(3 * MAX_POINTS), dirs = new Float32Array(3 * MAX_POINTS), ks = new Int32Array(MAX_POINTS);
  const rays = new Int32Array(MAX_POINTS), counts = new Int32Array(MAX_POINTS);
  const alphas = new Float32Array(MAX_POINTS);
  const state: MarchState = { rgb, depth, acc, trans, done, stepLen, dNorm, t, stepInterval, cursor, end, queue, segment, minTransmittance, alphas };
  let points = 0;
  while (ring.queued > 0) {
    if (cancelled()) return null;
    const batch = gatherCall(march, vd, chunk, queue, ring, pts, dirs, ks, rays, counts), m = ring.points;
    let t1 = performance.now();
    clock.marchMs += t1 - t0;
    if (m === 0) break;
    const out = await field(pts.subarray(0, 3 * m), dirs.subarray(0, 3 * m), m);
    points += m;
    t0 = performance.now();
    alphaPass(state, out.sigma, ks, rays, counts, batch);
    ring.queued = sumPass(state, out.rgb, ks, rays, counts, batch, ring.head, ring.queued);
    t1 = performance.now();
    clock.compositeMs += t1 - t0;
    t0 = t1;
  }
  if (white) addWhite(rgb, acc);
  if (timing) { timing.marchMs += clock.marchMs + performance.now() - t0; timing.compositeMs += clock.compositeMs; }
  return { rgb, depth, acc, points };
}
