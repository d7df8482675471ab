// The viewer in a real browser (Debian's chromium through playwright-core) against the native
// renderer: each bundle's test pose 0 rendered by the page (?pose=test:0) and by
// `nerf-render --npy` must agree to max |Δrgb| <= 1e-3 and PSNR >= 40 dB. A second chromium
// with --enable-unsafe-webgpu (a software WebGPU adapter) renders the portable hash-grid fixture
// on WebGPU, which must agree with its WASM frame to 1e-5, and a bitwise graph, which must fall
// back to WASM with the reason on the stats line (both skip, saying so, without an adapter).
// The contracted fixture (nerf-rs-scene-3: marched in segments through a NERFOCC2 grid) must
// match nerf-render to 1e-5 on every test pose on WASM, and on WebGPU (a smaller frame).
//
// The pages are served by `nerf-render --bundle B --serve --port P --viewer dist/` on a free
// loopback port. Environment: NERF_SERVE_CMD swaps the server: a shell command with {root},
// {bundle} and {port} filled in; `node` uses the in-process Node server (tests/serve.mjs)
// instead. The broken-bundle tests add --show-bundle-error to the command (nerf-render refuses
// to serve a bundle that does not load without it). The test without COOP/COEP always uses the
// Node server (nerf-render always sends them). CHROMIUM (default
// /usr/bin/chromium), NERF_RENDER (default $CARGO_TARGET_DIR/release/nerf-render after
// scripts/env.sh). Run `npm run build` first.
import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { execFileSync, spawn } from "node:child_process";
import { cpSync, existsSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";
import { serve } from "./serve.mjs";
import { REPO, frameError, freePort, nativeFrame, nativeTestFrames } from "./common.mjs";

/** A tiny hash-grid bundle in the portable lowering (fixtures/ngp-portable/README.md). */
const PORTABLE = resolve(import.meta.dirname, "fixtures/ngp-portable");
/** The same over a contracted world (fixtures/ngp-contracted/README.md). */
const CONTRACTED = resolve(import.meta.dirname, "fixtures/ngp-contracted");

const VIEWER = resolve(import.meta.dirname, "..");
const DIST = join(VIEWER, "dist");

/** Start a server for `bundle` (`broken`: one that does not load, served with
 * --show-bundle-error); returns { url, stop }. NERF_SERVE_CMD swaps in another server. */
export async function startServer(bundle, { broken = false } = {}) {
  const cmd = process.env.NERF_SERVE_CMD ??
    (process.env.NERF_RENDER ? `'${process.env.NERF_RENDER}'` : '. scripts/env.sh && exec "$CARGO_TARGET_DIR/release/nerf-render"') +
      " --bundle {bundle} --serve --port {port} --viewer {root}";
  if (cmd === "node") {
    const server = await serve({ root: DIST, bundle });
    return { url: `http://127.0.0.1:${server.address().port}/`, stop: () => new Promise((ok) => server.close(ok)) };
  }
  const port = await freePort();
  const line = (cmd + (broken ? " --show-bundle-error" : "")).replaceAll("{root}", DIST).replaceAll("{bundle}", bundle).replaceAll("{port}", String(port));
  const child = spawn("bash", ["-c", line], { cwd: REPO, stdio: ["ignore", "inherit", "inherit"], detached: true });
  const url = `http://127.0.0.1:${port}/`;
  for (let i = 0; ; i++) {
    try { if ((await fetch(url)).ok) break; } catch { /* not up yet */ }
    if (i > 300 || child.exitCode !== null) { try { process.kill(-child.pid); } catch {} throw new Error(`server did not come up: ${line}`); }
    await new Promise((ok) => setTimeout(ok, 100));
  }
  return { url, stop: async () => { try { process.kill(-child.pid); } catch {} } };
}

// Two browsers: one without a GPU (--disable-gpu: WASM, as most tests expect), and one with
// WebGPU on chromium's software adapter (SwiftShader; --enable-unsafe-webgpu offers it headless).
let browser, gpuBrowser, gpuAdapter;
before(async () => {
  assert.ok(existsSync(join(DIST, "index.html")), "run `npm run build` first");
  const launch = (flags) => chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", args: ["--no-sandbox", "--disable-dev-shm-usage", ...flags] });
  browser = await launch(["--disable-gpu"]);
  gpuBrowser = await launch(["--enable-unsafe-webgpu"]);
  // WebGPU needs a secure context: a page of the loopback server.
  const server = await serve({ root: DIST, bundle: PORTABLE });
  const page = await gpuBrowser.newPage();
  await page.goto(`http://127.0.0.1:${server.address().port}/?bundle=none/`);
  gpuAdapter = await page.evaluate(async () => !!(await navigator.gpu?.requestAdapter()));
  await page.close();
  await new Promise((ok) => server.close(ok));
});
after(async () => { await browser?.close(); await gpuBrowser?.close(); });

/** Render test pose `pose` in the page; returns { frame, stats, line, isolated }. */
async function pageFrame(bundle, width, height, extra = "", on = browser, pose = 0) {
  const server = await startServer(bundle);
  const page = await on.newPage();
  try {
    await page.goto(`${server.url}?pose=test:${pose}&width=${width}&height=${height}${extra}`);
    await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 300_000 });
    const r = await page.evaluate(() => ({
      state: document.body.dataset.state, error: document.getElementById("error")?.textContent,
      stats: window.nerfStats, line: document.getElementById("stats").textContent, isolated: crossOriginIsolated, frame: window.nerfFrame && Array.from(window.nerfFrame),
      canvas: [document.getElementById("view").width, document.getElementById("view").height],
    }));
    assert.equal(r.state, "done", `page error: ${r.error}`);
    return r;
  } finally { await page.close(); await server.stop(); }
}

