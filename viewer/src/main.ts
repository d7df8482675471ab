// The page: starts the render worker, loads bundle/ (relative to the page), and either renders
// one test pose at full quality (the test hook, ?pose=test:K&width=W&height=H) or runs the
// interactive viewer (orbit/pan/zoom, progressive refinement).

import type { FromWorker, FrameMsg, Loaded, ToWorker } from "./protocol";
import { type Orbit, orbitFromPose, orbitPose, toBytes } from "./view";
import { isolate } from "./isolation";
import { type Fly, captureRegion, captureUp, flyFromPose, flyPose, look, moveBy } from "./fly";
import type { Intrinsics } from "./protocol";
import { pathPanel } from "./pathpanel";
import { LIVE_POINTS, LIVE_WIDTH, probeLive, startLive } from "./live";

declare global {
  interface Window { nerfStats?: Record<string, unknown>; nerfStatsRuns?: Record<string, unknown>[]; nerfFrame?: Float32Array; nerfTimeline?: { width: number; height: number; at: number }[];
    /** The interactive view's navigation and the c2w of its latest render request (for tests). */
    nerfCamera?: { nav: "fly" | "orbit"; c2w: number[][] } }
}

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
const canvas = $<HTMLCanvasElement>("view");
const params = new URLSearchParams(location.search);

function fail(message: string): void {
  const el = $("error");
  el.textContent = message;
  el.hidden = false;
  document.body.dataset.state = "error";
}

let worker: Worker; // started once the page knows it will not reload for isolation
const send = (m: ToWorker) => worker.postMessage(m);
let onLoaded: (m: Loaded) => void = () => {};
let onFrame: (m: FrameMsg) => void = () => {};
/** Live training (live.ts): told when a snapshot loads or fails to. */
let live: ReturnType<typeof startLive> | null = null;
/** Why onnxruntime runs on one thread (not cross-origin isolated), for the stats line. */
let singleThreadWhy: string | null = null;

function startWorker(): void {
  worker = new Worker(new URL("./worker.ts", import.meta.url), { type: "module" });
  worker.onmessage = (ev: MessageEvent<FromWorker>) => {
    const m = ev.data;
    if ("id" in m && m.id !== undefined && pathRenders.has(m.id)) { pathSettle(m); return; }
    if (m.type === "loaded") onLoaded(m);
    else if (m.type === "frame") onFrame(m);
    else if (m.type === "error" && live && m.id === undefined) live.failed(m.message); // a snapshot that did not load
    else if (m.type === "error") fail(m.message);
  };
  worker.onerror = (ev) => fail(`worker: ${ev.message || "failed to start"}`);
}

// The camera-path panel's renders (pathpanel.ts): ids of their own, answered by promise.
const pathRenders = new Map<number, { ok: (m: FrameMsg) => void; no: (e: Error) => void }>();
let pathId = 1 << 30; // far past the interactive view's ids
function pathRender(width: number, height: number, c2w: number[][], intrinsics: Intrinsics): Promise<FrameMsg> {
  const id = pathId++;
  return new Promise((ok, no) => { pathRenders.set(id, { ok, no }); send({ type: "render", id, width, height, c2w, intrinsics }); });
}
function pathSettle(m: FromWorker & { id?: number }): void {
  const p = pathRenders.get(m.id!)!;
  pathRenders.delete(m.id!);
  if (m.type === "frame") p.ok(m);
  else p.no(new Error(m.type === "error" ? m.message : "cancelled"));
}

/** Draws rgb (or a depth map) 1:1 into the canvas, resizing it to the frame. */
function draw(m: FrameMsg, depthView: boolean, near: number, far: number): void {
  canvas.width = m.width; canvas.height = m.height;
  const ctx = canvas.getContext("2d")!;
  ctx.putImageData(new ImageData(toBytes(m, depthView, near, far), m.width, m.height), 0, 0);
}

function statsOf(m: FrameMsg, loaded: Loaded) {
  return { width: m.width, height: m.height, ms: m.ms, fieldMs: m.fieldMs, encodeMs: m.encodeMs, loopMs: m.ms - m.fieldMs,
    raysMs: m.raysMs, marchMs: m.marchMs, compositeMs: m.compositeMs, points: m.points, pointsPerSecond: m.points / (m.ms / 1000),
    threads: loaded.threads, backend: loaded.backend, reason: loaded.reason, encoding: loaded.encoding };
}

