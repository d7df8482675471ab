// The protobuf wire format, as much of it as reading and cutting an ONNX model takes: walking a
// message's fields (a length-delimited one by its byte range, so a large tensor is never copied
// or decoded) and writing fields back. Pure.

/** Throws the error of a malformed message. */
export type Bad = (why: string) => never;

/** The varint at `at.pos` of bytes[.., end), moving `at` past it. */
function readVarint(bytes: Uint8Array, at: { pos: number }, end: number, bad: Bad): number {
  let v = 0, scale = 1;
  for (let i = 0; i < 10; i++) {
    if (at.pos >= end) bad("truncated");
    const b = bytes[at.pos++];
    v += (b & 0x7f) * scale; scale *= 128;
    if (b < 0x80) return v;
  }
  return bad("a varint longer than 10 bytes");
}

/** Calls `field(number, start, end)` for each length-delimited field of bytes[start, end) and
 *  `scalar(number, value)` for each varint; fixed-width fields are skipped. */
export function walkFields(bytes: Uint8Array, start: number, end: number, bad: Bad,
  field: (n: number, s: number, e: number) => void, scalar: (n: number, v: number) => void = () => {}): void {
  const at = { pos: start };
  const varint = () => readVarint(bytes, at, end, bad);
  while (at.pos < end) {
    const key = varint(), n = Math.floor(key / 8), wire = key % 8;
    if (wire === 0) scalar(n, varint());
    else if (wire === 1) at.pos += 8;
    else if (wire === 5) at.pos += 4;
    else if (wire === 2) {
      const len = varint(), s = at.pos;
      if (s + len > end) bad("a field runs past the end of the file");
      at.pos += len;
      field(n, s, s + len);
    } else bad(`wire type ${wire}`);
    if (at.pos > end) bad("truncated");
  }
}

/** The varints of a packed repeated field (e.g. a TensorProto's dims) in bytes[start, end). */
export function packedVarints(bytes: Uint8Array, start: number, end: number, bad: Bad): number[] {
  const out: number[] = [], at = { pos: start };
  while (at.pos < end) out.push(readVarint(bytes, at, end, bad));
  return out;
}

const decoder = new TextDecoder();

/** An ONNX model's bytes and what every reader of them needs: its fields by range, its strings,
 *  and errors that name the file (`name`). */
export class ModelReader {
  constructor(readonly bytes: Uint8Array, readonly name: string) {}

  /** Throws "<name>: not an ONNX model (<why>)". */
  readonly bad: Bad = (why) => { throw new Error(`${this.name}: not an ONNX model (${why})`); };

  /** walkFields over bytes[start, end). */
  readonly walk = (start: number, end: number, field: (n: number, s: number, e: number) => void, scalar?: (n: number, v: number) => void): void =>
    walkFields(this.bytes, start, end, this.bad, field, scalar);

  /** The UTF-8 string in bytes[start, end). */
  readonly str = (start: number, end: number): string => decoder.decode(this.bytes.subarray(start, end));

  /** A metadata entry (ModelProto.metadata_props, StringStringEntryProto: key 1, value 2) in
   *  bytes[start, end). */
  entry(start: number, end: number): [string, string] {
    let key = "", value = "";
    this.walk(start, end, (m, a, b) => { if (m === 1) key = this.str(a, b); else if (m === 2) value = this.str(a, b); });
    return [key, value];
  }
}

/** A varint's bytes (non-negative integers below 2⁵³). */
function varintBytes(v: number): number[] {
  const out: number[] = [];
  while (v >= 0x80) { out.push((v % 128) | 0x80); v = Math.floor(v / 128); }
  out.push(v);
  return out;
}

/** Field `n` as a length-delimited field holding `body`. */
export function lengthDelimited(n: number, body: Uint8Array): Uint8Array {
  const head = [...varintBytes(n * 8 + 2), ...varintBytes(body.length)];
  const out = new Uint8Array(head.length + body.length);
  out.set(head);
  out.set(body, head.length);
  return out;
}

/** Field `n` as a varint. */
export function varintField(n: number, v: number): Uint8Array {
  return new Uint8Array([...varintBytes(n * 8), ...varintBytes(v)]);
}

/** Field `n` as a UTF-8 string. */
export function stringField(n: number, s: string): Uint8Array {
  return lengthDelimited(n, new TextEncoder().encode(s));
}

/** The parts one after the other. */
export function concatBytes(parts: Uint8Array[]): Uint8Array {
  const out = new Uint8Array(parts.reduce((s, p) => s + p.length, 0));
  let at = 0;
  for (const p of parts) { out.set(p, at); at += p.length; }
  return out;
}