function compare(name, bundle, width, dense = false) {
  test(`${name}${dense ? " (dense)" : ""}: browser matches nerf-render at width ${width}`, { timeout: 600_000 }, async (t) => {
    const native = nativeFrame(bundle, width, dense);
    const [h, w] = native.shape;
    const r = await pageFrame(bundle, w, h, dense ? "&dense=1" : "");
    assert.deepEqual(r.canvas, [w, h]);
    const { maxDiff, psnr } = frameError(r.frame, native);
    t.diagnostic(`${name}: ${w}×${h}, max |Δrgb| ${maxDiff.toExponential(2)}, PSNR ${psnr.toFixed(1)} dB, ` +
      `${r.stats.ms.toFixed(0)} ms, ${r.stats.points} points, ${r.stats.threads} threads, isolated ${r.isolated}`);
    assert.ok(maxDiff <= 1e-3, `max |Δrgb| ${maxDiff} > 1e-3`);
    assert.ok(psnr >= 40, `PSNR ${psnr} < 40 dB`);
    // Under COOP/COEP the page is isolated and onnxruntime gets more than one thread.
    assert.equal(r.isolated, true);
    assert.ok(r.stats.threads > 1, `threads ${r.stats.threads}`);
    assert.equal(r.stats.backend, "wasm");
    assert.match(r.line, /wasm, \d+ threads \(no GPU adapter\)/);
  });
}

compare("spheres", join(REPO, "models/spheres"), 64);
compare("spheres", join(REPO, "models/spheres"), 64, true);
// Each bundle at its full training size (lego 100×100, lego-ngp 400×400); the dense paths smaller.
compare("lego", join(REPO, "models/lego"), 100);
compare("lego", join(REPO, "models/lego"), 50, true);
compare("lego-ngp", join(REPO, "models/lego-ngp"), 400);
compare("ngp-portable", PORTABLE, 100);

