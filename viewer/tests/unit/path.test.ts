// Camera paths (src/path.ts): the spline on cases worked out by hand, the placement against the
// Rust mapping's numbers, and camera_path.json written and read back.
import { readFileSync } from "node:fs";
import { resolve } from "node:path";
import { describe, expect, it } from "vitest";
import {
  type CameraPath, type Mat4, type PathCamera, type Placement, cameraAt, catmullRom, frameCount, pathCameras, pathIntrinsics,
  pathJson, pathText, poseOf, quatOf, readPath, rotationOf, settingsProblem, slerp, toCapture, toField,
} from "../../src/path";

const near = (got: number[], want: number[], tol = 1e-12) => {
  expect(got.length).toBe(want.length);
  got.forEach((v, i) => expect(Math.abs(v - want[i]), `entry ${i}: ${got} vs ${want}`).toBeLessThanOrEqual(tol));
};
const deg = Math.PI / 180;
/** Rotation by `a` degrees about z, rows. */
const rz = (a: number) => [[Math.cos(a * deg), -Math.sin(a * deg), 0], [Math.sin(a * deg), Math.cos(a * deg), 0], [0, 0, 1]];
const rx = (a: number) => [[1, 0, 0], [0, Math.cos(a * deg), -Math.sin(a * deg)], [0, Math.sin(a * deg), Math.cos(a * deg)]];
const mul = (a: number[][], b: number[][]) => a.map((r) => [0, 1, 2].map((j) => r[0] * b[0][j] + r[1] * b[1][j] + r[2] * b[2][j]));
const rot = (m: Mat4) => [0, 1, 2].map((a) => m[a].slice(0, 3));
const key = (r: number[][], o: number[], fov: number): PathCamera => ({ c2w: poseOf(r, o), fov });

/** Three keyframes: centres (0,0,0), (1,0,0), (1,1,0); turned 0°, 60°, 180° about z; fov 30°, 50°, 70°. */
const KEYS = [key(rz(0), [0, 0, 0], 30), key(rz(60), [1, 0, 0], 50), key(rz(180), [1, 1, 0], 70)];

describe("quaternions", () => {
  it("a quarter turn about z is (cos 45°, 0, 0, sin 45°), and back", () => {
    near(quatOf(poseOf(rz(90), [0, 0, 0])), [Math.SQRT1_2, 0, 0, Math.SQRT1_2]);
    // Half turns take the other branches of Shepperd's method (trace −1).
    for (const r of [rz(180), rx(180), mul(rz(90), mul(rx(180), rz(-90)))]) near(rotationOf(quatOf(r)).flat(), r.flat());
  });
  it("slerp goes the short way: halfway from 350° to 10° about z is 0°", () => {
    near(rotationOf(slerp(quatOf(rz(350)), quatOf(rz(10)), 0.5)).flat(), rz(0).flat());
  });
});

