// Live training in the page: `nerf view RUN` on a run folder whose snapshots this test writes as
// a trainer does (live/<step>/, a bundle put in place by a rename, the older one removed; and
// progress.json). The page shows the first snapshot and the run's step; the user turns the
// camera; then a newer snapshot (another field) appears: the page loads it by itself, renders it
// from the camera the user left (not reset), and shows the new step. The live view's render
// time is printed (what a page attached costs the trainer per snapshot), and a page asking for a
// larger view stops refining at the live view's budget of samples. Needs chromium, the
// built dist/ and the `nerf` binary (NERF, else $CARGO_TARGET_DIR/release/nerf after
// scripts/env.sh), as browser.test.mjs.
import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { spawn } from "node:child_process";
import { cpSync, existsSync, mkdirSync, mkdtempSync, renameSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";
import { REPO, freePort } from "./common.mjs";

const DIST = resolve(import.meta.dirname, "../dist");
/** Two lego fields: the shipped hash grid (32 dB; the live view is 200×200) and a tiny one
 * (about 21 dB). */
const FIRST = join(REPO, "models/lego-ngp");
const SECOND = resolve(import.meta.dirname, "fixtures/ngp-portable");

let browser, tmp, run, server, url;

/** Write progress.json as `nerf train --serve` does (src/live.rs, Progress). */
function progress(step, done = false) {
  const p = { step, iters: 1000, elapsed_s: step / 10, budget_s: 600, remaining_s: done ? 0 : 600 - step / 10, steps_per_s: 10, loss: 0.01,
    train_psnr: 20 + step / 100, val_psnr: null, snapshots: true, done };
  writeFileSync(join(run, ".progress.json.tmp"), JSON.stringify(p));
  renameSync(join(run, ".progress.json.tmp"), join(run, "progress.json"));
}

/** Put `bundle` in place as snapshot `step` (copied beside, then renamed), and remove `old`. */
function snapshot(bundle, step, old) {
  const tmpDir = join(run, "live", `.${step}.tmp-1`);
  cpSync(bundle, tmpDir, { recursive: true });
  renameSync(tmpDir, join(run, "live", String(step)));
  if (old !== undefined) rmSync(join(run, "live", String(old)), { recursive: true });
  progress(step);
}

before(async () => {
  assert.ok(existsSync(join(DIST, "index.html")), "run `npm run build` first");
  tmp = mkdtempSync(join(tmpdir(), "nerf-live-"));
  run = join(tmp, "run");
  mkdirSync(join(run, "live"), { recursive: true });
  writeFileSync(join(run, "config.toml"), "# a run folder for the live page's test\n");
  snapshot(FIRST, 100);
  const port = await freePort();
  const nerf = process.env.NERF ? `'${process.env.NERF}'` : '. scripts/env.sh && exec "$CARGO_TARGET_DIR/release/nerf"';
  const line = `${nerf} view '${run}' --port ${port} --viewer '${DIST}'`;
  server = spawn("bash", ["-c", line], { cwd: REPO, stdio: ["ignore", "inherit", "inherit"], detached: true });
  url = `http://127.0.0.1:${port}/`;
  for (let i = 0; ; i++) {
    try { if ((await fetch(url + "live/status.json")).ok) break; } catch { /* not up yet */ }
    if (i > 300 || server.exitCode !== null) throw new Error(`nerf view did not come up: ${line}`);
    await new Promise((ok) => setTimeout(ok, 100));
  }
  browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", args: ["--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"] });
});
after(async () => {
  await browser?.close();
  if (server) try { process.kill(-server.pid); } catch { /* gone */ }
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

/** The page once it shows snapshot `id`, fully rendered: its camera, pixels, line and stats. */
async function shown(page, id) {
  await page.waitForFunction((id) => window.nerfLive?.snapshot === id && document.body.dataset.state === "done" ||
    document.body.dataset.state === "error", id, { timeout: 300_000, polling: 200 });
  return page.evaluate(() => {
    const c = document.getElementById("view");
    return {
      state: document.body.dataset.state, error: document.getElementById("error").textContent, live: window.nerfLive,
      c2w: window.nerfCamera.c2w, stats: window.nerfStats, line: document.getElementById("live-progress").textContent,
      // Since the snapshot was asked for: loading it, and rendering all its passes.
      loadMs: window.nerfLive.loadedAt - window.nerfLive.askedAt, renderMs: window.nerfTimeline.at(-1).at - window.nerfLive.loadedAt,
      pixels: Array.from(c.getContext("2d").getImageData(0, 0, c.width, c.height).data),
    };
  });
}

/** Mean |Δ| over two RGBA pixel arrays of the same size, in 0–255 levels. */
function meanDiff(a, b) {
  assert.equal(a.length, b.length);
  let sum = 0;
  for (let i = 0; i < a.length; i++) if (i % 4 !== 3) sum += Math.abs(a[i] - b[i]);
  return sum / (0.75 * a.length);
}

test("a live page loads the newer snapshot by itself and keeps the user's camera", { timeout: 900_000 }, async (t) => {
  const page = await browser.newPage();
  page.on("console", (m) => { if (m.type() === "error") t.diagnostic(`page: ${m.text()}`); });
  await page.goto(url);
  const first = await shown(page, "100");
  assert.equal(first.state, "done", `page error: ${first.error}`);
  assert.equal(first.live.step, 100);
  assert.match(first.line, /^step 100 \/ 1,000 · 10 s trained · /);
  assert.ok(await page.evaluate(() => !document.getElementById("live").hidden), "the live panel is shown");

  // The user turns the camera: a drag across the view.
  const box = await page.locator("#view").boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  await page.mouse.move(box.x + box.width / 2 + 40, box.y + box.height / 2 + 10, { steps: 4 });
  await page.mouse.up();
  await page.waitForFunction(() => document.body.dataset.state === "done", null, { timeout: 300_000 });
  const turned = await shown(page, "100");
  assert.notDeepEqual(turned.c2w, first.c2w, "the drag moved the camera");
  t.diagnostic(`live view ${first.stats.width}×${first.stats.height} of lego-ngp: loaded in ${first.loadMs.toFixed(0)} ms, ` +
    `its passes (1/8 to full) rendered in ${first.renderMs.toFixed(0)} ms, the full one ${first.stats.ms.toFixed(0)} ms (${first.stats.points} points)`);

  // Asked for 200 wide, the live view stops refining where the next pass would pass its budget of
  // field samples (100×100: 176,693; 200×200 would be about four times as many).
  const wide = await browser.newPage();
  await wide.goto(url + "?width=200");
  const capped = await shown(wide, "100");
  assert.equal(capped.state, "done", `page error: ${capped.error}`);
  assert.deepEqual([capped.stats.width, capped.stats.height], [100, 100]);
  assert.match(await wide.evaluate(() => document.getElementById("stats").textContent), /stopped here: the next size passes the live view's 200k samples/);
  await wide.close();

  // A newer snapshot, another field; the older one removed, as the trainer does.
  snapshot(SECOND, 200, 100);
  const second = await shown(page, "200");
  assert.equal(second.state, "done", `page error: ${second.error}`);
  assert.equal(second.live.loads, 2);
  assert.equal(second.live.step, 200);
  assert.match(second.line, /^step 200 \/ 1,000/);
  assert.deepEqual(second.c2w, turned.c2w, "the camera stays where the user left it");
  const diff = meanDiff(turned.pixels, second.pixels);
  t.diagnostic(`the two snapshots' frames differ by ${diff.toFixed(1)} levels on average; the second loaded in ` +
    `${second.loadMs.toFixed(0)} ms, rendered in ${second.renderMs.toFixed(0)} ms`);
  assert.ok(diff > 2, `the frame did not change with the snapshot (mean |Δ| ${diff})`);
  await page.close();

  // Training ends: a page held at the live budget (100×100 of the 200 asked for) renders its
  // view in full once the run is done and its last snapshot shown.
  progress(200, true);
  const ended = await browser.newPage();
  await ended.goto(url + "?width=200");
  await ended.waitForFunction(() => window.nerfStats?.width === 200 && document.body.dataset.state === "done" ||
    document.body.dataset.state === "error", null, { timeout: 300_000, polling: 200 });
  const full = await ended.evaluate(() => ({ state: document.body.dataset.state, error: document.getElementById("error").textContent,
    stats: window.nerfStats, line: document.getElementById("live-progress").textContent,
    sizes: window.nerfTimeline.map((f) => `${f.width}×${f.height}`) }));
  assert.equal(full.state, "done", `page error: ${full.error}`);
  assert.match(full.line, /· done/);
  t.diagnostic(`once done: passes ${full.sizes.join(", ")} (${full.stats.points} points in the last)`);
  await ended.close();
});