test("the hash grid in the page and the whole graph in onnxruntime-web (?encoding=graph) both give nerf-render's frame", { timeout: 600_000 }, async (t) => {
  const native = nativeFrame(PORTABLE, 100);
  const [h, w] = native.shape;
  const split = await pageFrame(PORTABLE, w, h), whole = await pageFrame(PORTABLE, w, h, "&encoding=graph");
  for (const [what, r] of [["split", split], ["whole", whole]]) {
    const { maxDiff } = frameError(r.frame, native);
    t.diagnostic(`${what}: max |Δrgb| ${maxDiff.toExponential(2)}; ${r.line}`);
    assert.ok(maxDiff <= 1e-5, `${what}: max |Δrgb| ${maxDiff} > 1e-5`);
  }
  assert.match(split.line, /field [\d.]+ s \(hash grid [\d.]+ s\).* · hash grid here, \d+ threads/);
  assert.ok(split.stats.encodeMs > 0);
  assert.match(whole.line, /whole graph \(asked for\)/);
  assert.equal(whole.stats.encodeMs, 0);
});

/** The contracted fixture's test poses in the page (`on`'s browser) against nerf-render's at
 * `width` (default: full size): max |Δrgb| <= 1e-5 each; returns the pages' results. */
async function compareContracted(t, on, width, poses = Infinity) {
  const native = nativeTestFrames(CONTRACTED, width).slice(0, poses), pages = [];
  for (const [i, { name, frame }] of native.entries()) {
    const [h, w] = frame.shape;
    const r = await pageFrame(CONTRACTED, w, h, "", on, i);
    const { maxDiff, psnr } = frameError(r.frame, frame);
    t.diagnostic(`ngp-contracted ${name}: ${w}×${h}, max |Δrgb| ${maxDiff.toExponential(2)}, PSNR ${psnr.toFixed(1)} dB, ${r.stats.points} points; ${r.line}`);
    assert.ok(r.stats.points > 1000, `${r.stats.points} points: the view sees the scene`);
    assert.ok(maxDiff <= 1e-5, `${name}: max |Δrgb| ${maxDiff} > 1e-5`);
    pages.push(r);
  }
  return pages;
}

test("ngp-contracted: a contracted bundle's test poses match nerf-render to 1e-5 (WASM)", { timeout: 600_000 }, async (t) => {
  const pages = await compareContracted(t, browser);
  assert.equal(pages.length, 2);
  for (const r of pages) assert.equal(r.stats.backend, "wasm");
});

// WebGPU on the software adapter is slow: one small frame.
test("webgpu: the contracted bundle on WebGPU matches nerf-render to 1e-5", { timeout: 600_000 }, async (t) => {
  if (!gpuAdapter) { t.skip("chromium offers no WebGPU adapter here"); return; }
  const [r] = await compareContracted(t, gpuBrowser, 9, 1);
  assert.equal(r.stats.backend, "webgpu", r.line);
});

/** max |a − b| over two frames of the same size. */
function maxDiff(a, b) {
  assert.equal(a.length, b.length);
  return a.reduce((m, v, i) => Math.max(m, Math.abs(v - b[i])), 0);
}