describe("the spline", () => {
  it("Catmull-Rom's midpoint is (−p0 + 9p1 + 9p2 − p3) / 16", () => {
    near(catmullRom([0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 2, 0], 0.5), [17 / 16, 7 / 16, 0]);
    near(catmullRom([0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 2, 0], 0), [1, 0, 0]);
    near(catmullRom([0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 2, 0], 1), [1, 1, 0]);
  });

  it("passes through each keyframe at its time (open path and loop)", () => {
    const keys = [...KEYS, key(mul(rz(-30), rx(40)), [0, 2, 1], 35)];
    for (const loop of [false, true]) {
      const segments = loop ? keys.length : keys.length - 1;
      keys.forEach((k, i) => {
        if (i > segments) return;
        const c = cameraAt(keys, loop, i / segments);
        expect(c).toEqual(k);
        // The spline itself goes through the keyframe: just before and after it.
        for (const du of [-1e-9, 1e-9]) {
          if (i / segments + du < 0 || i / segments + du > 1) continue;
          near(cameraAt(keys, loop, i / segments + du).c2w.flat(), k.c2w.flat(), 1e-7);
        }
      });
      // The loop comes back to the first keyframe at u = 1.
      if (loop) near(cameraAt(keys, loop, 1).c2w.flat(), keys[0].c2w.flat());
    }
  });

  it("midpoints worked by hand: mirrored ends, SQUAD about one axis, fov linear", () => {
    // Segment 0 (u = ¼): the mirrored neighbour p₋₁ = 2p₀ − p₁ = (−1,0,0), so the centre is
    // (1 + 9·(1,0,0) − (1,1,0)) / 16 = (9, −1, 0) / 16. About one axis SQUAD is linear in the
    // angle: inner points s₀ = 0° (mirrored end) and s₁ = 60° − (120° − 60°)/4 = 45°, so the
    // midpoint turns (0° + 60°)/4 + (0° + 45°)/4 = 26.25°. fov (30 + 50)/2.
    let c = cameraAt(KEYS, false, 0.25);
    near(c.c2w.map((r) => r[3]), [9 / 16, -1 / 16, 0, 1]);
    near(rot(c.c2w).flat(), rz(26.25).flat());
    expect(c.fov).toBeCloseTo(40, 12);
    // Segment 1 (u = ¾): p₃ = 2·(1,1,0) − (1,0,0) = (1,2,0): (17, 7, 0)/16; s₂ = 180°, so
    // (60° + 180°)/4 + (45° + 180°)/4 = 116.25°; fov 60.
    c = cameraAt(KEYS, false, 0.75);
    near(c.c2w.map((r) => r[3]), [17 / 16, 7 / 16, 0, 1]);
    near(rot(c.c2w).flat(), rz(116.25).flat());
    expect(c.fov).toBeCloseTo(60, 12);
  });

  it("two keyframes: a straight line and a slerp", () => {
    const c = cameraAt([key(rz(0), [0, 0, 0], 40), key(rz(90), [2, 0, 0], 40)], false, 0.5);
    near(c.c2w.map((r) => r[3]), [1, 0, 0, 1]);
    near(rot(c.c2w).flat(), rz(45).flat());
  });

  it("a loop wraps: the square's corners give midpoints (±0.625, 0.625) and (0.625, −0.625)", () => {
    const square = [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]].map((o, i) => key(rz(90 * i), o, 40));
    // Between corners 0 and 1: (−p₃ + 9p₀ + 9p₁ − p₂)/16 = (10, 10, 0)/16; the closing segment
    // 3 → 0: (−p₂ + 9p₃ + 9p₀ − p₁)/16 = (10, −10, 0)/16; the turn there is 315°, halfway 270° → 360°.
    near(cameraAt(square, true, 1 / 8).c2w.map((r) => r[3]), [0.625, 0.625, 0, 1]);
    const closing = cameraAt(square, true, 7 / 8);
    near(closing.c2w.map((r) => r[3]), [0.625, -0.625, 0, 1]);
    near(rot(closing.c2w).flat(), rz(315).flat());
  });

  it("rotations stay orthonormal along a winding path", () => {
    const keys = [0, 1, 2, 3, 4].map((i) => key(mul(rz(77 * i), mul(rx(50 * i - 90), rz(33 * i * i))), [Math.sin(i), i, Math.cos(2 * i)], 30 + 5 * i));
    for (const loop of [false, true]) {
      const cams = pathCameras({ keyframes: keys, seconds: 3, fps: 17, width: 8, height: 8, loop });
      expect(cams.length).toBe(51);
      for (const c of cams) {
        const r = rot(c.c2w), rtr = mul([0, 1, 2].map((i) => [0, 1, 2].map((j) => r[j][i])), r);
        near(rtr.flat(), [1, 0, 0, 0, 1, 0, 0, 0, 1]);
        const det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0]) + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        expect(det).toBeCloseTo(1, 12);
        near(c.c2w[3], [0, 0, 0, 1], 0);
      }
    }
  });

  it("frames: round(seconds · fps); an open path ends on its last keyframe, a loop one frame before its first", () => {
    expect(frameCount({ seconds: 1, fps: 4 })).toBe(4);
    expect(frameCount({ seconds: 2.5, fps: 24 })).toBe(60);
    expect(frameCount({ seconds: 0.01, fps: 24 })).toBe(1);
    const open = pathCameras({ keyframes: KEYS, seconds: 1, fps: 5, width: 8, height: 8, loop: false });
    near(open[0].c2w.flat(), KEYS[0].c2w.flat());
    near(open[4].c2w.flat(), KEYS[2].c2w.flat());
    near(open[2].c2w.flat(), KEYS[1].c2w.flat()); // u = ½: the middle keyframe
    const loop = pathCameras({ keyframes: KEYS, seconds: 1, fps: 6, width: 8, height: 8, loop: true });
    near(loop[0].c2w.flat(), KEYS[0].c2w.flat());
    near(loop[2].c2w.flat(), KEYS[1].c2w.flat());
    near(loop[4].c2w.flat(), KEYS[2].c2w.flat());
    expect(() => cameraAt([], false, 0)).toThrow(/no keyframes/);
  });

  it("nerfstudio's camera: 200×100 at 90° has focal 50 at (100, 50); at 60°, 86.6025", () => {
    expect(pathIntrinsics(200, 100, 90)).toEqual({ fx: 50, fy: 50, cx: 100, cy: 50 });
    expect(pathIntrinsics(200, 100, 60).fx).toBeCloseTo(86.60254, 4);
  });

  it("settings outside the renderers' limits are named", () => {
    const ok = { seconds: 2, fps: 24, width: 100, height: 80 };
    expect(settingsProblem(ok)).toBeNull();
    expect(settingsProblem({ ...ok, width: 12.5 })).toMatch(/width 12.5 is not a whole number/);
    expect(settingsProblem({ ...ok, height: 0 })).toMatch(/height 0/);
    expect(settingsProblem({ ...ok, width: 8192, height: 4096 })).toMatch(/more than 16777216 pixels/);
    expect(settingsProblem({ ...ok, seconds: 0 })).toMatch(/duration 0/);
    expect(settingsProblem({ ...ok, fps: NaN })).toMatch(/frame rate NaN/);
    expect(settingsProblem({ ...ok, seconds: 1000 })).toMatch(/24000 frames is more than the limit of 10000/);
  });
});

