// src/contraction.ts's contractionFactor in f32, for the marcher (march.ts) and the hash grid
// (hashgrid.ts): the same operations in the same order, so a contracted point is bit for bit
// nerf-render's.

/** The factor the L∞ contraction scales a point by: n = max(|x|, |y|, |z|), m = (n > 1 ? n : 1),
 *  r = 1/m, (2 − r)·r. Exactly 1 inside the unit cube. (A NaN coordinate gives a NaN n, so m = 1
 *  and a NaN point either way, as in Rust.) */
@inline export function contractionFactor(x: f32, y: f32, z: f32): f32 {
  const n = max(max(abs(x), abs(y)), abs(z));
  const r: f32 = <f32>1 / (n > 1 ? n : <f32>1);
  return (<f32>2 - r) * r;
}
