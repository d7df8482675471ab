// This viewer's WebAssembly (assembly/*.ts, AssemblyScript, built into wasm.gen.ts by
// scripts/wasm.mjs): each module compiled once per thread, instances with memory of their own,
// arrays laid out by their callers from BASE up.

import { WASM } from "./wasm.gen";

const compiled = new Map<keyof typeof WASM, WebAssembly.Module>();

/** A new instance of assembly/`name`.ts (compiled synchronously on first use: the modules are
 *  small, and they run in workers). */
export function instantiate<T>(name: keyof typeof WASM): T & { memory: WebAssembly.Memory } {
  let module = compiled.get(name);
  if (!module) compiled.set(name, (module = new WebAssembly.Module(Uint8Array.from(atob(WASM[name]), (c) => c.charCodeAt(0)))));
  const x = new WebAssembly.Instance(module, {}).exports as unknown as T & { memory: WebAssembly.Memory; heapBase(): number };
  if (x.heapBase() > BASE) throw new Error(`assembly/${name}.ts: its static data ends at ${x.heapBase()}, above ${BASE}`);
  return x;
}

/** Where callers' arrays start: above a module's own data (the first 64 KiB page). */
export const BASE = 65536;

/** Hands out byte ranges from `top` up, 16-byte aligned. */
export class Layout {
  constructor(public top: number) {}
  take(bytes: number): number { const at = this.top; this.top += (bytes + 15) & ~15; return at; }
}

/** Grows `memory` to hold `top` bytes; `what` names the data in the error when it cannot. */
export function reserve(memory: WebAssembly.Memory, top: number, what: string): void {
  const have = memory.buffer.byteLength;
  if (top <= have) return;
  try { memory.grow(Math.ceil((top - have) / 65536)); }
  catch { throw new Error(`${what}: ${(top / 2 ** 20).toFixed(0)} MB do not fit in this browser's WebAssembly memory`); }
}
