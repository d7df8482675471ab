// Camera paths made in the page: keyframes, the spline that turns them into one camera per
// frame, and nerfstudio's camera_path.json, the file `nerf-render --camera-path` and
// `nerf render --camera-path` read (core/src/frames/camera_path.rs). Pure functions; the panel
// that drives them is pathpanel.ts.
//
// The interpolation (docs/viewer.md, "Camera paths"): keyframes evenly spaced in time; the
// camera centre on a uniform Catmull-Rom spline, the rotation on a SQUAD quaternion spline (its
// tangents the quaternion analogue of Catmull-Rom's), the vertical field of view linear between
// keyframes. An open path's ends get mirrored neighbours (p₋₁ = 2p₀ − p₁, and the same for
// rotations), so two keyframes give a straight line and a slerp; a loop wraps around. Frame k
// of N sits at u = k / (N − 1) of an open path (the first and last frames are the end
// keyframes) and u = k / N of a loop (the frame after the last is the first). The renderers only
// read the cameras written out (camera_path[]); keyframes are written too, in nerfstudio's form,
// so a saved path loads back into the editor.
//
// The page works in the field's frame (the bundle's poses); the file holds poses in the original
// capture's coordinates, which the renderers map through the bundle's recorded placement
// (scene.json `placement.transform`, x' = scale·(R·x + t)). Saving applies the inverse, loading
// the placement itself. Both maps are similarities, under which Catmull-Rom (an affine
// combination of points) and SQUAD (relative rotations) give the same cameras in either frame.

/** Camera-to-world, row-major 4×4, OpenGL axes (the camera looks along −z, +y up). */
export type Mat4 = number[][];
/** A unit quaternion (w, x, y, z). */
export type Quat = [number, number, number, number];

/** A keyframe, or one camera of the path: a pose in the field's frame and a vertical fov in degrees. */
export interface PathCamera { c2w: Mat4; fov: number }

/** A path as the editor holds it. */
export interface CameraPath {
  keyframes: PathCamera[];
  /** Length of the video (s) and frames per second: round(seconds · fps) frames. */
  seconds: number; fps: number;
  /** Image size in pixels. */
  width: number; height: number;
  /** The path returns to its first keyframe (nerfstudio's `is_cycle`). */
  loop: boolean;
}

/** x' = scale · (rotation · x + translation): scene.json's `placement.transform`. */
export interface Placement { scale: number; rotation: number[][]; translation: number[] }

/** Limits of the renderers (core/src/io/limits.rs): frames per path, pixels per side and per frame. */
export const MAX_FRAMES = 10_000;
export const MAX_SIDE = 16_384;
export const MAX_PIXELS = 4096 * 4096;

// --- quaternions -------------------------------------------------------------------------------

function qmul(a: Quat, b: Quat): Quat {
  return [a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
    a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
    a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
    a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]];
}
const qconj = (q: Quat): Quat => [q[0], -q[1], -q[2], -q[3]];

/** a⁻¹·b, its sign chosen so that it turns the short way (w ≥ 0). */
function relative(a: Quat, b: Quat): Quat {
  const r = qmul(qconj(a), b);
  return r[0] < 0 ? [-r[0], -r[1], -r[2], -r[3]] : r;
}

/** log of a unit quaternion: half the rotation angle times the axis. */
function qlog(q: Quat): number[] {
  const v = Math.hypot(q[1], q[2], q[3]);
  const k = v < 1e-300 ? 1 : Math.atan2(v, q[0]) / v;
  return [k * q[1], k * q[2], k * q[3]];
}

function qexp(v: number[]): Quat {
  const a = Math.hypot(v[0], v[1], v[2]);
  const k = a < 1e-300 ? 1 : Math.sin(a) / a;
  return [Math.cos(a), k * v[0], k * v[1], k * v[2]];
}

/** The rotation t of the way from a to b, the short way round (t = 0: a, t = 1: b). */
export function slerp(a: Quat, b: Quat, t: number): Quat {
  return qmul(a, qexp(qlog(relative(a, b)).map((x) => t * x)));
}

