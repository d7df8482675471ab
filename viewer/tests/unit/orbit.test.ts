// The orbit camera about a capture's up vector, on cases worked out by hand.
import { describe, expect, it } from "vitest";
import { orbitFromPose, orbitPose, poleFrame } from "../../src/view";
import { captureUp, flyPose } from "../../src/fly";

const near = (got: number[], want: number[], tol = 1e-12) => got.forEach((v, i) => expect(Math.abs(v - want[i])).toBeLessThanOrEqual(tol));

describe("orbit about up", () => {
  it("z up: theta and phi are the usual spherical angles (x, y, z frame)", () => {
    const [e1, e2] = poleFrame([0, 0, 1]);
    near(e1, [1, 0, 0]);
    near(e2, [0, 1, 0]);
    // phi 90°, theta 90°: eye at (0, 4, 0) looking at the origin, x = z × (0, 1, 0) = (−1, 0, 0).
    const m = orbitPose({ target: [0, 0, 0], radius: 4, theta: Math.PI / 2, phi: Math.PI / 2, up: [0, 0, 1] });
    near(m.map((r) => r[3]), [0, 4, 0, 1]);
    near(m.map((r) => r[0]), [-1, 0, 0, 0]);
    near(m.map((r) => r[1]), [0, 0, 1, 0]);
  });
  it("y up: an eye on +z at the target's height has phi 90°, and turning theta keeps its height", () => {
    const pose = flyPose({ eye: [0, 1, 4], fwd: [0, 0, -1] }, [0, 1, 0]); // looks at (0, 1, 0)
    const o = orbitFromPose(pose, 0.1, [0, 1, 0]);
    near(o.target, [0, 1, 0]);
    expect(o.radius).toBeCloseTo(4, 12);
    expect(o.phi).toBeCloseTo(Math.PI / 2, 12);
    near(orbitPose(o).flat(), pose.flat()); // the orbit goes through the pose
    for (const t of [0.3, 1.7, 3]) {
      const m = orbitPose({ ...o, theta: o.theta + t });
      expect(m[1][3]).toBeCloseTo(1, 12); // the eye stays at height 1
      near(m.map((r) => r[1]), [0, 1, 0, 0]); // the camera stays upright
    }
  });
  it("captureUp is the mean of the poses' +y axes", () => {
    const a = flyPose({ eye: [0, 0, 0], fwd: [0, 0, -1] }, [0, 1, 0]);
    const b = flyPose({ eye: [0, 0, 0], fwd: [0, 0, -1] }, [1, 0, 0]);
    near(captureUp([a, b]), [Math.SQRT1_2, Math.SQRT1_2, 0]);
  });
});
