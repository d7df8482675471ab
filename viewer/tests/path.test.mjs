// The camera-path editor in headless chromium on models/lego-ngp: scripted drags and clicks on
// the panel's buttons make a path (four keyframes added from the view, one moved down, one
// deleted, one given its own fov) at 100×100, four frames; the page plays it (its played frames
// kept through window.nerfPath) and saves it with its save button (a download); `nerf-render
// --camera-path --npy` renders the saved file and each frame must agree with the page's frame of
// the same camera to PSNR >= 40 dB; the saved file loads back into the panel with the same
// keyframes. Then the same file is loaded into a copy of the bundle with a recorded placement
// (scale, rotation and shift, as a capture's scene.json has one): the page maps the file's poses
// into the field, plays, saves them back in the capture's coordinates (the same numbers), and
// nerf-render, mapping them forward itself, renders the page's frames again. Pages are served
// by the in-process Node server (tests/serve.mjs); needs chromium, the built dist/ and
// nerf-render, as browser.test.mjs.
import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { cpSync, existsSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";
import { serve } from "./serve.mjs";
import { REPO, frameError, nerfRender, readNpy } from "./common.mjs";

const DIST = resolve(import.meta.dirname, "../dist");
const BUNDLE = join(REPO, "models/lego-ngp");
/** A placement a capture might record: x' = 1.25·(Rz(90°)·x + (0.2, −0.1, 0.1)). */
const PLACEMENT = { format: "instant_ngp", transform: { scale: 1.25, rotation: [[0, -1, 0], [1, 0, 0], [0, 0, 1]], translation: [0.2, -0.1, 0.1] }, near_far: null, orbit: null };

let browser, tmp, saved; // saved: the first test's camera_path.json, loaded by the second
before(async () => {
  assert.ok(existsSync(join(DIST, "index.html")), "run `npm run build` first");
  tmp = mkdtempSync(join(tmpdir(), "nerf-path-"));
  browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", args: ["--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"] });
});
after(async () => {
  await browser?.close();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

/** The interactive page on `bundle` (a small view: 32 px wide), once its first view is done. */
async function open(bundle) {
  const server = await serve({ root: DIST, bundle });
  const page = await browser.newPage({ acceptDownloads: true });
  await page.goto(`http://127.0.0.1:${server.address().port}/?width=32`);
  await page.waitForFunction(() => ["done", "error"].includes(document.body.dataset.state), null, { timeout: 120_000 });
  assert.equal(await page.evaluate(() => document.body.dataset.state), "done", await page.locator("#error").textContent());
  assert.equal(await page.locator("#path").isVisible(), true, "the path panel shows in the interactive view");
  return { page, stop: async () => { await page.close(); await new Promise((ok) => server.close(ok)); } };
}

/** The panel's state once it leaves `from` (its data-state), and its status line. */
async function panelAfter(page, from) {
  await page.waitForFunction((s) => document.getElementById("path").dataset.state !== s, from, { timeout: 300_000 });
  return page.evaluate(() => ({ state: document.getElementById("path").dataset.state, status: document.getElementById("path-status").textContent }));
}

/** Play the path, keeping its frames: [{ width, height, rgb }]. */
async function play(page) {
  await page.evaluate(() => { window.nerfPath.keep = true; });
  await page.click("#path-play");
  const r = await panelAfter(page, "playing");
  assert.equal(r.state, "played", r.status);
  return page.evaluate(() => window.nerfPath.played);
}

/** Save through the save button; the downloaded file's path and JSON. */
async function save(page, name) {
  const [download] = await Promise.all([page.waitForEvent("download"), page.click("#path-save")]);
  assert.equal(download.suggestedFilename(), "camera_path.json");
  const file = join(tmp, name);
  await download.saveAs(file);
  return { file, json: JSON.parse(readFileSync(file, "utf8")) };
}

/** Load a file through the file input; the panel's state, status and path after it. */
async function load(page, file) {
  await page.evaluate(() => { document.getElementById("path").dataset.state = "test: loading"; });
  await page.setInputFiles("#path-load", file);
  return { ...(await panelAfter(page, "test: loading")), path: await page.evaluate(() => window.nerfPath.path()) };
}

/** nerf-render's frames of a camera path: [H, W, 5] each. */
function rendered(bundle, file, out, count) {
  nerfRender(["--bundle", bundle, "--camera-path", file, "--out", join(tmp, out), "--npy"]);
  return Array.from({ length: count }, (_, k) => readNpy(join(tmp, out, `frame_${String(k).padStart(5, "0")}.npy`)));
}

/** Each played frame against nerf-render's: >= 40 dB; the frames must show the object. */
function compareFrames(t, what, played, native) {
  assert.equal(played.length, native.length);
  played.forEach((p, k) => {
    const [h, w] = native[k].shape;
    assert.deepEqual([p.width, p.height], [w, h], `${what} frame ${k}: size`);
    let covered = 0;
    for (let i = 0; i < w * h; i++) covered += native[k].data[5 * i + 4] > 0.5 ? 1 : 0;
    assert.ok(covered > 0.05 * w * h, `${what} frame ${k}: the object covers only ${covered} pixels`);
    const { maxDiff, psnr } = frameError(p.rgb, native[k]);
    t.diagnostic(`${what} frame ${k}: ${w}×${h}, object on ${covered} pixels, max |Δrgb| ${maxDiff.toExponential(2)}, PSNR ${psnr.toFixed(1)} dB`);
    assert.ok(psnr >= 40, `${what} frame ${k}: PSNR ${psnr} < 40 dB`);
  });
}

const near = (a, b, tol, what) => a.forEach((v, i) => assert.ok(Math.abs(v - b[i]) <= tol, `${what}: entry ${i}: ${v} vs ${b[i]}`));

test("a path made by clicks renders through nerf-render --camera-path as the page plays it, and loads back", { timeout: 600_000 }, async (t) => {
  const scene = JSON.parse(readFileSync(join(BUNDLE, "scene.json"), "utf8"));
  const { page, stop } = await open(BUNDLE);
  try {
    for (const [id, v] of [["#path-width", "100"], ["#path-height", "100"], ["#path-seconds", "1"], ["#path-fps", "4"], ["#path-fov", "45"]]) await page.fill(id, v);
    const view = () => page.evaluate(() => window.nerfCamera.c2w);
    const box = await page.locator("#view").boundingBox();
    const drag = async (dx, dy) => {
      const x = box.x + box.width / 2, y = box.y + box.height / 2;
      await page.mouse.move(x, y);
      await page.mouse.down();
      await page.mouse.move(x + dx, y + dy, { steps: 4 });
      await page.mouse.up();
    };
    // Keyframes A (test pose 0, where the view opens), B, C, D after drags.
    const views = [];
    for (const [dx, dy] of [[0, 0], [60, 0], [-30, 20], [40, -25]]) {
      if (dx || dy) await drag(dx, dy);
      views.push(await view());
      await page.click("#path-add");
    }
    assert.deepEqual(views[0], scene.poses.test[0].transform_matrix, "the view opens on test pose 0");
    assert.equal(await page.locator("#path-keys option").count(), 4);
    // Reorder: B down (A C B D); delete D (A C B); B gets its own fov.
    await page.selectOption("#path-keys", "1");
    await page.click("#path-down");
    await page.selectOption("#path-keys", "3");
    await page.click("#path-delete");
    await page.selectOption("#path-keys", "2");
    await page.fill("#path-fov", "35");
    await page.press("#path-fov", "Tab"); // commits the value (change)
    const [A, B, C] = views;
    const made = await page.evaluate(() => window.nerfPath.path());
    assert.deepEqual(made.keyframes.map((k) => k.c2w), [A, C, B], "the keyframes after the reorder and the delete");
    assert.deepEqual(made.keyframes.map((k) => k.fov), [45, 45, 35]);
    assert.deepEqual([made.width, made.height, made.seconds, made.fps, made.loop], [100, 100, 1, 4, false]);

    const played = await play(page);
    assert.equal(played.length, 4);
    const first = await save(page, "camera_path.json");
    saved = first.file;
    const json = first.json;
    assert.deepEqual([json.render_width, json.render_height, json.seconds, json.fps, json.is_cycle, json.camera_path.length], [100, 100, 1, 4, false, 4]);
    // No placement (a Blender scene): the file holds the page's poses; the open path starts and
    // ends on its end keyframes.
    assert.deepEqual(json.keyframes.map((k) => k.matrix), [A, C, B].map((m) => m.flat()));
    assert.deepEqual(json.camera_path[0].camera_to_world, A.flat());
    near(json.camera_path[3].camera_to_world, B.flat(), 1e-12, "the last frame is keyframe B");
    assert.ok(Math.abs(json.camera_path[3].fov - 35) < 1e-12 && json.camera_path[0].fov === 45);

    compareFrames(t, "lego-ngp", played, rendered(BUNDLE, first.file, "plain", 4));

    // The saved file loads back: the same keyframes and settings.
    await page.click("#path-command");
    assert.match(await page.locator("#path-command-text").textContent(), /nerf-render --bundle \S+ --camera-path camera_path\.json --out/);
    await page.click("#path-delete");
    const back = await load(page, first.file);
    assert.equal(back.state, "loaded", back.status);
    assert.deepEqual(back.path, made);
    // A broken file: the panel names the file and the key, and keeps the path.
    const bad = join(tmp, "bad.json");
    writeFileSync(bad, JSON.stringify({ ...json, render_width: 0 }));
    const refused = await load(page, bad);
    assert.equal(refused.state, "error");
    assert.match(refused.status, /^bad\.json: render_width: 0 is not a positive whole number of pixels$/);
    assert.deepEqual(refused.path, made);
  } finally { await stop(); }
});

test("with a recorded placement: the file stays in the capture's coordinates and renders as the page plays it", { timeout: 600_000 }, async (t) => {
  assert.ok(saved, "the first test saved a path");
  const bundle = join(tmp, "placed");
  cpSync(BUNDLE, bundle, { recursive: true });
  const scene = JSON.parse(readFileSync(join(bundle, "scene.json"), "utf8"));
  writeFileSync(join(bundle, "scene.json"), JSON.stringify({ ...scene, placement: PLACEMENT }));
  const original = JSON.parse(readFileSync(saved, "utf8"));
  const { page, stop } = await open(bundle);
  try {
    const loaded = await load(page, saved);
    assert.equal(loaded.state, "loaded", loaded.status);
    // Keyframe A's centre mapped into the field by hand: 1.25·(Rz(90°)·o + t), Rz(90°)·(x, y, z) = (−y, x, z).
    const o = [3, 7, 11].map((i) => original.keyframes[0].matrix[i]), tr = PLACEMENT.transform.translation;
    const field = [-o[1], o[0], o[2]].map((v, a) => 1.25 * (v + tr[a]));
    near(loaded.path.keyframes[0].c2w.map((r) => r[3]).slice(0, 3), field, 1e-12, "keyframe A in the field");
    const played = await play(page);
    const { file, json } = await save(page, "placed.json");
    json.keyframes.forEach((k, i) => near(k.matrix, original.keyframes[i].matrix, 1e-12, `keyframe ${i} back in the capture's coordinates`));
    // Between keyframes to 1e-6 only: the keyframes' rotations (test pose 0's among them) are
    // float32, orthonormal to ~1e-7, and their quaternions differ by that much once rotated.
    json.camera_path.forEach((c, i) => near(c.camera_to_world, original.camera_path[i].camera_to_world, 1e-6, `camera ${i}`));
    const native = rendered(bundle, file, "placed", 4);
    compareFrames(t, "placed lego-ngp", played, native);
    // The placement moved the views: without the mapping the frames would be the plain bundle's.
    const plain = readNpy(join(tmp, "plain", "frame_00001.npy"));
    assert.ok(frameError(played[1].rgb, plain).psnr < 25, "the placed bundle's frame differs from the plain one's");
  } finally { await stop(); }
});
