// The hash grid (hashgrid.ts) on every core: the render worker encodes one share of a call's
// points and helper workers the others, all reading one table and writing one output in
// shared memory. Needs SharedArrayBuffer, i.e. a cross-origin isolated page (as onnxruntime's
// threads do); without it the render worker encodes alone.

import { HashEncoder, type Level, SH4_DIM } from "./hashgrid";

/** What a helper is sent once: the encoder's parts (the table in shared memory). */
export interface EncoderInit { type: "init"; levels: Level[]; features: number; table: Float32Array; min: number[]; scale: number[]; contracted: boolean }
/** A share of a call: rows from..to of the shared buffers. */
export interface EncodeJob { type: "encode"; buffers: Buffers; from: number; to: number }

/** A call's inputs and outputs in shared memory, room for `rows` points. */
interface Buffers { points: Float32Array; viewdirs: Float32Array; features: Float32Array; sh: Float32Array }

/** Floats in shared memory (`shared`), else ordinary. */
function floats(n: number, shared: boolean): Float32Array {
  return shared ? new Float32Array(new SharedArrayBuffer(4 * n)) : new Float32Array(n);
}

/** Rows `from..to` of the buffers, encoded. */
export function encodeRows(encoder: HashEncoder, b: Buffers, from: number, to: number): void {
  const w = encoder.width;
  encoder.encode(b.points.subarray(3 * from, 3 * to), b.viewdirs.subarray(3 * from, 3 * to), to - from,
    b.features.subarray(w * from, w * to), b.sh.subarray(SH4_DIM * from, SH4_DIM * to));
}

/** An encoder run on `helpers` workers besides the calling thread (0: alone, no shared memory
 *  needed), on calls of at most `rows` points. */
export class ParallelEncoder {
  private readonly encoder: HashEncoder;
  private readonly buffers: Buffers;
  private readonly workers: Worker[] = [];

  constructor(encoder: HashEncoder, helpers: number, readonly rows: number) {
    const shared = helpers > 0;
    // The table once in shared memory, for every thread.
    let table = encoder.table;
    if (shared) { table = floats(table.length, true); table.set(encoder.table); }
    this.encoder = new HashEncoder(encoder.levels, encoder.features, table, encoder.min, encoder.scale, encoder.contracted);
    this.buffers = { points: floats(3 * rows, shared), viewdirs: floats(3 * rows, shared), features: floats(encoder.width * rows, shared), sh: floats(SH4_DIM * rows, shared) };
    const init: EncoderInit = { type: "init", levels: encoder.levels, features: encoder.features, table, min: encoder.min, scale: encoder.scale, contracted: encoder.contracted };
    for (let k = 0; k < helpers; k++) {
      const worker = new Worker(new URL("./encoder-worker.ts", import.meta.url), { type: "module" });
      worker.postMessage(init);
      this.workers.push(worker);
    }
  }

  get width(): number { return this.encoder.width; }

  /** Threads encoding, this one included. */
  get threads(): number { return this.workers.length + 1; }

  /** features [n, L·F] and harmonics [n, 16] of points and viewdirs [n, 3] (n ≤ rows): views
   *  of shared memory, valid until the next call. */
  async encode(points: Float32Array, viewdirs: Float32Array, n: number): Promise<{ features: Float32Array; sh: Float32Array }> {
    const b = this.buffers;
    b.points.set(points.subarray(0, 3 * n));
    b.viewdirs.set(viewdirs.subarray(0, 3 * n));
    // Equal shares; the calling thread takes the first.
    const shares = this.workers.length + 1, size = Math.ceil(n / shares);
    const done = this.workers.map((worker, k) => new Promise<void>((ok, no) => {
      const from = Math.min(n, (k + 1) * size), to = Math.min(n, (k + 2) * size);
      worker.onmessage = (ev) => (ev.data === "done" ? ok() : no(new Error(`hash-grid helper: ${ev.data}`)));
      worker.onerror = (ev) => no(new Error(`hash-grid helper: ${ev.message}`));
      const job: EncodeJob = { type: "encode", buffers: b, from, to };
      worker.postMessage(job);
    }));
    encodeRows(this.encoder, b, 0, Math.min(n, size));
    await Promise.all(done);
    return { features: b.features.subarray(0, this.encoder.width * n), sh: b.sh.subarray(0, SH4_DIM * n) };
  }

  /** Stop the helpers (a new bundle replaces this one). */
  release(): void {
    for (const w of this.workers) w.terminate();
  }
}
