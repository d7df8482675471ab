// The viewer in a real browser (Debian's chromium through playwright-core) against the native
// renderer: each bundle's test pose 0 rendered by the page (?pose=test:0) and by
// `nerf-render --npy` must agree to max |Δrgb| <= 1e-3 and PSNR >= 40 dB. A second chromium
// with --enable-unsafe-webgpu (a software WebGPU adapter) renders the portable hash-grid fixture
// on WebGPU, which must agree with its WASM frame to 1e-5, and a bitwise graph, which must fall
// back to WASM with the reason on the stats line (both skip, saying so, without an adapter).
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
import { spawn } from "node:child_process";
import { cpSync, existsSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";
import { serve } from "./serve.mjs";
import { REPO, frameError, freePort, nativeFrame } from "./common.mjs";

/** A tiny hash-grid bundle in the portable lowering (fixtures/ngp-portable/README.md). */
const PORTABLE = resolve(import.meta.dirname, "fixtures/ngp-portable");

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

/** Render test pose 0 in the page; returns { frame, stats, line, isolated }. */
async function pageFrame(bundle, width, height, extra = "", on = browser) {
  const server = await startServer(bundle);
  const page = await on.newPage();
  try {
    await page.goto(`${server.url}?pose=test:0&width=${width}&height=${height}${extra}`);
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
