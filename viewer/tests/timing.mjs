// Time to the first preview and to the full frame in the browser, against nerf-render on the
// same view, one bundle after the other in one run:
//   node tests/timing.mjs [--viewer DIR ...] [--webgpu] [--no-native] [bundle ...]
// (default bundles: models/lego models/lego-ngp, paths from the repository root; default viewer:
// viewer/dist; several --viewer DIRs, e.g. a build before and after a change, run back to back
// on each bundle; --webgpu: chromium with --enable-unsafe-webgpu, its software adapter;
// SCREENSHOTS=DIR also saves a screenshot of each page there).
// The page is the interactive viewer (`/`, the bundle's first test pose at its training size up
// to 400 wide), served by `nerf-render --serve`, in headless chromium; times are from the start
// of the page load. The full pass is split into the time inside onnxruntime-web ("field") and
// the rest ("loop": rays, marching, packing, compositing). Native: `nerf-render --split test
// --limit 1` of the same pose and size, default and --whole-graph, its own per-frame time. Then
// the same pose alone, six times on one page (?pose=test:0&repeat=6): the frame once warm.
import { execFileSync, spawn } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";

const REPO = resolve(import.meta.dirname, "../..");
const env = (cmd) => execFileSync("bash", ["-c", `. scripts/env.sh && ${cmd}`], { cwd: REPO, encoding: "utf8" });
const bin = process.env.NERF_RENDER ?? env('echo "$CARGO_TARGET_DIR/release/nerf-render"').trim();
const args = process.argv.slice(2), viewers = [], bundles = [];
let webgpu = false, nativeToo = true;
for (let i = 0; i < args.length; i++) {
  if (args[i] === "--viewer") viewers.push(resolve(args[++i]));
  else if (args[i] === "--webgpu") webgpu = true;
  else if (args[i] === "--no-native") nativeToo = false;
  else bundles.push(args[i]);
}
if (!viewers.length) viewers.push(join(REPO, "viewer/dist"));
if (!bundles.length) bundles.push("models/lego", "models/lego-ngp");
const flags = ["--no-sandbox", "--disable-dev-shm-usage", ...(webgpu ? ["--enable-unsafe-webgpu"] : ["--disable-gpu"])];
const browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", args: flags });
const s = (ms) => (ms / 1000).toFixed(2);

/** nerf-render's own per-frame time ("… (9.12 s per frame …"), session creation excluded. */
function native(dir, width, extra) {
  const out = mkdtempSync(join(tmpdir(), "nerf-timing-"));
  try {
    const log = execFileSync(bin, ["--bundle", dir, "--split", "test", "--limit", "1", "--width", String(width), "--out", out, ...extra],
      { env: { ...process.env, ORT_DYLIB_PATH: env('echo "$ORT_DYLIB_PATH"').trim() }, encoding: "utf8", stdio: ["ignore", "pipe", "pipe"] });
    return Number(log.match(/\(([\d.]+) s per frame/)[1]);
  } finally { rmSync(out, { recursive: true, force: true }); }
}

for (const bundle of bundles) {
  const dir = resolve(REPO, bundle);
  const scene = JSON.parse(readFileSync(join(dir, "scene.json"), "utf8"));
  const width = Math.min(scene.camera.width, 400);
  for (const viewer of viewers) {
    const server = spawn(bin, ["--bundle", dir, "--serve", "--port", "0", "--viewer", viewer], { stdio: ["ignore", "pipe", "inherit"] });
    const url = await new Promise((ok) => server.stdout.once("data", (d) => ok(String(d).match(/http:\S+/)[0])));
    const page = await browser.newPage();
    await page.goto(`${url}?width=${width}`);
    await page.waitForFunction(() => (document.body.dataset.state === "done" && window.nerfTimeline?.length >= 4) || document.body.dataset.state === "error", null, { timeout: 600_000 });
    const error = await page.evaluate(() => document.body.dataset.state === "error" && document.getElementById("error").textContent);
    if (error) throw new Error(`${bundle} (${viewer}): ${error}`);
    const timeline = await page.evaluate(() => window.nerfTimeline);
    const stats = await page.evaluate(() => window.nerfStats);
    const line = await page.evaluate(() => document.getElementById("stats").textContent);
    // SCREENSHOTS=DIR: the viewer as it looks, for the docs.
    if (process.env.SCREENSHOTS) await page.screenshot({ path: join(process.env.SCREENSHOTS, `viewer-${bundle.split("/").pop()}.png`) });
    await page.close();
    // The same frame six times on its own page (?pose=test:0&repeat=6): once the code is warm,
    // as the Rust loop (replayed) and the Python package (first frame left out) are timed.
    const again = await browser.newPage();
    await again.goto(`${url}?pose=test:0&width=${width}&repeat=6`);
    await again.waitForFunction(() => document.body.dataset.state === "done" || document.body.dataset.state === "error", null, { timeout: 600_000 });
    const runs = await again.evaluate(() => window.nerfStatsRuns ?? []);
    await again.close();
    server.kill();
    const first = timeline[0], full = timeline[timeline.length - 1];
    console.log(`${bundle} [${viewer}]: first preview ${first.width}×${first.height} at ${s(first.at)} s, full ${full.width}×${full.height} at ${s(full.at)} s; ` +
      `that pass ${s(stats.ms)} s = field ${s(stats.fieldMs)} s + loop ${s(stats.ms - stats.fieldMs)} s` +
      (stats.marchMs !== undefined ? ` (rays ${s(stats.raysMs)}, march ${s(stats.marchMs)}, compositing ${s(stats.compositeMs)})` : "") +
      ` (${stats.threads} threads, ${stats.backend})\n  stats line: ${line}\n  test pose 0 six times: ` +
      runs.map((r) => `${s(r.ms)} s = field ${s(r.fieldMs)} s (hash grid ${s(r.encodeMs ?? 0)} s) + loop ${s(r.ms - r.fieldMs)} s (rays ${s(r.raysMs)}, march ${s(r.marchMs)}, compositing ${s(r.compositeMs)})`).join("; "));
  }
  if (!nativeToo) continue;
  const fast = native(dir, width, []), whole = native(dir, width, ["--whole-graph"]);
  console.log(`${bundle}: nerf-render ${fast.toFixed(2)} s per frame, --whole-graph ${whole.toFixed(2)} s (same view)`);
}
await browser.close();
