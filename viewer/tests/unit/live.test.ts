// The live view's progress line and curve scaling, on values worked out by hand.
import { describe, expect, it } from "vitest";
import { type LiveStatus, curvePoints, duration, progressLine } from "../../src/live";

const status = (over: Partial<LiveStatus["progress"] & object> = {}, rest: Partial<LiveStatus> = {}): LiveStatus => ({
  snapshot: "1200", progress_age_s: 1, curve: [], note: null,
  progress: { step: 1200, iters: 100000, elapsed_s: 160, budget_s: 600, remaining_s: 440, steps_per_s: 7.5, loss: 0.00421,
    train_psnr: 24.512, val_psnr: null, snapshots: true, done: false, ...over },
  ...rest,
});

describe("live progress", () => {
  it("durations: seconds, then minutes and seconds, then hours and minutes", () => {
    expect(duration(12.4)).toBe("12 s");
    expect(duration(245)).toBe("4 min 05 s");
    expect(duration(3720)).toBe("1 h 02 min");
    expect(duration(-3)).toBe("0 s");
  });
  it("a running run: step of iters, time trained and left, loss and PSNR", () => {
    expect(progressLine(status())).toBe("step 1,200 / 100,000 · 2 min 40 s trained · 7 min 20 s left · loss 0.0042 · train 24.51 dB");
    expect(progressLine(status({ val_psnr: 26.1 }))).toContain("· val 26.10 dB");
  });
  it("a finished run says done, a stalled one how long ago it stopped, and a run without progress the note", () => {
    expect(progressLine(status({ done: true }))).toContain("trained · done · loss");
    expect(progressLine(status({ loss: null }))).toBe("step 1,200 / 100,000 · 2 min 40 s trained · 7 min 20 s left · train 24.51 dB");
    expect(progressLine(status({}, { progress_age_s: 95 }))).toContain("not training (last update 1 min 35 s ago)");
    expect(progressLine(status({}, { progress: null, note: "exporting the checkpoint of step 1000" }))).toBe("exporting the checkpoint of step 1000");
  });
  it("the curve spans whole decibels and the minutes trained, inside the margin", () => {
    const rows = [{ step: 0, minutes: 0, train_psnr: 20.5, val_psnr: null }, { step: 10, minutes: 5, train_psnr: 25.2, val_psnr: 24 },
      { step: 20, minutes: 10, train_psnr: 27.9, val_psnr: 26.5 }];
    const { train, val, range } = curvePoints(rows, 108, 58, 4); // 100×50 inside the margin
    expect(range).toEqual([20, 28]);
    expect(train.map(([x]) => x)).toEqual([4, 54, 104]);
    expect(train[0][1]).toBeCloseTo(54 - (0.5 / 8) * 50, 12);
    expect(val).toHaveLength(2);
    expect(val[1][1]).toBeCloseTo(54 - (6.5 / 8) * 50, 12);
    expect(curvePoints([], 100, 50)).toEqual({ train: [], val: [], range: [0, 0] });
  });
});
