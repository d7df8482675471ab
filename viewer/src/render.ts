// Sampling, compositing and the two render paths of tests/python/render_rays.py (render: coarse
// + importance-sampled fine; march: equal steps through the occupancy grid with early
// termination), vectorised over batches of points for the field. Pure: the field is a callback.

import { norm3 } from "./camera";
import { marchSegments } from "./contraction";
import type { Grid } from "./march";
import { MAX_POINTS, MarchWasm } from "./marcher";

const f = Math.fround;

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

/** march(): march_steps equal intervals over [near, far] (a contracted grid: the segments of
 *  contraction.ts's marchSegments, δ of each sample its segment's), a sample at each middle, only samples in
 *  occupied cells evaluated (marched lazily with empty-space skipping, in WebAssembly: see
 *  marcher.ts), front to
 *  back in segments of `segment` occupied samples per ray; a ray stops after the segment where
 *  its transmittance falls below `minTransmittance`. Rays take turns in a queue, each handing
 *  the field its next `chunk` occupied samples, so every call carries up to MAX_POINTS.
 *  `timing`, when given, receives the split of the time outside the field. */
export async function renderMarch(s: Sampling, steps: number, white: boolean, grid: Grid, field: Field,
  o: Float32Array, d: Float32Array, view: Float32Array, cancelled: Cancelled = () => false,
  segment = 16, minTransmittance = 1e-4, chunk = segment, timing?: MarchTiming): Promise<Frame | null> {
  let t0 = performance.now(), marchMs = 0, compositeMs = 0, points = 0;
  const segments = marchSegments(s.near, s.far, steps, !!grid.contracted);
  const wasm = MarchWasm.take();
  try {
    if (grid.contracted) wasm.contracted(grid, o, d, segments);
    else wasm.straight(grid, o, d, segments[0].start, segments[0].interval, steps);
    let queued = wasm.start(viewDirs(view), segment, minTransmittance);
    while (queued > 0) {
      if (cancelled()) return null;
      const call = wasm.gather(chunk);
      let t1 = performance.now();
      marchMs += t1 - t0;
      if (call.points === 0) break;
      const out = await field(call.pts, call.dirs, call.points);
      points += call.points;
      t0 = performance.now();
      queued = wasm.composite(out.sigma, out.rgb, call.points, call.batch);
      t1 = performance.now();
      compositeMs += t1 - t0;
      t0 = t1;
    }
    const frame = wasm.frame(white);
    if (timing) { timing.marchMs += marchMs + performance.now() - t0; timing.compositeMs += compositeMs; }
    return { ...frame, points };
  } finally {
    wasm.give();
  }
}
