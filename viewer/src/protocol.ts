// Messages between the page and the render worker.

/** onnxruntime-web's execution provider that runs the graphs. */
export type Provider = "webgpu" | "wasm";

export type ToWorker =
  | { type: "load"; bundleUrl: string; ortUrl: string; dense: boolean; ep: string; wholeGraph: boolean }
  | { type: "render"; id: number; width: number; height: number; c2w: number[][]; intrinsics?: Intrinsics }
  | { type: "cancel"; id: number };

/** A camera path frame's own pinhole (nerfstudio's: path.ts pathIntrinsics), at exactly
 *  width × height, no distortion; without it a render uses the bundle's camera resized. */
export interface Intrinsics { fx: number; fy: number; cx: number; cy: number }

export interface Loaded {
  type: "loaded"; scene: any; threads: number; isolated: boolean; marched: boolean;
  backend: Provider;
  reason: string; // why this provider: the adapter, or why not WebGPU
  encoding: string; // "hash grid here" (the head in onnxruntime-web), or why the whole graph runs there ("": not a hash grid, or WebGPU)
}
export interface FrameMsg {
  type: "frame"; id: number; width: number; height: number;
  rgb: Float32Array; depth: Float32Array; acc: Float32Array; points: number; ms: number;
  fieldMs: number; // of ms, the time evaluating the field: onnxruntime, and the hash grid where it runs here
  encodeMs: number; // of fieldMs, the hash grid evaluated here
  // The rest of ms, the loop around the field: rays, marching + packing, compositing.
  raysMs: number; marchMs: number; compositeMs: number;
}
export type FromWorker = Loaded | FrameMsg | { type: "cancelled"; id: number } | { type: "error"; id?: number; message: string };
