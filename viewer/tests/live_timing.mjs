// What watching a run costs, measured (issue 39's Done-when): runs `nerf train` on a dataset for
// a time budget, plainly and/or with --serve (optionally with a headless chromium page attached
// for the whole run), one after the other, and reports the steps each made (progress.json) and,
// with a page, when its first frame of the field was drawn, counted from the command's start.
//   node viewer/tests/live_timing.mjs [--data DIR] [--minutes M] [--runs plain,serve,page] [--viewer DIR] [--keep DIR]
//     [--width W] [--screenshot FILE.png]
// (--width: the live page's ?width=; --screenshot: the page run's page once training has ended
// and the page has drawn its view in full)
// (defaults: ../shared/data/nerf_synthetic/lego, 10 minutes, plain,serve, the viewer built in
// viewer/dist; runs in a temporary folder removed at the end unless --keep). Times nothing
// else: run it on a quiet machine.
import { execFileSync, spawn } from "node:child_process";
import { existsSync, mkdtempSync, readFileSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { chromium } from "playwright-core";
import { freePort } from "./common.mjs";

const REPO = resolve(import.meta.dirname, "../..");
const env = (cmd) => execFileSync("bash", ["-c", `. scripts/env.sh && ${cmd}`], { cwd: REPO, encoding: "utf8" });
const nerf = process.env.NERF ?? env('echo "$CARGO_TARGET_DIR/release/nerf"').trim();
const args = process.argv.slice(2);
const opt = (name, fallback) => { const i = args.indexOf(name); return i >= 0 ? args[i + 1] : fallback; };
const data = resolve(opt("--data", join(REPO, "../shared/data/nerf_synthetic/lego")));
const minutes = Number(opt("--minutes", "10"));
const runs = opt("--runs", "plain,serve").split(",");
const keep = opt("--keep", null);
const viewer = resolve(opt("--viewer", join(REPO, "viewer/dist")));
const width = opt("--width", null), screenshot = opt("--screenshot", null);
const root = keep ? resolve(keep) : mkdtempSync(join(tmpdir(), "nerf-live-timing-"));
const sleep = (ms) => new Promise((ok) => setTimeout(ok, ms));
const progress = (out) => { try { return JSON.parse(readFileSync(join(out, "progress.json"), "utf8")); } catch { return null; } };

/** One run: the steps it made and, with a page, the seconds to its first frame. */
async function run(kind) {
  const out = join(root, kind);
  rmSync(out, { recursive: true, force: true });
  const port = kind === "plain" ? null : await freePort();
  const cmd = ["train", "--data", data, "--out", out, "--time-budget-min", String(minutes)];
  if (port) cmd.push("--serve", "--port", String(port), "--viewer", viewer);
  const start = Date.now();
  const child = spawn(nerf, cmd, { stdio: ["ignore", "ignore", "pipe"], env: { ...process.env, NO_COLOR: "1" } });
  let stderr = "";
  child.stderr.on("data", (d) => { stderr = (stderr + d).slice(-4000); });
  const exited = new Promise((ok) => child.on("exit", ok));
  let browser = null, page = null, firstFrameS = null, frames = 0;
  if (kind === "page") {
    browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", args: ["--no-sandbox"] });
    page = await browser.newPage();
    // The server is up once the port is bound (before the data loads); retry until then.
    for (;;) {
      try { await page.goto(`http://127.0.0.1:${port}/${width ? `?width=${width}` : ""}`); break; } catch { await sleep(200); }
      if (Date.now() - start > 120e3) throw new Error(`no server on port ${port} after 2 minutes: ${stderr}`);
    }
    await page.exposeFunction("nerfTimingFrame", () => { frames++; firstFrameS ??= (Date.now() - start) / 1000; });
    await page.evaluate(() => {
      // Each drawn pass pushes to window.nerfTimeline (main.ts): report the first.
      const seen = () => (window.nerfTimeline?.length ?? 0);
      let n = 0;
      setInterval(() => { const s = seen(); if (s > n) { n = s; window.nerfTimingFrame(); } }, 100);
    });
  }
  // --serve keeps serving after training: stop it once progress.json says done.
  for (;;) {
    const p = progress(out);
    if (p?.done) break;
    if (child.exitCode !== null) break;
    await sleep(1000);
  }
  const seconds = (Date.now() - start) / 1000;
  if (page && screenshot) {
    // Training over, the page renders its view in full (live.ts): the picture once it has.
    await page.waitForFunction(() => document.body.dataset.state === "done" && (window.nerfTimeline?.at(-1)?.width ?? 0) >= 200,
      null, { timeout: 180_000, polling: 500 }).catch(() => {});
    await page.screenshot({ path: resolve(screenshot) });
  }
  if (child.exitCode === null) child.kill("SIGINT");
  const code = await exited;
  const shown = page ? await page.evaluate(() => [document.body.dataset.state, document.getElementById("stats")?.textContent,
    document.getElementById("live")?.textContent, document.getElementById("error")?.textContent].join(" | ")) : "";
  if (browser) await browser.close();
  const p = progress(out);
  if (!p?.done) throw new Error(`${kind}: training did not finish (exit ${code}): ${stderr}`);
  const snapshots = existsSync(join(out, "live")) ? "yes" : "no";
  return { kind, steps: p.step, trainedS: p.elapsed_s, wallS: seconds, firstFrameS, frames, snapshots, shown };
}

const cpu = execFileSync("bash", ["-c", "lscpu | sed -n 's/^Model name: *//p'"], { encoding: "utf8" }).trim();
console.log(`${cpu}, ${data}, ${minutes} min each, load before: ${readFileSync("/proc/loadavg", "utf8").trim()}`);
const results = [];
for (const kind of runs) {
  const r = await run(kind);
  results.push(r);
  console.log(`${kind}: ${r.steps} steps in ${r.trainedS.toFixed(1)} s trained (${r.wallS.toFixed(1)} s wall)` +
    (kind === "page" ? `, first frame of the field in the page ${r.firstFrameS?.toFixed(1) ?? "never"} s after the start, ${r.frames} passes drawn (the page at the end: ${r.shown})` : "") +
    `; load after: ${readFileSync("/proc/loadavg", "utf8").trim()}`);
}
const plain = results.find((r) => r.kind === "plain");
for (const r of results) if (plain && r !== plain) console.log(`${r.kind} / plain steps: ${(100 * r.steps / plain.steps).toFixed(1)}%`);
if (!keep) rmSync(root, { recursive: true, force: true });
