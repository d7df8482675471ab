// The render worker: loads a bundle into onnxruntime-web and renders frames off the page's
// thread. It picks the execution provider (WebGPU where the browser offers a GPU adapter and
// the graphs can run there, WASM otherwise) and says why. Sessions and the grid live here;
// frames go back as transferred arrays.

import type * as OrtModule from "onnxruntime-web/wasm";
import { cameraRays, ndcRays, outputSize, pinhole, resized } from "./camera";
import { type GraphInfo, checkGridContraction, checkScene, graphFiles, graphInfo, isBounded, isContracted, parseGrid, wholeBox } from "./bundle";
import type { Grid } from "./march";
import { MAX_POINTS } from "./marcher";
import { type Field, type MarchTiming, renderDense, renderMarch } from "./render";
import type { FromWorker, Intrinsics, Provider, ToWorker } from "./protocol";
import { type Adapter, pickProvider } from "./provider";
import { FEATURES_TENSOR, SH4_DIM, SH_TENSOR, type SplitGraph, splitHashGrid } from "./hashgrid";
import { ParallelEncoder } from "./encoder";

type Ort = typeof OrtModule;
interface Loaded { scene: any; coarse: Field; fine: Field | null; grid: Grid | null; release: (() => void)[] }
let bundle: Loaded | null = null;
let latest = 0; // the newest render request: older ones are cancelled
// Renders run one after another: a new request waits for the previous one to stop.
let queue: Promise<void> = Promise.resolve();
let fieldMs = 0; // time spent evaluating the field (onnxruntime, and the hash grid where it runs here), for the stats
let encodeMs = 0; // of fieldMs, the hash grid evaluated here

const post = (m: FromWorker, transfer: Transferable[] = []) => (self as unknown as Worker).postMessage(m, transfer);

