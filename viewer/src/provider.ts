// Which onnxruntime-web execution provider runs a bundle's graphs: WebGPU where the browser offers
// a GPU adapter and every graph can run on it, WASM otherwise, with the reason. Pure: the worker
// asks the browser for the adapter.

import type { GraphInfo } from "./bundle";
import type { Provider } from "./protocol";

/** Operators of the hash grid's default (bitwise) lowering that onnxruntime-web's WebGPU
 *  provider has no kernel for (the portable lowering, `nerf export --portable`, avoids them). */
export const WEBGPU_MISSING_OPS = ["BitwiseXor", "BitwiseAnd", "BitwiseOr", "BitwiseNot", "BitShift"];

/** What the provider choice needs of a GPU adapter (a GPUAdapter has it). */
export interface Adapter {
  features: { has(name: string): boolean };
  info?: { vendor?: string; architecture?: string; isFallbackAdapter?: boolean };
}

/** The provider for `graphs` given the browser's adapter (null: none, or no WebGPU), and why.
 *  A graph with an operator WebGPU lacks, or float16 tensors on an adapter without
 *  `shader-f16`, renders on WASM: onnxruntime would otherwise move those nodes to the CPU with
 *  copies each call, or fail. */
export function pickProvider(adapter: Adapter | null, graphs: { name: string; info: GraphInfo }[], noWebGpu = false): { provider: Provider; reason: string } {
  if (noWebGpu) return { provider: "wasm", reason: "no WebGPU in this browser" };
  if (!adapter) return { provider: "wasm", reason: "no GPU adapter" };
  for (const g of graphs) {
    const missing = WEBGPU_MISSING_OPS.filter((op) => g.info.ops.has(op));
    if (missing.length) return { provider: "wasm", reason: `${g.name} has ops WebGPU lacks: ${missing.join(", ")} (nerf export --portable avoids them)` };
    if (g.info.float16 && !adapter.features.has("shader-f16"))
      return { provider: "wasm", reason: `${g.name} has a float16 table and the GPU adapter lacks shader-f16 (nerf export --tables f32 stores float32)` };
  }
  const info = adapter.info ?? {};
  const name = [info.vendor, info.architecture].filter(Boolean).join(" ") || "GPU";
  return { provider: "webgpu", reason: `${name} adapter${info.isFallbackAdapter ? ", software" : ""}` };
}