/** The unit quaternion of a rotation matrix (the 3×3 top-left of `m`), Shepperd's method. */
export function quatOf(m: number[][]): Quat {
  const [r00, r11, r22] = [m[0][0], m[1][1], m[2][2]], tr = r00 + r11 + r22;
  let q: Quat;
  if (tr > 0) {
    const s = 2 * Math.sqrt(tr + 1);
    q = [s / 4, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s];
  } else if (r00 > r11 && r00 > r22) {
    const s = 2 * Math.sqrt(1 + r00 - r11 - r22);
    q = [(m[2][1] - m[1][2]) / s, s / 4, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s];
  } else if (r11 > r22) {
    const s = 2 * Math.sqrt(1 + r11 - r00 - r22);
    q = [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, s / 4, (m[1][2] + m[2][1]) / s];
  } else {
    const s = 2 * Math.sqrt(1 + r22 - r00 - r11);
    q = [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, s / 4];
  }
  const l = Math.hypot(...q);
  return q.map((v) => v / l) as Quat;
}

/** The rotation matrix of a unit quaternion, rows. */
export function rotationOf(q: Quat): number[][] {
  const [w, x, y, z] = q;
  return [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]];
}

// --- the spline --------------------------------------------------------------------------------

/** Uniform Catmull-Rom between p1 (s = 0) and p2 (s = 1); at s = ½: (−p0 + 9p1 + 9p2 − p3) / 16. */
export function catmullRom(p0: number[], p1: number[], p2: number[], p3: number[], s: number): number[] {
  const s2 = s * s, s3 = s2 * s;
  return p1.map((_, a) => 0.5 * (2 * p1[a] + (p2[a] - p0[a]) * s + (2 * p0[a] - 5 * p1[a] + 4 * p2[a] - p3[a]) * s2
    + (3 * p1[a] - p0[a] - 3 * p2[a] + p3[a]) * s3));
}

/** SQUAD's inner control point of q between its neighbours (an end without one: q itself, as
 *  a mirrored neighbour cancels the other's pull). */
function squadInner(prev: Quat | null, q: Quat, next: Quat | null): Quat {
  if (!prev || !next) return q;
  const a = qlog(relative(q, next)), b = qlog(relative(q, prev));
  return qmul(q, qexp(a.map((v, i) => -(v + b[i]) / 4)));
}

/** SQUAD from q1 (t = 0) to q2 (t = 1) with q0 before and q3 after (null at an open end). */
export function squad(q0: Quat | null, q1: Quat, q2: Quat, q3: Quat | null, t: number): Quat {
  const s1 = squadInner(q0, q1, q2), s2 = squadInner(q1, q2, q3);
  return slerp(slerp(q1, q2, t), slerp(s1, s2, t), 2 * t * (1 - t));
}

const centre = (m: Mat4) => [m[0][3], m[1][3], m[2][3]];

/** The 4×4 of a rotation (rows) and a centre. */
export function poseOf(r: number[][], o: number[]): Mat4 {
  return [0, 1, 2].map((a) => [r[a][0], r[a][1], r[a][2], o[a]]).concat([[0, 0, 0, 1]]);
}

/** The camera at u ∈ [0, 1] along the keyframes (an open path or a loop; see the top of the file);
 *  exactly keyframe i at u = i / segments. */