describe("placement", () => {
  it("toField is SceneTransform::apply_pose: scale 0.5 about (0, 0, −2) takes (0,0,4) to (0,0,1)", () => {
    // The case of camera_path.rs's own test.
    const p: Placement = { scale: 0.5, rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, -2] };
    near(toField(poseOf(rz(0), [0, 0, 4]), p).map((r) => r[3]), [0, 0, 1, 1]);
    near(toCapture(poseOf(rz(0), [0, 0, 1]), p).map((r) => r[3]), [0, 0, 4, 1]);
  });
  it("a rotated, scaled, shifted placement, by hand, and the page's pose back through the inverse", () => {
    // x' = 2·(Rz(90°)·x + (1, 0, 0)): the centre (1, 2, 3) → 2·((−2, 1, 3) + (1, 0, 0)) = (−2, 2, 6);
    // the rotation R·I = Rz(90°).
    const p: Placement = { scale: 2, rotation: [[0, -1, 0], [1, 0, 0], [0, 0, 1]], translation: [1, 0, 0] };
    const field = toField(poseOf(rz(0), [1, 2, 3]), p);
    near(field.flat(), [0, -1, 0, -2, 1, 0, 0, 2, 0, 0, 1, 6, 0, 0, 0, 1]);
    // A pose of the page (the field's frame) written for the renderers and mapped forward again.
    const page = poseOf(mul(rz(30), rx(-20)), [0.3, -1.2, 2.5]);
    near(toField(toCapture(page, p), p).flat(), page.flat());
    near(toCapture(page, null).flat(), page.flat());
  });
});

