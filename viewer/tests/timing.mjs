// Time to the first preview and to the full frame in the browser, against nerf-render on the
// same view, one bundle after the other in one run:
//   node tests/timing.mjs [bundle ...]   (default: models/lego models/lego-ngp; paths from the
//   repository root; SCREENSHOTS=DIR also saves a screenshot of each page there)
// The page is the interactive viewer (`/`, the bundle's first test pose at its training size up
// to 400 wide), served by `nerf-render --serve`, in headless chromium; times are from the start
// of the page load. Native: `nerf-render --split test --limit 1` of the same pose and size.
import { execFileSync, spawn } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";

const REPO = resolve(import.meta.dirname, "../..");
const env = (cmd) => execFileSync("bash", ["-c", `. scripts/env.sh && ${cmd}`], { cwd: REPO, encoding: "utf8" });
const bin = env('echo "$CARGO_TARGET_DIR/release/nerf-render"').trim();
const bundles = process.argv.slice(2).length ? process.argv.slice(2) : ["models/lego", "models/lego-ngp"];
const browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", args: ["--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"] });
for (const bundle of bundles) {
  const dir = resolve(REPO, bundle);
  const scene = JSON.parse(readFileSync(join(dir, "scene.json"), "utf8"));
  const width = Math.min(scene.camera.width, 400);
  const server = spawn(bin, ["--bundle", dir, "--serve", "--port", "0", "--viewer", join(REPO, "viewer/dist")], { stdio: ["ignore", "pipe", "inherit"] });
  const url = await new Promise((ok) => server.stdout.once("data", (d) => ok(String(d).match(/http:\S+/)[0])));
  const page = await browser.newPage();
  await page.goto(`${url}?width=${width}`);
  await page.waitForFunction(() => document.body.dataset.state === "done" && window.nerfTimeline?.length >= 4, null, { timeout: 600_000 });
  const timeline = await page.evaluate(() => window.nerfTimeline);
  const stats = await page.evaluate(() => window.nerfStats);
  // SCREENSHOTS=DIR: the viewer as it looks, for the docs.
  if (process.env.SCREENSHOTS) await page.screenshot({ path: join(process.env.SCREENSHOTS, `viewer-${bundle.split("/").pop()}.png`) });
  await page.close();
  server.kill();
  const out = mkdtempSync(join(tmpdir(), "nerf-timing-"));
  const t = Date.now();
  execFileSync(bin, ["--bundle", dir, "--split", "test", "--limit", "1", "--width", String(width), "--out", out], { env: { ...process.env, ORT_DYLIB_PATH: env('echo "$ORT_DYLIB_PATH"').trim() } });
  const native = (Date.now() - t) / 1000;
  rmSync(out, { recursive: true, force: true });
  const first = timeline[0], full = timeline[timeline.length - 1];
  console.log(`${bundle}: browser first preview ${first.width}×${first.height} at ${(first.at / 1000).toFixed(2)} s, full ${full.width}×${full.height} at ${(full.at / 1000).toFixed(2)} s (that pass ${(stats.ms / 1000).toFixed(2)} s, ${stats.threads} threads); nerf-render ${native.toFixed(2)} s for the same view, process start included`);
}
await browser.close();