export function cameraAt(keys: PathCamera[], loop: boolean, u: number): PathCamera {
  const n = keys.length;
  if (n === 0) throw new Error("the path has no keyframes");
  if (n === 1) return { c2w: keys[0].c2w.map((r) => [...r]), fov: keys[0].fov };
  const segments = loop ? n : n - 1;
  const x = Math.min(Math.max(u, 0), 1) * segments;
  const at = (j: number) => keys[((j % n) + n) % n];
  // At its time a keyframe's own pose, not its quaternion's matrix: a keyframe on a test pose
  // (stored in float32, orthonormal to ~1e-7 only) renders that test view bit for bit.
  if (Number.isInteger(x)) return { c2w: at(x).c2w.map((r) => [...r]), fov: at(x).fov };
  const i = Math.floor(x), s = x - i;
  // Neighbours: wrapped on a loop, mirrored past an open path's ends.
  const point = (j: number): number[] => {
    if (loop || (j >= 0 && j < n)) return centre(at(j).c2w);
    const [e, f] = j < 0 ? [keys[0], keys[1]] : [keys[n - 1], keys[n - 2]];
    return centre(e.c2w).map((v, a) => 2 * v - centre(f.c2w)[a]);
  };
  const rot = (j: number): Quat | null => (loop || (j >= 0 && j < n) ? quatOf(at(j).c2w) : null);
  const o = catmullRom(point(i - 1), point(i), point(i + 1), point(i + 2), s);
  const q = squad(rot(i - 1), rot(i)!, rot(i + 1)!, rot(i + 2), s);
  return { c2w: poseOf(rotationOf(q), o), fov: at(i).fov + s * (at(i + 1).fov - at(i).fov) };
}

/** Frames of a path: round(seconds · fps), at least one. */
export function frameCount(p: { seconds: number; fps: number }): number {
  return Math.max(1, Math.round(p.seconds * p.fps));
}

/** One camera per frame: camera_path[] of the file, and what the page plays. */
export function pathCameras(p: CameraPath): PathCamera[] {
  const n = frameCount(p);
  return Array.from({ length: n }, (_, k) => cameraAt(p.keyframes, p.loop, p.loop ? k / n : n > 1 ? k / (n - 1) : 0));
}

/** nerfstudio's camera for a path frame (perspective_camera in camera_path.rs): focal
 *  (height / 2) / tan(fov / 2) on both axes, in f32 as the renderers, principal point at the centre. */
export function pathIntrinsics(width: number, height: number, fov: number): { fx: number; fy: number; cx: number; cy: number } {
  const focal = Math.fround((0.5 * height) / Math.tan(0.5 * (fov * (Math.PI / 180))));
  return { fx: focal, fy: focal, cx: Math.fround(0.5 * width), cy: Math.fround(0.5 * height) };
}

/** The vertical fov (degrees) of a pinhole of `height` pixels and focal `fy`. */
export function verticalFov(height: number, fy: number): number {
  return (2 * Math.atan(height / (2 * fy)) * 180) / Math.PI;
}

/** What is wrong with the path's settings, or null: the limits the renderers apply. */
export function settingsProblem(p: Omit<CameraPath, "keyframes" | "loop">): string | null {
  for (const [key, v] of [["width", p.width], ["height", p.height]] as const)
    if (!Number.isInteger(v) || v < 1 || v > MAX_SIDE) return `${key} ${v} is not a whole number of pixels from 1 to ${MAX_SIDE}`;
  if (p.width * p.height > MAX_PIXELS) return `${p.width}×${p.height} is more than ${MAX_PIXELS} pixels`;
  if (!(p.seconds > 0 && Number.isFinite(p.seconds))) return `duration ${p.seconds} is not a positive number of seconds`;
  if (!(p.fps > 0 && Number.isFinite(p.fps))) return `frame rate ${p.fps} is not a positive number`;
  if (frameCount(p) > MAX_FRAMES) return `${frameCount(p)} frames is more than the limit of ${MAX_FRAMES}`;
  return null;
}

// --- placement ---------------------------------------------------------------------------------

