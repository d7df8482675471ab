// A hash-grid helper (encoder.ts): encodes the shares of calls it is sent, in shared memory.

import { type EncodeJob, type EncoderInit, encodeRows } from "./encoder";
import { HashEncoder } from "./hashgrid";

let encoder: HashEncoder | null = null;

self.onmessage = (ev: MessageEvent<EncoderInit | EncodeJob>) => {
  const m = ev.data;
  try {
    if (m.type === "init") encoder = new HashEncoder(m.levels, m.features, m.table, m.min, m.scale, m.contracted);
    else {
      if (!encoder) throw new Error("no encoder sent");
      encodeRows(encoder, m.buffers, m.from, m.to);
      (self as unknown as Worker).postMessage("done");
    }
  } catch (e) {
    (self as unknown as Worker).postMessage(String((e as Error).message ?? e));
  }
};
