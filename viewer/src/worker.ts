// The render worker: loads a bundle into onnxruntime-web (WASM) and renders frames off the
// page's thread. Sessions and the grid live here; frames go back as transferred arrays.

import * as ort from "onnxruntime-web/wasm";
import { cameraRays, ndcRays, outputSize, pinhole, resized } from "./camera";
import { checkScene, graphFiles, isBounded, parseGrid, wholeBox } from "./bundle";
import { type Field, type Grid, MAX_POINTS, renderDense, renderMarch } from "./render";
import type { FromWorker, ToWorker } from "./protocol";

interface Loaded { scene: any; coarse: Field; fine: Field | null; grid: Grid | null }
let bundle: Loaded | null = null;
let latest = 0; // the newest render request: older ones are cancelled
// Renders run one after another: a new request waits for the previous one to stop.
let queue: Promise<void> = Promise.resolve();
let fieldMs = 0; // time spent inside onnxruntime, for the stats

const post = (m: FromWorker, transfer: Transferable[] = []) => (self as unknown as Worker).postMessage(m, transfer);

async function fetchOk(url: string): Promise<ArrayBuffer> {
  const res = await fetch(url);
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status} ${res.statusText}`);
  return res.arrayBuffer();
}

/** A field backed by one session, split into calls of at most MAX_POINTS points. */
function sessionField(session: ort.InferenceSession): Field {
  return async (points, viewdirs, n) => {
    const rgb = new Float32Array(3 * n), sigma = new Float32Array(n);
    for (let s = 0; s < n; s += MAX_POINTS) {
      const m = Math.min(MAX_POINTS, n - s);
      const t0 = performance.now();
      const out = await session.run({
        points: new ort.Tensor("float32", points.subarray(3 * s, 3 * (s + m)), [m, 3]),
        viewdirs: new ort.Tensor("float32", viewdirs.subarray(3 * s, 3 * (s + m)), [m, 3]),
      });
      rgb.set(out.rgb.data as Float32Array, 3 * s);
      sigma.set(out.sigma.data as Float32Array, s);
      out.rgb.dispose(); out.sigma.dispose();
      fieldMs += performance.now() - t0;
    }
    return { rgb, sigma };
  };
}

async function load(bundleUrl: string, ortUrl: string, dense: boolean): Promise<void> {
  const isolated = (self as any).crossOriginIsolated === true;
  // Threads need SharedArrayBuffer, which needs cross-origin isolation (COOP + COEP).
  ort.env.wasm.numThreads = isolated ? navigator.hardwareConcurrency || 1 : 1;
  ort.env.wasm.wasmPaths = ortUrl; // served locally from the build, never a CDN
  const sceneUrl = new URL("scene.json", bundleUrl).href;
  let scene: any;
  try { scene = JSON.parse(new TextDecoder().decode(await fetchOk(sceneUrl))); }
  catch (e) { throw new Error(`${sceneUrl}: ${(e as Error).message}`); }
  checkScene(scene);
  const files = graphFiles(scene);
  const open = async (name: string) => {
    const url = new URL(name, bundleUrl).href;
    try { return await ort.InferenceSession.create(new Uint8Array(await fetchOk(url)), { executionProviders: ["wasm"] }); }
    catch (e) { throw new Error(`${url}: ${(e as Error).message}`); }
  };
  // One graph for the whole field serves both stages.
  const coarse = sessionField(await open(files.field ?? files.coarse));
  const fine = files.fine ? sessionField(await open(files.fine)) : null;
  let grid: Grid | null = null;
  if (scene.occupancy && !dense) grid = parseGrid(await fetchOk(new URL(scene.occupancy.file, bundleUrl).href));
  else if (isBounded(scene)) grid = wholeBox(scene.occupancy.bound);
  bundle = { scene, coarse, fine, grid };
  post({ type: "loaded", scene, threads: ort.env.wasm.numThreads as number, backend: "wasm", isolated, marched: grid !== null });
}

async function render(id: number, width: number, height: number, c2w: number[][]): Promise<void> {
  if (!bundle) throw new Error("no bundle loaded");
  const { scene, coarse, fine, grid } = bundle;
  const cancelled = () => latest !== id;
  if (cancelled()) { post({ type: "cancelled", id }); return; }
  const start = performance.now();
  fieldMs = 0;
  const base = pinhole(scene.camera);
  const [w, h] = outputSize(base, width, height);
  const cam = resized(base, w, h);
  const rays = cameraRays(cam, c2w);
  let { o, d } = rays;
  const view = d; // viewdirs stay the world direction, also under NDC
  if (scene.sampling.ndc) ({ o, d } = ndcRays(scene.sampling.ndc, o, d));
  const frame = grid
    ? await renderMarch(scene.sampling, scene.march_steps ?? 256, !!scene.white_background, grid, fine ?? coarse, o, d, view, cancelled)
    : await renderDense(scene.sampling, !!scene.white_background, coarse, fine, o, d, view, cancelled);
  if (!frame) { post({ type: "cancelled", id }); return; }
  const ms = performance.now() - start;
  post({ type: "frame", id, width: w, height: h, rgb: frame.rgb, depth: frame.depth, acc: frame.acc, points: frame.points, ms, fieldMs },
    [frame.rgb.buffer, frame.depth.buffer, frame.acc.buffer]);
}

self.onmessage = (ev: MessageEvent<ToWorker>) => {
  const m = ev.data;
  if (m.type === "load") {
    load(m.bundleUrl, m.ortUrl, m.dense).catch((e) => post({ type: "error", message: String((e as Error).message ?? e) }));
  } else if (m.type === "render") {
    latest = m.id;
    queue = queue.then(() => render(m.id, m.width, m.height, m.c2w))
      .catch((e) => post({ type: "error", id: m.id, message: String((e as Error).message ?? e) }));
  } else if (m.type === "cancel") {
    if (latest === m.id) latest = -1;
  }
};