// WebGPU on the software adapter is slow (≈ 1,300 points/s here): small frames.
test("webgpu: the portable hash grid renders on WebGPU and agrees with WASM", { timeout: 600_000 }, async (t) => {
  if (!gpuAdapter) { t.skip("chromium offers no WebGPU adapter here"); return; }
  const gpu = await pageFrame(PORTABLE, 24, 24, "", gpuBrowser);
  const cpu = await pageFrame(PORTABLE, 24, 24, "&ep=wasm", gpuBrowser);
  assert.equal(gpu.stats.backend, "webgpu", gpu.line);
  assert.match(gpu.line, /webgpu \(.*adapter/);
  assert.equal(cpu.stats.backend, "wasm");
  assert.ok(gpu.stats.points > 1000, `${gpu.stats.points} points: the view sees the object`);
  const diff = maxDiff(gpu.frame, cpu.frame);
  t.diagnostic(`webgpu vs wasm: max |Δrgb| ${diff.toExponential(2)} over ${gpu.stats.points} points; ${gpu.line}`);
  assert.ok(diff <= 1e-5, `max |Δrgb| ${diff} > 1e-5`);
});

test("webgpu: a bitwise graph falls back to WASM and the stats line says why", { timeout: 600_000 }, async (t) => {
  if (!gpuAdapter) { t.skip("chromium offers no WebGPU adapter here"); return; }
  const r = await pageFrame(join(REPO, "models/lego-ngp"), 24, 24, "", gpuBrowser);
  assert.equal(r.stats.backend, "wasm");
  assert.match(r.line, /wasm, \d+ threads \(field\.onnx has ops WebGPU lacks: BitwiseXor/);
});

test("interactive page: refines to full size, re-renders after a drag, depth toggle", { timeout: 300_000 }, async () => {
  const server = await startServer(join(REPO, "models/spheres"));
  const page = await browser.newPage();
  try {
    await page.goto(server.url);
    const done = () => page.waitForFunction(() => document.body.dataset.state === "done" || document.body.dataset.state === "error", null, { timeout: 120_000 });
    await done();
    assert.equal(await page.evaluate(() => document.body.dataset.state), "done");
    assert.deepEqual(await page.evaluate(() => [window.nerfStats.width, window.nerfStats.height]), [64, 64]);
    assert.equal(await page.evaluate(() => window.nerfCamera.nav), "orbit", "a 360° capture orbits");
    assert.ok((await page.locator("#pose option").count()) > 1);
    assert.equal(await page.locator("#isolation").isHidden(), true);
    const before = await page.evaluate(() => document.getElementById("view").toDataURL());
    const box = await page.locator("#view").boundingBox();
    await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
    await page.mouse.down();
    await page.mouse.move(box.x + box.width / 2 + 40, box.y + box.height / 2, { steps: 4 });
    await page.mouse.up();
    await page.waitForFunction(() => document.body.dataset.state === "rendering", null, { timeout: 10_000 }).catch(() => {});
    await done();
    assert.equal(await page.evaluate(() => document.body.dataset.state), "done");
    const afterDrag = await page.evaluate(() => document.getElementById("view").toDataURL());
    assert.notEqual(afterDrag, before, "the view did not change after a drag");
    await page.click("#mode");
    assert.notEqual(await page.evaluate(() => document.getElementById("view").toDataURL()), afterDrag, "depth view looks like rgb");
  } finally { await page.close(); await server.stop(); }
});

/** fern as a bundle: the nerf-pytorch checkpoint of tests/fixtures imported (NDC rays, 3 test
 *  poses) with the LLFF data of $NERF_SHARED/data/real/fern (default ../shared, as the Rust tests). */
function fernBundle() {
  const fern = join(process.env.NERF_SHARED ?? join(REPO, "../shared"), "data/real/fern");
  assert.ok(existsSync(join(fern, "poses_bounds.npy")), `${fern} is missing (CI provides ../shared; NERF_SHARED points elsewhere)`);
  const dir = mkdtempSync(join(tmpdir(), "nerf-fern-"));
  const out = join(dir, "fern");
  execFileSync("bash", ["-c", '. scripts/env.sh && exec "$CARGO_TARGET_DIR/release/nerf" "$@"', "nerf", "import", "nerf-pytorch",
    "--checkpoint", join(REPO, "tests/fixtures/nerf-pytorch/llff/001500.tar"), "--data", fern, "--out", out],
    { cwd: REPO, stdio: "pipe", env: { ...process.env } });
  return { dir, bundle: out };
}

/** The region the fly camera must keep to, computed here from the poses as docs/viewer.md states
 *  it: the box of the eyes grown by a tenth of its diagonal, and the cone around the mean view
 *  direction out to the widest view plus 0.1 rad. */
function regionOf(poses) {
  const eye = (m) => [m[0][3], m[1][3], m[2][3]];
  const fwd = (m) => { const v = [-m[0][2], -m[1][2], -m[2][2]], l = Math.hypot(...v); return v.map((x) => x / l); };
  const lo = [0, 1, 2].map((a) => Math.min(...poses.map((m) => eye(m)[a]))), hi = [0, 1, 2].map((a) => Math.max(...poses.map((m) => eye(m)[a])));
  const g = 0.1 * Math.hypot(...hi.map((v, a) => v - lo[a]));
  const sum = [0, 1, 2].map((a) => poses.reduce((t, m) => t + fwd(m)[a], 0)), l = Math.hypot(...sum), axis = sum.map((v) => v / l);
  const ang = (v) => Math.acos(Math.min(1, Math.max(-1, v[0] * axis[0] + v[1] * axis[1] + v[2] * axis[2])));
  return { lo: lo.map((v) => v - g), hi: hi.map((v) => v + g), ang, eye, fwd, cone: Math.max(...poses.map((m) => ang(fwd(m)))) + 0.1 };
}

test("fern (NDC): flying by drags, wheel and keys keeps the camera inside the captured region; the snap button gives test pose 0", { timeout: 300_000 }, async (t) => {
  const { dir, bundle } = fernBundle();
  const scene = JSON.parse(readFileSync(join(bundle, "scene.json"), "utf8"));
  assert.ok(scene.sampling.ndc, "the imported fern bundle has NDC rays");
  const poses = scene.poses.test.map((p) => p.transform_matrix);
  const r = regionOf(poses);
  const server = await startServer(bundle);
  const page = await browser.newPage();
  try {
    await page.goto(`${server.url}?width=80`);
    const done = () => page.waitForFunction(() => document.body.dataset.state === "done" || document.body.dataset.state === "error", null, { timeout: 120_000 });
    await done();
    assert.equal(await page.evaluate(() => document.body.dataset.state), "done", await page.locator("#error").textContent());
    const camera = () => page.evaluate(() => window.nerfCamera);
    const first = await camera();
    assert.equal(first.nav, "fly");
    assert.deepEqual(first.c2w, poses[0]);
    const tol = 1e-6;
    const where = (c2w) => ({ eye: r.eye(c2w), angle: r.ang(r.fwd(c2w)) });
    const check = async (what) => {
      const c = await camera();
      const w = where(c.c2w);
      for (let a = 0; a < 3; a++)
        assert.ok(w.eye[a] >= r.lo[a] - tol && w.eye[a] <= r.hi[a] + tol, `${what}: eye ${w.eye} outside [${r.lo}] .. [${r.hi}]`);
      assert.ok(w.angle <= r.cone + tol, `${what}: view ${w.angle} rad from the capture's axis, cone ${r.cone}`);
      return w;
    };
    const box = await page.locator("#view").boundingBox();
    const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
    const drag = async (dx, dy, button = "left") => {
      await page.mouse.move(cx, cy);
      await page.mouse.down({ button });
      await page.mouse.move(cx + dx, cy + dy, { steps: 8 });
      await page.mouse.up({ button });
    };
    // Far enough that an unbounded camera would leave: 1,500 px of look is 4.5 rad.
    await drag(1500, 0);
    let w = await check("look right");
    assert.ok(Math.abs(w.angle - r.cone) < 1e-6, `a long look stops on the cone's edge: ${w.angle} vs ${r.cone}`);
    await drag(-700, -900);
    await check("look up-left");
    await page.keyboard.down("Shift");
    await drag(-2000, 1500);
    await page.keyboard.up("Shift");
    await check("shift-drag");
    await drag(3000, -3000, "right");
    await check("right-drag");
    for (let i = 0; i < 40; i++) await page.mouse.wheel(0, -2000);
    w = await check("wheel forward");
    const onFace = w.eye.some((v, a) => Math.abs(v - r.lo[a]) < 1e-6 || Math.abs(v - r.hi[a]) < 1e-6);
    assert.ok(onFace, `moving far forward stops on the box: eye ${w.eye}`);
    await page.locator("#view").click();
    for (const key of ["w", "w", "a", "a", "a", "e", "e", "ArrowDown", "q", "d", "s"]) for (let i = 0; i < 10; i++) await page.keyboard.press(key);
    await check("keys");
    await done();
    assert.equal(await page.evaluate(() => document.body.dataset.state), "done", "the moved views render");
    assert.notDeepEqual((await camera()).c2w, poses[0], "the camera moved");
    t.diagnostic(`fern: region ${r.lo.map((v) => v.toFixed(3))} .. ${r.hi.map((v) => v.toFixed(3))}, cone ${r.cone.toFixed(3)} rad; last eye ${where((await camera()).c2w).eye.map((v) => v.toFixed(3))}`);
    // One click back to test pose 0, though it is still the chosen pose.
    await page.click("#snap");
    assert.deepEqual((await camera()).c2w, poses[0]);
    await page.selectOption("#pose", "2");
    assert.deepEqual((await camera()).c2w, poses[2]);
    await done();
    assert.equal(await page.evaluate(() => document.body.dataset.state), "done");
  } finally { await page.close(); await server.stop(); rmSync(dir, { recursive: true, force: true }); }
});

test("a missing bundle shows its error on the page", { timeout: 120_000 }, async () => {
  // ?bundle= points the page at a directory the server does not have (any server: 404).
  const server = await startServer(join(REPO, "models/spheres"));
  const page = await browser.newPage();
  try {
    await page.goto(`${server.url}?pose=test:0&bundle=missing/`);
    await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 60_000 });
    assert.equal(await page.evaluate(() => document.body.dataset.state), "error");
    assert.match(await page.locator("#error").textContent(), /scene\.json.*404/);
  } finally { await page.close(); await server.stop(); }
});

