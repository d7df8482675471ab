// Messages between the page and the render worker.

export type ToWorker =
  | { type: "load"; bundleUrl: string; ortUrl: string; dense: boolean }
  | { type: "render"; id: number; width: number; height: number; c2w: number[][] }
  | { type: "cancel"; id: number };

export interface Loaded { type: "loaded"; scene: any; threads: number; backend: string; isolated: boolean; marched: boolean }
export interface FrameMsg {
  type: "frame"; id: number; width: number; height: number;
  rgb: Float32Array; depth: Float32Array; acc: Float32Array; points: number; ms: number;
  fieldMs: number; // of ms, the time inside onnxruntime
}
export type FromWorker = Loaded | FrameMsg | { type: "cancelled"; id: number } | { type: "error"; id?: number; message: string };