const sec = (ms: number) => `${(ms / 1000).toFixed(2)} s`;

/** "400×400 in 4.80 s: field 4.52 s (hash grid 1.90 s) · loop 0.28 s (march 0.20 s) · 2.82 M points · … · wasm, 2 threads
 *  (no GPU adapter) · hash grid here". */
function statsLine(s: ReturnType<typeof statsOf>, loaded: Loaded): string {
  const threads = s.backend === "wasm" ? `, ${s.threads} thread${s.threads > 1 ? "s" : ""}` : "";
  return `${s.width}×${s.height} in ${sec(s.ms)}: field ${sec(s.fieldMs)}` + (s.encodeMs > 0 ? ` (hash grid ${sec(s.encodeMs)})` : "") +
    ` · loop ${sec(s.loopMs)}` +
    (loaded.marched ? ` (march ${sec(s.marchMs)})` : "") + ` · ${(s.points / 1e6).toFixed(2)} M points · ` +
    `${(s.pointsPerSecond / 1e6).toFixed(2)} M points/s · ${s.backend}${threads} (${s.reason})` +
    (loaded.marched ? " · marched" : " · coarse+fine") + (s.encoding ? ` · ${s.encoding}` : "") +
    (s.backend === "wasm" && !loaded.isolated && singleThreadWhy ? ` · one thread: not isolated, ${singleThreadWhy}` : "");
}

/** ?pose=test:K: one full-quality frame (&repeat=N: N of them, one after the other, e.g. to time
 *  a frame once the code is warm), then data-state="done" for a test to read window.nerfFrame;
 *  window.nerfStatsRuns holds every frame's stats. */
function testHook(loaded: Loaded, spec: string): void {
  const k = Number(spec.slice("test:".length));
  const poses = loaded.scene.poses?.test ?? [];
  if (!Number.isInteger(k) || k < 0 || k >= poses.length) { fail(`pose ${spec}: the bundle has ${poses.length} test poses`); return; }
  const width = Number(params.get("width") ?? 0), height = Number(params.get("height") ?? 0);
  const repeat = Math.max(1, Math.floor(Number(params.get("repeat") ?? 1)) || 1);
  const render = (id: number) => send({ type: "render", id, width, height, c2w: poses[k].transform_matrix });
  onFrame = (m) => {
    draw(m, false, 0, 1);
    window.nerfFrame = m.rgb;
    window.nerfStats = statsOf(m, loaded);
    (window.nerfStatsRuns ??= []).push(window.nerfStats);
    $("stats").textContent = statsLine(window.nerfStats as any, loaded);
    if (m.id < repeat) render(m.id + 1);
    else document.body.dataset.state = "done";
  };
  render(1);
}

/** The interactive viewer (orbit, or for a forward-facing NDC capture a fly camera bounded to
 *  the region its poses saw: fly.ts): each camera move starts 1/8 → 1/4 → 1/2 → full, cancelling older work;
 *  a pass is refined only while the next would take at most `maxPoints` field samples (live.ts).
 *  Returns what renders the current view again (a live snapshot loaded: same camera, new field)
 *  and what lifts the live limits (training ended: the usual size, refined to the full pass). */