/** The bundle's recorded placement (scene.json `placement.transform`), or null (Blender scenes). */
export function placementOf(scene: any): Placement | null {
  const t = scene?.placement?.transform;
  if (!t) return null;
  const rotation = t.rotation ?? [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
  const numbers = [t.scale, ...rotation.flat(), ...t.translation];
  if (!(t.scale > 0) || numbers.length !== 13 || !numbers.every(Number.isFinite))
    throw new Error(`scene.json: placement.transform is not a scale, a 3×3 rotation and a translation`);
  return { scale: t.scale, rotation, translation: t.translation };
}

const matVec = (r: number[][], v: number[]) => r.map((row) => row[0] * v[0] + row[1] * v[1] + row[2] * v[2]);
const transpose = (r: number[][]) => [0, 1, 2].map((i) => [0, 1, 2].map((j) => r[j][i]));
const matMul = (a: number[][], b: number[][]) => a.map((row) => [0, 1, 2].map((j) => row[0] * b[0][j] + row[1] * b[1][j] + row[2] * b[2][j]));
const rotationPart = (m: Mat4) => [0, 1, 2].map((a) => [m[a][0], m[a][1], m[a][2]]);

/** A capture's pose in the field's frame: rotation R·R_c, centre scale·(R·o + t) (SceneTransform::apply_pose). */
export function toField(c2w: Mat4, p: Placement | null): Mat4 {
  if (!p) return c2w.map((r) => [...r]);
  const o = matVec(p.rotation, centre(c2w)).map((v, a) => p.scale * (v + p.translation[a]));
  return poseOf(matMul(p.rotation, rotationPart(c2w)), o);
}

/** A field pose back in the capture's coordinates: rotation Rᵀ·R_f, centre Rᵀ·(o / scale − t). */
export function toCapture(c2w: Mat4, p: Placement | null): Mat4 {
  if (!p) return c2w.map((r) => [...r]);
  const rt = transpose(p.rotation);
  const o = matVec(rt, centre(c2w).map((v, a) => v / p.scale - p.translation[a]));
  return poseOf(matMul(rt, rotationPart(c2w)), o);
}

// --- camera_path.json --------------------------------------------------------------------------

/** nerfstudio's camera_path.json of a path (poses in the capture's coordinates): the cameras
 *  the renderers read, and the keyframes, fps and loop flag its viewer (and this one) reads back. */
export function pathJson(p: CameraPath, placement: Placement | null): Record<string, unknown> {
  const aspect = p.width / p.height, flat = (m: Mat4) => toCapture(m, placement).flat();
  return {
    camera_type: "perspective",
    render_width: p.width,
    render_height: p.height,
    seconds: p.seconds,
    fps: p.fps,
    is_cycle: p.loop,
    keyframes: p.keyframes.map((k) => ({ matrix: flat(k.c2w), fov: k.fov, aspect, override_transition_enabled: false, override_transition_sec: null })),
    camera_path: pathCameras(p).map((c) => ({ camera_to_world: flat(c.c2w), fov: c.fov, aspect })),
  };
}

/** The text of a path's file: camera_path.json as the save button writes it. */
export function pathText(p: CameraPath, placement: Placement | null): string {
  return JSON.stringify(pathJson(p, placement), null, 1) + "\n";
}

/** An error naming the file and the key, as the Rust reader's (`camera_path.json: fps: …`). */
class Keys {
  constructor(readonly name: string) {}
  error(key: string, problem: string): Error { return new Error(`${this.name}: ${key}: ${problem}`); }
  number(v: unknown, key: string): number {
    if (typeof v !== "number" || !Number.isFinite(v)) throw this.error(key, v === undefined ? "missing" : `${JSON.stringify(v)} is not a number`);
    return v;
  }
  /** A camera-to-world: 16 numbers row by row (or a nested 4×4), last row 0 0 0 1, a rotation. */
  pose(v: unknown, key: string): Mat4 {
    if (v === undefined) throw this.error(key, "missing");
    const flat = Array.isArray(v) && v.length > 0 && v.every(Array.isArray) ? (v as unknown[][]).flat() : v;
    if (!Array.isArray(flat)) throw this.error(key, `${JSON.stringify(v)} is not a list of 16 numbers`);
    if (flat.length !== 16) throw this.error(key, `${flat.length} numbers, expected 16 (the 4×4 matrix, row by row)`);
    const x = flat.map((e, i) => this.number(e, `${key}[${i}]`));
    const m = [0, 1, 2, 3].map((r) => x.slice(4 * r, 4 * r + 4));
    if (m[3].some((e, i) => Math.abs(e - [0, 0, 0, 1][i]) > 1e-6)) throw this.error(key, `the last row is [${m[3].join(", ")}], not [0, 0, 0, 1]`);
    const r = rotationPart(m), rtr = matMul(transpose(r), r);
    const off = Math.max(...rtr.flatMap((row, i) => row.map((e, j) => Math.abs(e - (i === j ? 1 : 0)))));
    if (off > 1e-3) throw this.error(key, `the rotation is not orthonormal (max |RᵀR − I| = ${off.toFixed(3)})`);
    const det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0]) + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    if (det < 0) throw this.error(key, "the rotation is a reflection (determinant −1)");
    return m;
  }
  fov(v: unknown, key: string): number {
    const fov = this.number(v, key);
    if (!(fov > 0 && fov < 180)) throw this.error(key, `${fov} is outside (0, 180) degrees`);
    return fov;
  }
}

