// Fly / look-around navigation for forward-facing (NDC) captures. Their field is only defined
// where the cameras looked (NDC warps the frustum of the capture into a cube), so the eye is
// kept inside the box of the capture's camera positions, grown a little, and the view direction
// inside the cone the cameras looked along, grown a little.

export type Vec3 = [number, number, number];

/** Where a forward-facing capture's views may go: eye within [lo, hi], view within `cone`
 *  radians of `axis`; `up` is the capture's mean up vector, `size` the box's diagonal. */
export interface Region { lo: Vec3; hi: Vec3; axis: Vec3; cone: number; up: Vec3; size: number }

/** A fly camera: the eye and the unit direction it looks along. */
export interface Fly { eye: Vec3; fwd: Vec3 }

/** How much the box grows on each side, as a fraction of its diagonal. */
export const BOX_GROW = 0.1;
/** How much the cone's half-angle grows (radians, ≈ 5.7°). */
export const CONE_GROW = 0.1;

const dot = (a: Vec3, b: Vec3) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a: Vec3, b: Vec3): Vec3 => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const scale = (a: Vec3, k: number): Vec3 => [a[0] * k, a[1] * k, a[2] * k];
const add = (a: Vec3, b: Vec3): Vec3 => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const unit = (a: Vec3): Vec3 => scale(a, 1 / (Math.hypot(...a) || 1));
const col = (m: number[][], c: number): Vec3 => [m[0][c], m[1][c], m[2][c]];

/** Angle between two unit vectors (acos clamped against rounding). */
export function angle(a: Vec3, b: Vec3): number {
  return Math.acos(Math.min(Math.max(dot(a, b), -1), 1));
}

/** The eye and view direction (−z column) of a c2w pose. */
export function flyFromPose(m: number[][]): Fly {
  return { eye: col(m, 3), fwd: unit(scale(col(m, 2), -1)) };
}

/** A capture's up vector: the mean of its poses' (unit) +y axes. */
export function captureUp(poses: number[][][]): Vec3 {
  return unit(poses.reduce((t: Vec3, m) => add(t, unit(col(m, 1))), [0, 0, 0]));
}

/** The region of a capture's poses (c2w, row-major): the box of their eyes grown by
 *  BOX_GROW × its diagonal each side, and the cone around their mean view direction out to the
 *  widest of them plus CONE_GROW. */
export function captureRegion(poses: number[][][]): Region {
  if (!poses.length) throw new Error("no poses to bound the navigation by");
  const lo: Vec3 = [Infinity, Infinity, Infinity], hi: Vec3 = [-Infinity, -Infinity, -Infinity];
  let sumF: Vec3 = [0, 0, 0];
  const fwds = poses.map((m) => flyFromPose(m));
  for (const { eye, fwd } of fwds) {
    for (let a = 0; a < 3; a++) { lo[a] = Math.min(lo[a], eye[a]); hi[a] = Math.max(hi[a], eye[a]); }
    sumF = add(sumF, fwd);
  }
  const size = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]), g = BOX_GROW * size;
  const axis = unit(sumF);
  const widest = Math.max(...fwds.map(({ fwd }) => angle(fwd, axis)));
  return { lo: lo.map((v) => v - g) as Vec3, hi: hi.map((v) => v + g) as Vec3, axis, cone: Math.min(widest + CONE_GROW, Math.PI / 2), up: captureUp(poses), size };
}

/** `f` brought inside the region: the eye clamped to the box, the direction turned (in the
 *  plane of it and the axis) onto the cone's edge when it points outside. */
export function clampFly(f: Fly, r: Region): Fly {
  const eye = f.eye.map((v, a) => Math.min(Math.max(v, r.lo[a]), r.hi[a])) as Vec3;
  let fwd = unit(f.fwd);
  if (angle(fwd, r.axis) > r.cone) {
    const side = add(fwd, scale(r.axis, -dot(fwd, r.axis)));
    // Pointing straight back along −axis leaves no plane: any side will do.
    const s = Math.hypot(...side) > 1e-9 ? unit(side) : unit(cross(r.axis, Math.abs(r.axis[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0]));
    fwd = add(scale(r.axis, Math.cos(r.cone)), scale(s, Math.sin(r.cone)));
  }
  return { eye, fwd };
}

/** The c2w (row-major 4×4, the camera looks along −z) of a fly camera held level to `up`. */
export function flyPose(f: Fly, up: Vec3): number[][] {
  const z = scale(unit(f.fwd), -1);
  let x = cross(f.fwd, up);
  // Looking along up: keep any right-hand side.
  if (Math.hypot(...x) < 1e-9) x = cross(f.fwd, Math.abs(f.fwd[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0]);
  x = unit(x);
  const y = cross(z, x);
  return [0, 1, 2].map((a) => [x[a], y[a], z[a], f.eye[a]]).concat([[0, 0, 0, 1]]);
}

/** Turn the view `yaw` radians about `up` (positive: to the left) and `pitch` about the
 *  camera's right (positive: upwards), then bring it back inside the region. */
export function look(f: Fly, r: Region, yaw: number, pitch: number): Fly {
  const rot = (v: Vec3, k: Vec3, t: number): Vec3 => // Rodrigues, k a unit axis
    add(add(scale(v, Math.cos(t)), scale(cross(k, v), Math.sin(t))), scale(k, dot(k, v) * (1 - Math.cos(t))));
  let fwd = rot(f.fwd, r.up, yaw);
  const right = unit(cross(fwd, r.up));
  fwd = rot(fwd, right, pitch);
  return clampFly({ eye: f.eye, fwd }, r);
}

/** Move the eye by `right`, `upward` and `forward` (world units, in the camera's frame),
 *  then bring it back inside the region. */
export function moveBy(f: Fly, r: Region, right: number, upward: number, forward: number): Fly {
  const m = flyPose(f, r.up);
  const d = [0, 1, 2].map((a) => right * m[a][0] + upward * m[a][1] - forward * m[a][2]) as Vec3;
  return clampFly({ eye: add(f.eye, d), fwd: f.fwd }, r);
}

/** Whether a c2w pose is inside the region (to `tol`): what the browser test asserts. */
export function inside(m: number[][], r: Region, tol = 1e-9): boolean {
  const { eye, fwd } = flyFromPose(m);
  return eye.every((v, a) => v >= r.lo[a] - tol && v <= r.hi[a] + tol) && angle(fwd, r.axis) <= r.cone + tol;
}