function interactive(loaded: Loaded, maxWidth = 400, maxPoints = Infinity): { rerender(): void; unlimit(): void } {
  document.body.classList.add("interactive");
  const scene = loaded.scene, cam = scene.camera, s = scene.sampling;
  const tests: { name?: string; transform_matrix: number[][] }[] = scene.poses?.test ?? [];
  const orbits: number[][][] = scene.poses?.orbit ?? [];
  const select = $<HTMLSelectElement>("pose");
  const choices = tests.length ? tests.map((p, i) => ({ label: p.name ?? `test ${i}`, m: p.transform_matrix }))
    : orbits.map((m, i) => ({ label: `orbit ${i}`, m }));
  for (const [i, c] of choices.entries()) select.add(new Option(c.label, String(i)));
  const sized = (most: number) => Number(params.get("width") ?? 0) || Math.min(cam.width, most);
  let width = sized(maxWidth);
  let height = Math.round((width * cam.height) / cam.width);
  // 360° captures orbit about their own up vector (z for the Blender scenes).
  const upAxis = choices.length ? captureUp(choices.map((c) => c.m)) : [0, 0, 1];
  let orbit: Orbit = orbitFromPose(choices[0]?.m ?? orbits[0], s.near, upAxis);
  const region = s.ndc && choices.length ? captureRegion(choices.map((c) => c.m)) : null;
  let fly: Fly | null = region ? flyFromPose(choices[0].m) : null;
  let exact: number[][] | null = choices[0]?.m ?? null; // a chosen pose renders exactly, until moved
  let depthView = false, last: FrameMsg | null = null, next = 1;
  const levels = [8, 4, 2, 1];
  const pending = new Map<number, number>(); // request id → level index
  let current = 0;
  let reached = 0; // the level of the frame shown

  const view = () => exact ?? (region && fly ? flyPose(fly, region.up) : orbitPose(orbit));
  const request = (level: number) => {
    const id = next++;
    current = id;
    pending.set(id, level);
    const f = levels[level];
    const c2w = view();
    window.nerfCamera = { nav: region ? "fly" : "orbit", c2w };
    send({ type: "render", id, width: Math.max(1, Math.round(width / f)), height: Math.max(1, Math.round(height / f)), c2w });
  };
  const restart = (from = 0) => {
    if (current) send({ type: "cancel", id: current });
    document.body.dataset.state = "rendering";
    request(from);
  };
  onFrame = (m) => {
    const level = pending.get(m.id);
    pending.delete(m.id);
    if (m.id !== current || level === undefined) return; // stale
    last = m;
    reached = level;
    // A pass has about 4× the samples of the one before.
    const finest = level === levels.length - 1 || 4 * m.points > maxPoints;
    draw(m, depthView, s.near, s.far);
    // When each pass was drawn (ms since the page started loading): time to a first preview.
    (window.nerfTimeline ??= []).push({ width: m.width, height: m.height, at: performance.now() });
    canvas.style.aspectRatio = `${width} / ${height}`;
    window.nerfStats = statsOf(m, loaded);
    $("stats").textContent = statsLine(window.nerfStats as any, loaded) +
      (!finest ? " · refining" : level < levels.length - 1 ? ` · stopped here: the next size passes the live view's ${maxPoints / 1e3}k samples` : "");
    if (!finest) request(level + 1);
    document.body.dataset.state = finest ? "done" : "rendering";
  };
  const goTo = (m: number[][]) => {
    exact = m;
    orbit = orbitFromPose(exact, s.near, upAxis);
    if (region) fly = flyFromPose(exact);
    restart();
  };
  const snap = () => goTo(choices[Number(select.value)].m);
  select.onchange = snap;
  $("snap").onclick = snap; // back to the chosen pose in one click, even when it is already chosen
  $("mode").onclick = () => {
    depthView = !depthView;
    $("mode").textContent = depthView ? "rgb" : "depth";
    if (last) draw(last, depthView, s.near, s.far);
  };
  $("shot").onclick = () => canvas.toBlob((b) => {
    if (!b) return;
    const a = document.createElement("a");
    a.href = URL.createObjectURL(b); a.download = `nerf-${Date.now()}.png`; a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  });

  // Pointers: one drags to orbit (shift or right button: pan), two pinch to zoom; the wheel zooms.
  // Flying: a drag looks around, shift/right-drag moves sideways, the wheel or a pinch moves
  // forward, WASD / arrows / Q E move; every step is clamped to the region.
  const pointers = new Map<number, { x: number; y: number }>();
  const move = (fn: () => void) => { fn(); exact = null; restart(); };
  const step = region ? region.size : 0;
  const flyBy = (right: number, upward: number, forward: number) => move(() => { fly = moveBy(fly!, region!, right, upward, forward); });
  if (region) window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLSelectElement || e.target instanceof HTMLInputElement) return;
    const k = 0.05 * step, d = ({ w: [0, 0, k], s: [0, 0, -k], a: [-k, 0, 0], d: [k, 0, 0], q: [0, -k, 0], e: [0, k, 0],
      arrowup: [0, 0, k], arrowdown: [0, 0, -k], arrowleft: [-k, 0, 0], arrowright: [k, 0, 0] } as Record<string, number[]>)[e.key.toLowerCase()];
    if (!d) return;
    e.preventDefault();
    flyBy(d[0], d[1], d[2]);
  });
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => { canvas.setPointerCapture(e.pointerId); pointers.set(e.pointerId, { x: e.clientX, y: e.clientY }); });
  const up = (e: PointerEvent) => pointers.delete(e.pointerId);
  canvas.addEventListener("pointerup", up);
  canvas.addEventListener("pointercancel", up);
  canvas.addEventListener("pointermove", (e) => {
    const p = pointers.get(e.pointerId);
    if (!p) return;
    const dx = e.clientX - p.x, dy = e.clientY - p.y;
    if (pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      const other = a === p ? b : a;
      const before = Math.hypot(p.x - other.x, p.y - other.y), after = Math.hypot(e.clientX - other.x, e.clientY - other.y);
      if (before > 0 && after > 0) {
        if (region) flyBy(0, 0, (after - before) * 0.002 * step);
        else move(() => { orbit.radius *= before / after; });
      }
    } else if (region) {
      if (e.shiftKey || e.buttons === 2) flyBy(-dx * 0.002 * step, dy * 0.002 * step, 0);
      else move(() => { fly = look(fly!, region, -dx * 0.003, -dy * 0.003); });
    } else if (e.shiftKey || e.buttons === 2) {
      move(() => panBy(orbit, dx, dy));
    } else {
      move(() => { orbit.theta -= dx * 0.01; orbit.phi = Math.min(Math.max(orbit.phi - dy * 0.01, 0.05), Math.PI - 0.05); });
    }
    p.x = e.clientX; p.y = e.clientY;
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    if (region) flyBy(0, 0, -e.deltaY * 0.001 * step);
    else move(() => { orbit.radius *= Math.exp(e.deltaY * 0.001); });
  }, { passive: false });
  const panBy = (o: Orbit, dx: number, dy: number) => {
    const m = orbitPose(o), k = (o.radius * 0.002);
    for (let a = 0; a < 3; a++) o.target[a] += (-dx * m[a][0] + dy * m[a][1]) * k;
  };

  // Camera paths (pathpanel.ts): keyframes from this view; a path frame cancels the view's
  // refinement, and a move of the view cancels a playing path in turn.
  pathPanel({ scene, view, goTo, resume: restart,
    render: (w, h, c2w, intrinsics) => { if (current) send({ type: "cancel", id: current }); current = 0; return pathRender(w, h, c2w, intrinsics); },
    show: (m) => { draw(m, false, 0, 1); canvas.style.aspectRatio = `${m.width} / ${m.height}`; } });
  request(0);
  return {
    // A new live snapshot: at the size shown, the old frame staying until then (no previews).
    rerender: () => restart(reached),
    unlimit: () => {
      maxPoints = Infinity;
      width = sized(400);
      height = Math.round((width * cam.height) / cam.width);
      restart(reached);
    },
  };
}

