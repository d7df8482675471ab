// Builds the viewer into dist/ and copies onnxruntime-web's WASM runtime to dist/ort/, which
// the worker points ort.env.wasm.wasmPaths at (served locally, never from a CDN).
import { copyFileSync, mkdirSync } from "node:fs";
import { resolve } from "node:path";
import { defineConfig, type Plugin } from "vite";

// The WASM build, and the WebGPU one (asyncify) the worker loads instead when it runs on a GPU.
const ORT_FILES = ["ort-wasm-simd-threaded.mjs", "ort-wasm-simd-threaded.wasm",
  "ort-wasm-simd-threaded.asyncify.mjs", "ort-wasm-simd-threaded.asyncify.wasm"];

function copyOrt(): Plugin {
  return {
    name: "copy-ort-wasm",
    apply: "build",
    closeBundle() {
      const out = resolve(import.meta.dirname, "dist/ort");
      mkdirSync(out, { recursive: true });
      for (const f of ORT_FILES) copyFileSync(resolve(import.meta.dirname, "node_modules/onnxruntime-web/dist", f), resolve(out, f));
    },
  };
}

// "onnxruntime-web-use-extern-wasm" picks ort.wasm.min.mjs (ort.webgpu.min.mjs), which loads the runtime from
// wasmPaths instead of bundling it into our chunks.
const conditions = ["onnxruntime-web-use-extern-wasm", "module", "browser", "development|production"];

export default defineConfig({
  base: "./",
  resolve: { conditions },
  worker: { format: "es" },
  build: { target: "es2022", outDir: "dist", emptyOutDir: true },
  plugins: [copyOrt()],
  test: { include: ["tests/unit/**/*.test.ts"] },
} as any);
