// The bounds of the fly navigation for forward-facing captures, on cases worked out by hand.
import { describe, expect, it } from "vitest";
import { type Region, type Vec3, captureRegion, clampFly, flyFromPose, flyPose, inside, look, moveBy } from "../../src/fly";

/** A c2w looking along `fwd` (unit) from `eye`, level to +y. */
function pose(eye: Vec3, fwd: Vec3): number[][] {
  return flyPose({ eye, fwd }, [0, 1, 0]);
}

const near = (got: number[], want: number[], tol = 1e-12) => got.forEach((v, i) => expect(Math.abs(v - want[i])).toBeLessThanOrEqual(tol));
const deg = Math.PI / 180;

describe("captureRegion", () => {
  // Eyes at (0,0,0) and (3,4,0): box diagonal 5, grown 0.5 each side. Views along −z turned
  // ±10° about y: mean axis −z, widest 10°, cone 10° + 0.1 rad.
  const s = Math.sin(10 * deg), c = Math.cos(10 * deg);
  const r = captureRegion([pose([0, 0, 0], [s, 0, -c]), pose([3, 4, 0], [-s, 0, -c])]);
  it("grows the box of the eyes by a tenth of its diagonal", () => {
    expect(r.size).toBeCloseTo(5, 12);
    near(r.lo, [-0.5, -0.5, -0.5]);
    near(r.hi, [3.5, 4.5, 0.5]);
  });
  it("takes the cone around the mean view out to the widest view, plus 0.1 rad", () => {
    near(r.axis, [0, 0, -1]);
    expect(r.cone).toBeCloseTo(10 * deg + 0.1, 12);
    near(r.up, [0, 1, 0]);
  });
  it("refuses no poses", () => expect(() => captureRegion([])).toThrow(/no poses/));
});

describe("clampFly", () => {
  const r: Region = { lo: [-1, -1, -1], hi: [1, 2, 3], axis: [0, 0, -1], cone: 30 * deg, up: [0, 1, 0], size: 1 };
  it("clamps the eye to the box, each axis", () => {
    near(clampFly({ eye: [5, -7, 0.5], fwd: [0, 0, -1] }, r).eye, [1, -1, 0.5]);
  });
  it("leaves a view inside the cone as it is", () => {
    const f = { eye: [0, 0, 0] as Vec3, fwd: [Math.sin(20 * deg), 0, -Math.cos(20 * deg)] as Vec3 };
    near(clampFly(f, r).fwd, f.fwd);
  });
  it("turns a view outside the cone onto its edge, on the same side", () => {
    // 60° to +x: back to 30° to +x.
    near(clampFly({ eye: [0, 0, 0], fwd: [Math.sin(60 * deg), 0, -Math.cos(60 * deg)] }, r).fwd, [0.5, 0, -Math.cos(30 * deg)]);
    // Straight up (+y, 90°): 30° towards +y.
    near(clampFly({ eye: [0, 0, 0], fwd: [0, 1, 0] }, r).fwd, [0, 0.5, -Math.cos(30 * deg)]);
  });
  it("turns a view straight back onto the cone's edge", () => {
    const f = clampFly({ eye: [0, 0, 0], fwd: [0, 0, 1] }, r).fwd;
    expect(f[2]).toBeCloseTo(-Math.cos(30 * deg), 12);
    expect(Math.hypot(...f)).toBeCloseTo(1, 12);
  });
});

describe("look and move", () => {
  const r: Region = { lo: [-1, -1, -1], hi: [1, 1, 1], axis: [0, 0, -1], cone: 30 * deg, up: [0, 1, 0], size: 1 };
  const f0 = { eye: [0, 0, 0] as Vec3, fwd: [0, 0, -1] as Vec3 };
  it("yaws about up (positive: left) and pitches about right (positive: up)", () => {
    near(look(f0, r, 20 * deg, 0).fwd, [-Math.sin(20 * deg), 0, -Math.cos(20 * deg)]);
    near(look(f0, r, 0, 20 * deg).fwd, [0, Math.sin(20 * deg), -Math.cos(20 * deg)]);
  });
  it("stops at the cone however far it turns", () => {
    near(look(f0, r, -170 * deg, 0).fwd, [0.5, 0, -Math.cos(30 * deg)]);
  });
  it("moves in the camera's frame and stops at the box", () => {
    near(moveBy(f0, r, 0.25, 0.5, 0.75).eye, [0.25, 0.5, -0.75]);
    near(moveBy(f0, r, 0, 0, 10).eye, [0, 0, -1]);
    near(moveBy(f0, r, -10, 10, 0).eye, [-1, 1, 0]);
  });
});

describe("poses", () => {
  it("a level pose round-trips through flyFromPose and flyPose", () => {
    const m = pose([1, 2, 3], [0.6, 0, -0.8]);
    near(m[0], [0.8, 0, -0.6, 1]); // right = fwd × up = (0.8, 0, 0.6), z = −fwd
    near(m[1], [0, 1, 0, 2]);
    near(m[2], [0.6, 0, 0.8, 3]);
    near(flyPose(flyFromPose(m), [0, 1, 0]).flat(), m.flat());
  });
  it("inside checks both the box and the cone", () => {
    const r: Region = { lo: [-1, -1, -1], hi: [1, 1, 1], axis: [0, 0, -1], cone: 30 * deg, up: [0, 1, 0], size: 1 };
    expect(inside(pose([0.9, 0, 0], [0, 0, -1]), r)).toBe(true);
    expect(inside(pose([1.1, 0, 0], [0, 0, -1]), r)).toBe(false);
    expect(inside(pose([0, 0, 0], [Math.sin(31 * deg), 0, -Math.cos(31 * deg)]), r)).toBe(false);
  });
});