async function start(): Promise<void> {
  const isolation = await isolate(params.get("sw") === "0");
  if (!isolation) return; // reloading under the service worker
  singleThreadWhy = isolation.why;
  startWorker();
  const bundleUrl = new URL(params.get("bundle") ?? "bundle/", document.baseURI).href;
  const ortUrl = new URL("ort/", document.baseURI).href;
  $("isolation").hidden = crossOriginIsolated;
  if (singleThreadWhy) $("isolation").textContent += ` (${singleThreadWhy})`;
  const load = (url: string) => send({ type: "load", bundleUrl: url, ortUrl, dense: params.get("dense") === "1", ep: params.get("ep") ?? "auto",
    wholeGraph: params.get("encoding") === "graph" });
  let view: ReturnType<typeof interactive> | null = null;
  onLoaded = (loaded) => {
    live?.loaded();
    if (view) return view.rerender(); // a newer live snapshot: the user's view again
    const pose = params.get("pose");
    if (pose && pose.startsWith("test:")) testHook(loaded, pose);
    else if (pose) fail(`pose ${pose}: expected test:K`);
    else view = live ? interactive(loaded, LIVE_WIDTH, LIVE_POINTS) : interactive(loaded);
  };
  // Live training: the run's snapshots (live/<id>/) as they come, instead of bundle/; once it
  // has ended, the view is no longer held small for the trainer's sake.
  const status = params.has("bundle") ? null : await probeLive(document.baseURI);
  if (status) live = startLive(document.baseURI, status, { load, finished: () => view?.unlimit() });
  else load(bundleUrl);
}

start().catch((e) => fail(`start: ${(e as Error).message}`));