/** A copy of models/spheres changed by `edit(dir)`. */
function brokenBundle(edit) {
  const dir = mkdtempSync(join(tmpdir(), "nerf-broken-"));
  cpSync(join(REPO, "models/spheres"), dir, { recursive: true });
  edit(dir);
  return dir;
}

// nerf-render serves such a bundle's scene.json alone: a scene.json error shows as it is, and
// for any other file the page shows the first graph it could not fetch.
for (const [what, edit, message] of [
  ["a missing graph", (dir) => rmSync(join(dir, "fine.onnx")), /bundle\/(coarse|fine)\.onnx: HTTP 404/],
  ["a scene.json that is not JSON", (dir) => writeFileSync(join(dir, "scene.json"), "{ not json"), /scene\.json/],
  ["a scene.json without a camera", (dir) => {
    const scene = JSON.parse(readFileSync(join(dir, "scene.json"), "utf8"));
    delete scene.camera;
    writeFileSync(join(dir, "scene.json"), JSON.stringify(scene));
  }, /camera/],
]) {
  test(`a bundle with ${what} shows its error on the page`, { timeout: 120_000 }, async () => {
    const bundle = brokenBundle(edit);
    const server = await startServer(bundle, { broken: true });
    const page = await browser.newPage();
    try {
      await page.goto(`${server.url}?pose=test:0&width=32&height=32`);
      await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 60_000 });
      assert.equal(await page.evaluate(() => document.body.dataset.state), "error");
      const text = await page.locator("#error").textContent();
      assert.match(text, message);
      assert.equal(await page.locator("#error").isVisible(), true, "the reason is on the page");
    } finally { await page.close(); await server.stop(); rmSync(bundle, { recursive: true, force: true }); }
  });
}

test("without COOP/COEP: a visible note, one thread", { timeout: 120_000, }, async () => {
  const server = await serve({ root: DIST, bundle: join(REPO, "models/spheres"), isolation: false });
  const page = await browser.newPage();
  try {
    await page.goto(`http://127.0.0.1:${server.address().port}/?pose=test:0&width=32&height=32&sw=0`);
    await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 60_000 });
    assert.equal(await page.evaluate(() => document.body.dataset.state), "done");
    assert.equal(await page.evaluate(() => crossOriginIsolated), false);
    assert.equal(await page.evaluate(() => window.nerfStats.threads), 1);
    assert.equal(await page.locator("#isolation").isVisible(), true);
  } finally { await page.close(); await new Promise((ok) => server.close(ok)); }
});
