// Scene contraction (nerf-rs-scene-3 bundles) as core/src/sample/contraction.rs and the marching
// segments of core/src/render/grid.rs's march_segments, with the same float32 operations in
// the same order (Math.fround after each), so a sample lands in the same occupancy cell, at
// the same t, as in nerf-render. Pure.

const f = Math.fround;

/** Half the side of the cube a contracted world fills (a contracted grid's bound). */
export const CONTRACTED_HALF_SIZE = 2;

/** The factor the L∞ contraction scales a point by: n = max(|x|, |y|, |z|), m = (n > 1 ? n : 1),
 *  r = 1/m, (2 − r)·r. Exactly 1 inside the unit cube, so contracted points there stay bit for
 *  bit. (A NaN coordinate gives a NaN point either way, as in Rust, whose max skips NaN.) */
export function contractionFactor(x: number, y: number, z: number): number {
  const n = Math.max(Math.abs(x), Math.abs(y), Math.abs(z));
  const r = f(1 / (n > 1 ? n : 1));
  return f(f(2 - r) * r);
}

/** Contraction::Linf.apply: x where ‖x‖∞ ≤ 1, else (2 − 1/‖x‖∞)·x/‖x‖∞ (inside [−2, 2]³). */
export function contract(p: readonly number[]): number[] {
  const s = contractionFactor(p[0], p[1], p[2]);
  return [f(p[0] * s), f(p[1] * s), f(p[2] * s)];
}

/** `steps` equal intervals of `interval` from t = `start`. */
export interface Segment { start: number; interval: number; steps: number }

/** The most segments a contracted march has (the fifth starts ≈ 170 units out). */
export const MAX_SEGMENTS = 8;

/** Where marching steps along a ray: one segment of `steps` intervals over [near, far]; over a
 *  contracted world segments of max(⌊steps/4⌋, 1) intervals, the first spanning 2 (the inner
 *  cube's side), each next interval 4× the last, while a segment starts before far
 *  (MAX_SEGMENTS at most): steps grow with distance as the contraction shrinks what lies far. */
export function marchSegments(near: number, far: number, steps: number, contracted: boolean): Segment[] {
  near = f(near); far = f(far);
  if (!contracted) return [{ start: near, interval: f(f(far - near) / f(steps)), steps }];
  const n = Math.max(Math.floor(steps / 4), 1), out: Segment[] = [];
  let start = near, interval = f(2 / n);
  for (;;) {
    out.push({ start, interval, steps: n });
    start = f(start + f(n * interval));
    interval = f(interval * 4);
    if (!(start < far) || out.length === MAX_SEGMENTS) return out;
  }
}
