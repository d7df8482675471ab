// Rays of a scene bundle's pinhole camera, ported from tests/python/render_rays.py
// (pinhole, undistort, camera_rays, ndc_rays). Float32 steps use Math.fround so the arithmetic
// matches numpy's float32 (and nerf-render's f32) where it matters.

const f = Math.fround;

export interface Distortion { k1: number; k2: number; p1: number; p2: number }

export interface Pinhole {
  width: number; height: number;
  fx: number; fy: number; cx: number; cy: number;
  pixelCenter: "integer" | "half_pixel";
  distortion: Distortion | null;
}

export interface Ndc { width: number; height: number; fx: number; fy: number; near: number }

/** scene.json's camera; old bundles have `focal` alone (principal point at the centre, integer centres). */
export function pinhole(cam: any): Pinhole {
  const fx = cam.fx ?? cam.focal ?? NaN;
  return {
    width: cam.width, height: cam.height, fx, fy: cam.fy ?? fx,
    cx: cam.cx ?? 0.5 * cam.width, cy: cam.cy ?? 0.5 * cam.height,
    pixelCenter: cam.pixel_center ?? "integer", distortion: cam.distortion ?? null,
  };
}

/** nerf-render's --width/--height: height keeps the aspect (rounded) unless given. */
export function outputSize(cam: Pinhole, width?: number, height?: number): [number, number] {
  if (!width) return [cam.width, cam.height];
  return [width, height || Math.floor((width * cam.height + Math.floor(cam.width / 2)) / cam.width)];
}

/** PinholeCamera::resized: focal lengths and principal point scale with each side (in f32). */
export function resized(cam: Pinhole, width: number, height: number): Pinhole {
  const sx = f(f(width) / f(cam.width)), sy = f(f(height) / f(cam.height));
  return { ...cam, width, height, fx: f(f(cam.fx) * sx), fy: f(f(cam.fy) * sy), cx: f(f(cam.cx) * sx), cy: f(f(cam.cy) * sy) };
}

/** OpenCV radial-tangential distortion undone by Newton's method in float64 (OpenCvDistortion::undistort). */
export function undistort(xd: number, yd: number, k: Distortion): [number, number] {
  const k1 = f(k.k1), k2 = f(k.k2), p1 = f(k.p1), p2 = f(k.p2);
  let x = xd, y = yd;
  for (let it = 0; it < 20; it++) {
    const r2 = x * x + y * y;
    const radial = 1 + r2 * (k1 + k2 * r2);
    const dr = k1 + 2 * k2 * r2;
    const drx = dr * 2 * x, dry = dr * 2 * y;
    const fx = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd;
    const fy = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd;
    const a = radial + x * drx + 2 * p1 * y + 6 * p2 * x;
    const b = x * dry + 2 * p1 * x + 2 * p2 * y;
    const c = y * drx + 2 * p1 * x + 2 * p2 * y;
    const d = radial + y * dry + 6 * p1 * y + 2 * p2 * x;
    const det = a * d - b * c;
    if (Math.abs(det) < 1e-12) break;
    const dx = (d * fx - b * fy) / det, dy = (a * fy - c * fx) / det;
    x -= dx; y -= dy;
    if (Math.max(Math.abs(dx), Math.abs(dy)) < 1e-12) break;
  }
  return [x, y];
}

/** Ray origins and (unnormalised) directions for pixels (i, j) = (column, row), all pixels of
 *  the camera in row-major order when `pixels` is omitted. c2w: row-major 4×4. */
export function cameraRays(cam: Pinhole, c2w: number[][], pixels?: Int32Array): { o: Float32Array; d: Float32Array; n: number } {
  const n = pixels ? pixels.length / 2 : cam.width * cam.height;
  const o = new Float32Array(3 * n), d = new Float32Array(3 * n);
  const off = cam.pixelCenter === "half_pixel" ? 0.5 : 0;
  const m = c2w.map((row) => row.map((v) => f(v)));
  const [m00, m01, m02, ox] = m[0], [m10, m11, m12, oy] = m[1], [m20, m21, m22, oz] = m[2];
  const { width, cx: px, cy: py, fx, fy, distortion } = cam;
  for (let r = 0, i = 0, j = 0; r < n; r++) {
    if (pixels) { i = pixels[2 * r]; j = pixels[2 * r + 1]; }
    else if (r > 0 && ++i === width) { i = 0; j++; }
    let x = (i + off - px) / fx, y = (j + off - py) / fy;
    if (distortion) [x, y] = undistort(x, y, distortion);
    const cx = f(x), cy = f(-y);
    // dirs @ c2w[:3,:3].T, z = -1, summed left to right in f32.
    d[3 * r] = f(f(f(cx * m00) + f(cy * m01)) + f(-m02));
    d[3 * r + 1] = f(f(f(cx * m10) + f(cy * m11)) + f(-m12));
    d[3 * r + 2] = f(f(f(cx * m20) + f(cy * m21)) + f(-m22));
    o[3 * r] = ox; o[3 * r + 1] = oy; o[3 * r + 2] = oz;
  }
  return { o, d, n };
}

/** nerf-pytorch's ndc_rays, term by term, with separate focal lengths; returns new arrays. */
export function ndcRays(ndc: Ndc, o: Float32Array, d: Float32Array): { o: Float32Array; d: Float32Array } {
  const W = f(ndc.width), H = f(ndc.height), near = f(ndc.near);
  const ax = f(f(-2 * f(ndc.fx)) / W), ay = f(f(-2 * f(ndc.fy)) / H);
  const n = o.length / 3, o2 = new Float32Array(3 * n), d2 = new Float32Array(3 * n);
  for (let r = 0; r < n; r++) {
    const dx = d[3 * r], dy = d[3 * r + 1], dz = d[3 * r + 2];
    const t = f(f(-f(near + o[3 * r + 2])) / dz);
    const ox = f(o[3 * r] + f(t * dx)), oy = f(o[3 * r + 1] + f(t * dy)), oz = f(o[3 * r + 2] + f(t * dz));
    o2[3 * r] = f(f(ax * ox) / oz);
    o2[3 * r + 1] = f(f(ay * oy) / oz);
    o2[3 * r + 2] = f(1 + f(f(2 * near) / oz));
    d2[3 * r] = f(ax * f(f(dx / dz) - f(ox / oz)));
    d2[3 * r + 1] = f(ay * f(f(dy / dz) - f(oy / oz)));
    d2[3 * r + 2] = f(f(-2 * near) / oz);
  }
  return { o: o2, d: d2 };
}

/** |v| of a float32 3-vector, as numpy's float32 norm. */
export function norm3(x: number, y: number, z: number): number {
  return f(Math.sqrt(f(f(f(x * x) + f(y * y)) + f(z * z))));
}
