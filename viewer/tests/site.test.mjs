// The static site (`nerf-render --export-site`) served by a plain static server, Python's
// `http.server` from the project's venv ($NERF_PYTHON, default ~/.cache/nerf-rs/venv/bin/python),
// which sends no cross-origin isolation headers: the page registers its service worker, reloads
// once, and renders models/lego-ngp's test pose 0 on several threads to >= 40 dB (max |Δrgb| <=
// 1e-3) against nerf-render's frame; a second visit is isolated at once; with ?sw=0 it runs on one
// thread and the stats line says why (the two timings are printed). Needs chromium, the built
// dist/ and nerf-render, as browser.test.mjs.
import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { spawn } from "node:child_process";
import { existsSync, mkdtempSync, readdirSync, rmSync, unlinkSync } from "node:fs";
import { homedir, tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";
import { REPO, frameError, freePort, nativeFrame, nerfRender } from "./common.mjs";

const DIST = resolve(import.meta.dirname, "../dist");
const BUNDLE = join(REPO, "models/lego-ngp");
const PYTHON = process.env.NERF_PYTHON ?? join(process.env.NERF_HOME ?? join(homedir(), ".cache/nerf-rs"), "venv/bin/python");

let browser, tmp, site, server, url;
before(async () => {
  assert.ok(existsSync(join(DIST, "index.html")), "run `npm run build` first");
  tmp = mkdtempSync(join(tmpdir(), "nerf-site-"));
  site = join(tmp, "site");
  nerfRender(["--bundle", BUNDLE, "--export-site", site, "--viewer", DIST]);
  const port = await freePort();
  server = spawn(PYTHON, ["-m", "http.server", String(port), "--bind", "127.0.0.1", "--directory", site], { stdio: "ignore" });
  url = `http://127.0.0.1:${port}/`;
  for (let i = 0; ; i++) {
    try { if ((await fetch(url)).ok) break; } catch { /* not up yet */ }
    if (i > 300 || server.exitCode !== null) throw new Error(`${PYTHON} -m http.server did not come up`);
    await new Promise((ok) => setTimeout(ok, 100));
  }
  browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", args: ["--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"] });
});
after(async () => {
  await browser?.close();
  server?.kill();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

/** Wait for the page's data-state across its reload (a reload destroys the context waited in). */
async function settled(page) {
  const end = Date.now() + 300_000;
  for (;;) {
    try { return await page.waitForFunction(() => document.body?.dataset.state, null, { timeout: Math.max(1, end - Date.now()) }); }
    catch (e) { if (!/context was destroyed|navigat/i.test(e.message) || Date.now() > end) throw e; }
  }
}

/** Open `query` on the site in `page`; the page's result and how many times its document loaded. */
async function open(page, query) {
  let loads = 0;
  page.on("framenavigated", (frame) => { if (frame === page.mainFrame()) loads++; });
  await page.goto(url + query);
  await settled(page);
  const r = await page.evaluate(() => ({
    state: document.body.dataset.state, error: document.getElementById("error")?.textContent,
    stats: window.nerfStats, line: document.getElementById("stats").textContent, isolated: crossOriginIsolated,
    note: document.getElementById("isolation").hidden ? null : document.getElementById("isolation").textContent,
    frame: window.nerfFrame && Array.from(window.nerfFrame),
  }));
  assert.equal(r.state, "done", `page error: ${r.error}`);
  return { ...r, loads };
}

test("the exported folder holds the viewer, its service worker and the bundle's files", () => {
  const top = readdirSync(site).sort();
  for (const name of ["index.html", "isolation-sw.js", "assets", "ort", "bundle"]) assert.ok(top.includes(name), `${name} in ${top}`);
  assert.deepEqual(readdirSync(join(site, "bundle")).sort(), ["field.onnx", "occupancy.bin", "scene.json"]);
});

test("python -m http.server: the service worker isolates the page, which renders test pose 0 as nerf-render does", { timeout: 600_000 }, async (t) => {
  const native = nativeFrame(BUNDLE, 400);
  const [h, w] = native.shape;
  const context = await browser.newContext();
  try {
    const first = await open(await context.newPage(), `?pose=test:0&width=${w}&height=${h}`);
    assert.equal(first.loads, 2, "one reload under the service worker");
    assert.equal(first.isolated, true);
    assert.equal(first.note, null, "no single-thread note");
    assert.ok(first.stats.threads > 1, `threads ${first.stats.threads}`);
    assert.match(first.line, /wasm, \d+ threads/);
    // The hash grid is encoded in the page, by the worker and its helpers.
    assert.match(first.line, /hash grid here, [2-9]\d* threads/);
    const { maxDiff, psnr } = frameError(first.frame, native);
    t.diagnostic(`lego-ngp ${w}×${h} from http.server: max |Δrgb| ${maxDiff.toExponential(2)}, PSNR ${psnr.toFixed(1)} dB, ` +
      `${first.stats.ms.toFixed(0)} ms on ${first.stats.threads} threads`);
    assert.ok(maxDiff <= 1e-3, `max |Δrgb| ${maxDiff} > 1e-3`);
    assert.ok(psnr >= 40, `PSNR ${psnr} < 40 dB`);

    // A later visit of the same browser is isolated from its first load.
    const again = await open(await context.newPage(), "?pose=test:0&width=40&height=40");
    assert.equal(again.loads, 1, "no reload once the worker is installed");
    assert.equal(again.isolated, true);
  } finally { await context.close(); }

  // Without the worker: one thread, and the page says so on the stats line and the note.
  const single = await open(await browser.newPage(), `?pose=test:0&width=${w}&height=${h}&sw=0`);
  assert.equal(single.isolated, false);
  assert.equal(single.stats.threads, 1);
  assert.match(single.line, /wasm, 1 thread .*one thread: not isolated, service worker off \(\?sw=0\)/);
  assert.match(single.note, /one thread/);
  assert.ok(frameError(single.frame, native).psnr >= 40);
  t.diagnostic(`lego-ngp ${w}×${h} on one thread (?sw=0): ${single.stats.ms.toFixed(0)} ms`);
});

test("a hash-grid helper that cannot start: the worker encodes alone, the same frame", { timeout: 600_000 }, async (t) => {
  // Last in this file: it removes the helper's script from the exported site.
  const helper = readdirSync(join(site, "assets")).filter((f) => /^encoder-worker.*\.js$/.test(f));
  assert.equal(helper.length, 1, `one helper script in ${readdirSync(join(site, "assets"))}`);
  unlinkSync(join(site, "assets", helper[0]));
  const native = nativeFrame(BUNDLE, 100);
  const [h, w] = native.shape;
  const context = await browser.newContext();
  try {
    const page = await context.newPage();
    const warnings = [];
    page.on("console", (m) => { if (m.type() === "warning") warnings.push(m.text()); });
    const r = await open(page, `?pose=test:0&width=${w}&height=${h}`);
    const { maxDiff, psnr } = frameError(r.frame, native);
    t.diagnostic(`without the helper: max |Δrgb| ${maxDiff.toExponential(2)}, PSNR ${psnr.toFixed(1)} dB; ${warnings.join(" | ")}`);
    assert.ok(maxDiff <= 1e-3 && psnr >= 40, `max |Δrgb| ${maxDiff}, PSNR ${psnr}`);
    assert.ok(warnings.some((w) => /hash-grid helper.*one thread/.test(w)), `warnings: ${warnings}`);
  } finally { await context.close(); }
});