async function fetchOk(url: string): Promise<ArrayBuffer> {
  const res = await fetch(url);
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status} ${res.statusText}`);
  return res.arrayBuffer();
}

/** A field backed by one session, split into calls of at most MAX_POINTS points; with an
 *  encoder, the session holds the graph's head and the hash grid is evaluated here first. */
function sessionField(ort: Ort, session: OrtModule.InferenceSession, encoder: ParallelEncoder | null): Field & { release(): void } {
  const feeds = async (points: Float32Array, viewdirs: Float32Array, m: number): Promise<Record<string, OrtModule.Tensor>> => {
    if (!encoder) return { points: new ort.Tensor("float32", points, [m, 3]), viewdirs: new ort.Tensor("float32", viewdirs, [m, 3]) };
    const t0 = performance.now();
    const { features, sh } = await encoder.encode(points, viewdirs, m);
    encodeMs += performance.now() - t0;
    // onnxruntime-web copies its inputs into its own memory: the encoder's buffers can be reused.
    return { [FEATURES_TENSOR]: new ort.Tensor("float32", features, [m, encoder.width]), [SH_TENSOR]: new ort.Tensor("float32", sh, [m, SH4_DIM]) };
  };
  const run = async (points: Float32Array, viewdirs: Float32Array, m: number) => {
    const t0 = performance.now();
    const out = await session.run(await feeds(points, viewdirs, m));
    const rgb = out.rgb.data as Float32Array, sigma = out.sigma.data as Float32Array;
    fieldMs += performance.now() - t0;
    return { rgb, sigma };
  };
  const field: Field = async (points, viewdirs, n) => {
    // One call (the renderers never ask for more): onnxruntime's own output arrays, no copy.
    if (n <= MAX_POINTS) return run(points.subarray(0, 3 * n), viewdirs.subarray(0, 3 * n), n);
    const rgb = new Float32Array(3 * n), sigma = new Float32Array(n);
    for (let s = 0; s < n; s += MAX_POINTS) {
      const m = Math.min(MAX_POINTS, n - s);
      const out = await run(points.subarray(3 * s, 3 * (s + m)), viewdirs.subarray(3 * s, 3 * (s + m)), m);
      rgb.set(out.rgb, 3 * s); sigma.set(out.sigma, s);
    }
    return { rgb, sigma };
  };
  const release = () => { session.release().catch(() => {}); encoder?.release(); };
  return Object.assign(field, { release });
}

/** The provider (see provider.ts); `want` = "wasm" (?ep=wasm) skips WebGPU. */
async function chooseProvider(graphs: { name: string; info: GraphInfo }[], want: string): Promise<{ provider: Provider; reason: string }> {
  if (want === "wasm") return { provider: "wasm", reason: "asked for (?ep=wasm)" };
  const gpu = (navigator as any).gpu;
  if (!gpu) return pickProvider(null, graphs, true);
  let adapter: Adapter | null = null;
  try { adapter = await gpu.requestAdapter(); } catch { /* as no adapter */ }
  return pickProvider(adapter, graphs);
}

/** onnxruntime-web's WASM build, or its WebGPU build (which also holds the WASM kernels). */
async function loadOrt(provider: Provider, ortUrl: string, isolated: boolean): Promise<Ort> {
  const ort: Ort = provider === "webgpu" ? await import("onnxruntime-web/webgpu") : await import("onnxruntime-web/wasm");
  // Set once: a later bundle (a live snapshot) finds the runtime already started with them.
  if (!ort.env.wasm.wasmPaths) {
    // Threads need SharedArrayBuffer, which needs cross-origin isolation (COOP + COEP).
    ort.env.wasm.numThreads = isolated ? navigator.hardwareConcurrency || 1 : 1;
    ort.env.wasm.wasmPaths = ortUrl; // served locally from the build, never a CDN
  }
  return ort;
}

async function load(bundleUrl: string, ortUrl: string, dense: boolean, ep: string, wholeGraph: boolean): Promise<void> {
  const isolated = (self as any).crossOriginIsolated === true;
  const sceneUrl = new URL("scene.json", bundleUrl).href;
  let scene: any;
  try { scene = JSON.parse(new TextDecoder().decode(await fetchOk(sceneUrl))); }
  catch (e) { throw new Error(`${sceneUrl}: ${(e as Error).message}`); }
  checkScene(scene);
  const files = graphFiles(scene);
  // One graph for the whole field serves both stages.
  const names = [files.field ?? files.coarse, ...(files.fine ? [files.fine] : [])];
  const graphs = await Promise.all(names.map(async (name) => {
    const url = new URL(name, bundleUrl).href, bytes = new Uint8Array(await fetchOk(url));
    return { name, url, bytes, info: graphInfo(bytes, url) };
  }));
  let { provider, reason } = await chooseProvider(graphs, ep);
  // On WASM a hash-grid graph's encoding runs here and onnxruntime-web runs the graph's head, as
  // nerf-render does (?encoding=graph: the whole graph); WebGPU runs the whole graph.
  let encoding = "";
  const open = async (ort: Ort, g: (typeof graphs)[number], p: Provider) => {
    const split = p === "wasm" && !wholeGraph ? splitHashGrid(g.bytes, g.url) : null;
    // Helpers on the other cores where memory can be shared (onnxruntime's threads need the same).
    const encoder = split && "encoder" in split ? new ParallelEncoder(split.encoder, isolated ? Math.max(0, (navigator.hardwareConcurrency || 1) - 1) : 0, MAX_POINTS) : null;
    if (split) encoding = encoder ? `hash grid here, ${encoder.threads} thread${encoder.threads > 1 ? "s" : ""}` : `whole graph: ${(split as { reason: string }).reason}`;
    else if (wholeGraph && p === "wasm") encoding = "whole graph (asked for)";
    try { return sessionField(ort, await ort.InferenceSession.create(encoder ? (split as SplitGraph).head : g.bytes, { executionProviders: [p] }), encoder); }
    catch (e) { encoder?.release(); throw new Error(`${g.url}: ${(e as Error).message}`); }
  };
  let ort = await loadOrt(provider, ortUrl, isolated);
  let fields: ReturnType<typeof sessionField>[];
  try { fields = await Promise.all(graphs.map((g) => open(ort, g, provider))); }
  catch (e) {
    if (provider !== "webgpu") throw e;
    // A GPU that will not take the graph: render on the CPU and say why.
    reason = `WebGPU failed: ${(e as Error).message}`;
    provider = "wasm";
    ort = await loadOrt(provider, ortUrl, isolated);
    fields = await Promise.all(graphs.map((g) => open(ort, g, provider)));
  }
  let grid: Grid | null = null;
  if (scene.occupancy && !dense) {
    grid = parseGrid(await fetchOk(new URL(scene.occupancy.file, bundleUrl).href));
    checkGridContraction(scene, grid);
  } else if (isBounded(scene)) grid = wholeBox(scene.occupancy.bound, isContracted(scene));

  // Another bundle replaces this one (a live snapshot): its sessions are freed once no render uses
  // them (loads wait in the render queue).
  const old = bundle;
  bundle = { scene, coarse: fields[0], fine: fields[1] ?? null, grid, release: fields.map((f) => f.release) };
  for (const release of old?.release ?? []) release();
  post({ type: "loaded", scene, threads: ort.env.wasm.numThreads as number, backend: provider, reason, isolated, marched: grid !== null, encoding });
}

async function render(id: number, width: number, height: number, c2w: number[][], intrinsics?: Intrinsics): Promise<void> {
  if (!bundle) throw new Error("no bundle loaded");
  const { scene, coarse, fine, grid } = bundle;
  const cancelled = () => latest !== id;
  if (cancelled()) { post({ type: "cancelled", id }); return; }
  const start = performance.now();
  fieldMs = 0;
  encodeMs = 0;
  const base = pinhole(scene.camera);
  const [w, h] = intrinsics ? [width, height] : outputSize(base, width, height);
  const cam = intrinsics ? { ...base, width, height, ...intrinsics, distortion: null } : resized(base, w, h);
  const rays = cameraRays(cam, c2w);
  let { o, d } = rays;
  const view = d; // viewdirs stay the world direction, also under NDC
  if (scene.sampling.ndc) ({ o, d } = ndcRays(scene.sampling.ndc, o, d));
  const raysMs = performance.now() - start;
  const timing: MarchTiming = { marchMs: 0, compositeMs: 0 };
  const frame = grid
    ? await renderMarch(scene.sampling, scene.march_steps ?? 256, !!scene.white_background, grid, fine ?? coarse, o, d, view, cancelled, undefined, undefined, undefined, timing)
    : await renderDense(scene.sampling, !!scene.white_background, coarse, fine, o, d, view, cancelled);
  if (!frame) { post({ type: "cancelled", id }); return; }
  const ms = performance.now() - start;
  post({ type: "frame", id, width: w, height: h, rgb: frame.rgb, depth: frame.depth, acc: frame.acc, points: frame.points, ms, fieldMs, encodeMs,
    raysMs, marchMs: timing.marchMs, compositeMs: timing.compositeMs }, [frame.rgb.buffer, frame.depth.buffer, frame.acc.buffer]);
}

self.onmessage = (ev: MessageEvent<ToWorker>) => {
  const m = ev.data;
  if (m.type === "load") {
    // After the render in progress, which stops early (cancelled): it holds the current sessions.
    latest = -1;
    queue = queue.then(() => load(m.bundleUrl, m.ortUrl, m.dense, m.ep, m.wholeGraph)).catch((e) => post({ type: "error", message: String((e as Error).message ?? e) }));
  } else if (m.type === "render") {
    latest = m.id;
    queue = queue.then(() => render(m.id, m.width, m.height, m.c2w, m.intrinsics))
      .catch((e) => post({ type: "error", id: m.id, message: String((e as Error).message ?? e) }));
  } else if (m.type === "cancel") {
    if (latest === m.id) latest = -1;
  }
};
