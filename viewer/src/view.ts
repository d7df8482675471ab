// Small pure helpers of the page: an orbit camera (about the capture's up vector) and the
// conversion of frames to 8-bit pixels (as core/src/io/image.rs: clamp, ×255, round).

/** theta: azimuth about `up` (from `poleFrame(up)`'s first axis), phi: angle from `up`. */
export interface Orbit { target: number[]; radius: number; theta: number; phi: number; up: number[] }

/** Two unit axes perpendicular to unit `up` and each other, (e1, e2, up) right-handed; for
 *  z up they are x and y, so theta and phi are the usual spherical angles. */
export function poleFrame(up: number[]): [number[], number[]] {
  const a = Math.abs(up[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0];
  const k = a[0] * up[0] + a[1] * up[1] + a[2] * up[2];
  let e1 = a.map((v, i) => v - k * up[i]);
  const l = Math.hypot(...e1);
  e1 = e1.map((v) => v / l);
  return [e1, [up[1] * e1[2] - up[2] * e1[1], up[2] * e1[0] - up[0] * e1[2], up[0] * e1[1] - up[1] * e1[0]]];
}

/** 8-bit value of a linear [0, 1] colour: round(clamp(v, 0, 1)·255) (NaN → 0). */
export function toU8(v: number): number {
  return Math.round(Math.min(Math.max(v || 0, 0), 1) * 255);
}

/** RGBA bytes of a frame: rgb, or depth (near white, far black; background black). */
export function toBytes(m: { width: number; height: number; rgb: Float32Array; depth: Float32Array; acc: Float32Array },
  depthView: boolean, near: number, far: number): Uint8ClampedArray<ArrayBuffer> {
  const n = m.width * m.height, out = new Uint8ClampedArray(4 * n);
  for (let p = 0; p < n; p++) {
    if (depthView) {
      const a = m.acc[p], z = a > 1e-3 ? m.depth[p] / a : far;
      out.fill(toU8(a * (1 - (z - near) / (far - near))), 4 * p, 4 * p + 3);
    } else for (let c = 0; c < 3; c++) out[4 * p + c] = toU8(m.rgb[3 * p + c]);
    out[4 * p + 3] = 255;
  }
  return out;
}

/** The orbit through a c2w pose about unit `up`: around the point of its view axis nearest the origin. */
export function orbitFromPose(m: number[][], near: number, up: number[] = [0, 0, 1]): Orbit {
  const eye = [m[0][3], m[1][3], m[2][3]], fwd = [-m[0][2], -m[1][2], -m[2][2]];
  const fl = Math.hypot(...fwd) || 1;
  const f = fwd.map((v) => v / fl);
  const along = Math.max(-(eye[0] * f[0] + eye[1] * f[1] + eye[2] * f[2]), near);
  const target = eye.map((v, a) => v + along * f[a]);
  const rel = eye.map((v, a) => v - target[a]);
  const radius = Math.hypot(...rel);
  const [e1, e2] = poleFrame(up), dot = (a: number[]) => a[0] * rel[0] + a[1] * rel[1] + a[2] * rel[2];
  return { target, radius, theta: Math.atan2(dot(e2), dot(e1)), phi: Math.acos(Math.min(Math.max(dot(up) / radius, -1), 1)), up };
}

/** The c2w (row-major 4×4, OpenGL: the camera looks along −z) of an orbit. */
export function orbitPose(o: Orbit): number[][] {
  const [e1, e2] = poleFrame(o.up), u = o.up;
  const c1 = Math.sin(o.phi) * Math.cos(o.theta), c2 = Math.sin(o.phi) * Math.sin(o.theta), c3 = Math.cos(o.phi);
  const z = [0, 1, 2].map((a) => c1 * e1[a] + c2 * e2[a] + c3 * u[a]);
  const eye = o.target.map((v, a) => v + o.radius * z[a]);
  let x = [u[1] * z[2] - u[2] * z[1], u[2] * z[0] - u[0] * z[2], u[0] * z[1] - u[1] * z[0]]; // up × z
  const xl = Math.hypot(...x) || 1;
  x = x.map((v) => v / xl);
  const y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]];
  return [0, 1, 2].map((a) => [x[a], y[a], z[a], eye[a]]).concat([[0, 0, 0, 1]]);
}
