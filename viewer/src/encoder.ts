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
  /** Why a helper failed (the calls then run on this thread alone), and how to stop waiting for one. */
  private failed: string | null = null;
  private abort: (() => void) | null = null;

  constructor(encoder: HashEncoder, helpers: number, readonly rows: number) {
    const shared = helpers > 0;
    // The table once in shared memory, for every thread.
    let table = encoder.table;
    if (shared) { table = floats(table.length, true); table.set(encoder.table); }
    this.encoder = new HashEncoder(encoder.levels, encoder.features, table, encoder.min, encoder.scale, encoder.contracted);
    // The inputs are copied into shared memory only for helpers to read.
    const inputs = shared ? 3 * rows : 0;
    this.buffers = { points: floats(inputs, shared), viewdirs: floats(inputs, shared), features: floats(encoder.width * rows, shared), sh: floats(SH4_DIM * rows, shared) };
    const init: EncoderInit = { type: "init", levels: encoder.levels, features: encoder.features, table, min: encoder.min, scale: encoder.scale, contracted: encoder.contracted };
    for (let k = 0; k < helpers; k++) {
      const worker = new Worker(new URL("./encoder-worker.ts", import.meta.url), { type: "module" });
      // A helper that cannot start (its script missing, say) is noticed at the next call.
      worker.onerror = (ev) => { ev.preventDefault(); this.failed = `hash-grid helper: ${ev.message || "did not start"}`; this.abort?.(); };
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
    if (this.failed && this.workers.length) {
      console.warn(`${this.failed}: the hash grid is encoded on one thread`);
      this.release();
      this.workers.length = 0;
    }
    const out = { features: b.features.subarray(0, this.encoder.width * n), sh: b.sh.subarray(0, SH4_DIM * n) };
    if (!this.workers.length) {
      // Alone: straight from the caller's arrays.
      this.encoder.encode(points, viewdirs, n, out.features, out.sh);
      return out;
    }
    b.points.set(points.subarray(0, 3 * n));
    b.viewdirs.set(viewdirs.subarray(0, 3 * n));
    // Equal shares; the calling thread takes the first.
    const shares = this.workers.length + 1, size = Math.ceil(n / shares);
    const stopped = new Promise<boolean>((ok) => { this.abort = () => ok(false); });
    const done = this.workers.map((worker, k) => new Promise<boolean>((ok) => {
      const from = Math.min(n, (k + 1) * size), to = Math.min(n, (k + 2) * size);
      worker.onmessage = (ev) => {
        if (ev.data !== "done") this.failed = `hash-grid helper: ${ev.data}`;
        ok(ev.data === "done");
      };
      const job: EncodeJob = { type: "encode", buffers: b, from, to };
      worker.postMessage(job);
    }));
    encodeRows(this.encoder, b, 0, Math.min(n, size));
    const helped = await Promise.race([Promise.all(done).then((all) => all.every(Boolean)), stopped]);
    this.abort = null;
    // A helper that failed: its share (and the others', to be sure) on this thread.
    if (!helped) encodeRows(this.encoder, b, Math.min(n, size), n);
    return out;
  }

  /** Stop the helpers (a new bundle replaces this one). */
  release(): void {
    for (const w of this.workers) w.terminate();
  }
}