describe("camera_path.json", () => {
  const placement: Placement = { scale: 1.25, rotation: rz(90), translation: [0.2, -0.1, 0.1] };
  const path: CameraPath = { keyframes: KEYS, seconds: 1.5, fps: 4, width: 120, height: 90, loop: true };

  it("written and read back: the same keyframes, settings and cameras", () => {
    for (const pl of [null, placement]) {
      const text = pathText(path, pl);
      const json = JSON.parse(text);
      expect(json.camera_path.length).toBe(6);
      expect([json.render_width, json.render_height, json.seconds, json.fps, json.is_cycle, json.camera_type]).toEqual([120, 90, 1.5, 4, true, "perspective"]);
      expect(json.camera_path[0].aspect).toBeCloseTo(4 / 3, 12);
      const back = readPath(text, "camera_path.json", pl);
      expect([back.width, back.height, back.seconds, back.fps, back.loop]).toEqual([120, 90, 1.5, 4, true]);
      expect(back.keyframes.length).toBe(3);
      back.keyframes.forEach((k, i) => { near(k.c2w.flat(), KEYS[i].c2w.flat()); expect(k.fov).toBe(KEYS[i].fov); });
      const again = pathJson(back, pl).camera_path as { camera_to_world: number[]; fov: number }[];
      again.forEach((c, i) => { near(c.camera_to_world, json.camera_path[i].camera_to_world); expect(c.fov).toBeCloseTo(json.camera_path[i].fov, 12); });
    }
    // The file holds capture coordinates: the first keyframe's centre (0,0,0) is
    // Rᵀ·(0/1.25 − t) = Rz(−90°)·(−0.2, 0.1, −0.1) = (0.1, 0.2, −0.1).
    near(JSON.parse(pathText(path, placement)).keyframes[0].matrix.filter((_: number, i: number) => i % 4 === 3), [0.1, 0.2, -0.1, 1], 1e-15);
  });

  it("a file without keyframes loads its cameras as keyframes (the repository's example path)", () => {
    const text = readFileSync(resolve(import.meta.dirname, "../../../examples/camera_path.json"), "utf8");
    const p = readPath(text, "camera_path.json", null);
    expect(p.keyframes.length).toBe(24);
    expect([p.width, p.height, p.seconds, p.fps, p.loop]).toEqual([200, 200, 2.4, 10, true]);
    const first = JSON.parse(text).camera_path[0];
    near(p.keyframes[0].c2w.flat(), first.camera_to_world);
    expect(p.keyframes[0].fov).toBe(40);
    // Nested 4×4 lists read too; fps defaults to one camera per frame.
    const nested = JSON.stringify({ render_width: 10, render_height: 10, seconds: 2, camera_path: [{ camera_to_world: [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]], fov: 50 }] });
    const q = readPath(nested, "p.json", null);
    near(q.keyframes[0].c2w.map((r) => r[3]), [1, 2, 3, 1]);
    expect(q.fps).toBe(0.5);
  });

  it("bad files: the error names the file and the key", () => {
    const good = pathJson(path, null);
    const cases: [(v: any) => void, RegExp][] = [
      [(v) => delete v.render_width, /^camera_path\.json: render_width: missing$/],
      [(v) => { v.render_height = 0; }, /render_height: 0 is not a positive whole number of pixels/],
      [(v) => { v.seconds = -1; }, /seconds: -1 is not a positive duration/],
      [(v) => { v.fps = "fast"; }, /fps: "fast" is not a number/],
      [(v) => { v.is_cycle = "yes"; }, /is_cycle: "yes" is not true or false/],
      [(v) => { v.camera_type = "fisheye"; }, /camera_type: "fisheye": only perspective cameras/],
      [(v) => { v.keyframes = []; delete v.camera_path; }, /camera_path: missing \(and no keyframes\)/],
      [(v) => { v.keyframes = 3; }, /keyframes: not a list/],
      [(v) => { v.keyframes[1] = 3; }, /keyframes\[1\]: not an object with matrix and fov/],
      [(v) => { v.keyframes[0].matrix.pop(); }, /keyframes\[0\]\.matrix: 15 numbers, expected 16/],
      [(v) => { v.keyframes[0].matrix[3] = null; }, /keyframes\[0\]\.matrix\[3\]: null is not a number/],
      [(v) => { v.keyframes[2].matrix[15] = 2; }, /keyframes\[2\]\.matrix: the last row is \[0, 0, 0, 2\]/],
      [(v) => { v.keyframes[0].matrix[0] = 2; }, /keyframes\[0\]\.matrix: the rotation is not orthonormal/],
      [(v) => { v.keyframes[0].matrix[0] = -1; v.keyframes[0].matrix[5] = 1; v.keyframes[0].matrix[10] = 1; }, /keyframes\[0\]\.matrix: the rotation is a reflection/],
      [(v) => { v.keyframes[1].fov = 180; }, /keyframes\[1\]\.fov: 180 is outside \(0, 180\) degrees/],
      [(v) => { delete v.keyframes; v.camera_path[0].fov = 0; }, /camera_path\[0\]\.fov: 0 is outside/],
      [(v) => { delete v.keyframes; delete v.camera_path[4].camera_to_world; }, /camera_path\[4\]\.camera_to_world: missing/],
      [(v) => { v.render_width = 20000; }, /width 20000 is not a whole number of pixels from 1 to 16384/],
    ];
    for (const [edit, message] of cases) {
      const v = structuredClone(good);
      edit(v);
      expect(() => readPath(JSON.stringify(v), "camera_path.json", null)).toThrow(message);
    }
    expect(() => readPath("{", "a.json", null)).toThrow(/^a\.json: not JSON/);
    expect(() => readPath('{"fov": NaN}', "a.json", null)).toThrow(/^a\.json: not JSON/);
    expect(() => readPath("[1]", "a.json", null)).toThrow(/a\.json: not a camera path: the top level is not a JSON object/);
  });
});