/** A camera_path.json (`text`, from the file `name`) as an editable path in the field's frame:
 *  its keyframes when it has any, else its cameras as keyframes. Errors name the file and key. */
export function readPath(text: string, name: string, placement: Placement | null): CameraPath {
  const keys = new Keys(name);
  let top: any;
  try { top = JSON.parse(text); }
  catch (e) { throw new Error(`${name}: not JSON (${(e as Error).message})`); }
  if (typeof top !== "object" || top === null || Array.isArray(top)) throw new Error(`${name}: not a camera path: the top level is not a JSON object`);
  const type = top.camera_type;
  if (type !== undefined && !(typeof type === "string" && type.toLowerCase() === "perspective"))
    throw keys.error("camera_type", `${JSON.stringify(type)}: only perspective cameras are supported`);
  const pixels = (key: string) => {
    const v = keys.number(top[key], key);
    if (!Number.isInteger(v) || v < 1) throw keys.error(key, `${v} is not a positive whole number of pixels`);
    return v;
  };
  const width = pixels("render_width"), height = pixels("render_height");
  const seconds = keys.number(top.seconds, "seconds");
  if (!(seconds > 0)) throw keys.error("seconds", `${seconds} is not a positive duration`);
  const loop = top.is_cycle ?? false;
  if (typeof loop !== "boolean") throw keys.error("is_cycle", `${JSON.stringify(loop)} is not true or false`);
  const list = (key: string): unknown[] | null => {
    const v = top[key];
    if (v === undefined || v === null) return null;
    if (!Array.isArray(v)) throw keys.error(key, "not a list");
    if (v.length > MAX_FRAMES) throw keys.error(key, `${v.length} entries is more than the limit of ${MAX_FRAMES}`);
    return v;
  };
  const keyframes = list("keyframes"), cameras = list("camera_path");
  const [from, entries] = keyframes?.length ? ["keyframes", keyframes] : ["camera_path", cameras];
  if (!entries) throw keys.error("camera_path", "missing (and no keyframes)");
  if (!entries.length) throw keys.error(from, "no cameras");
  const matrixKey = from === "keyframes" ? "matrix" : "camera_to_world";
  const read = entries.map((e: any, k) => {
    const at = `${from}[${k}]`;
    if (typeof e !== "object" || e === null || Array.isArray(e)) throw keys.error(at, `not an object with ${matrixKey} and fov`);
    return { c2w: toField(keys.pose(e[matrixKey], `${at}.${matrixKey}`), placement), fov: keys.fov(e.fov ?? top.default_fov, `${at}.fov`) };
  });
  // nerfstudio always writes fps; a file without it plays its cameras one per frame.
  const fps = top.fps === undefined ? (cameras?.length || read.length) / seconds : keys.number(top.fps, "fps");
  if (!(fps > 0)) throw keys.error("fps", `${fps} is not a positive frame rate`);
  const path: CameraPath = { keyframes: read, seconds, fps, width, height, loop };
  const problem = settingsProblem(path);
  if (problem) throw new Error(`${name}: ${problem}`);
  return path;
}
