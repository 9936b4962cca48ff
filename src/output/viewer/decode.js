// The vertex stream's decoder for the browser viewer (protocols/vertex-stream.md,
// versions 1 to 4): one message (an ArrayBuffer holding exactly one) to an object, or an
// Error saying what is wrong. Pure: no DOM, no network; viewer.js uses it, and
// tests/browser/decode_check.mjs runs it under Node.js on good and mutated messages.

const MAGIC = [0x52, 0x47, 0x4c, 0x53]; // "RGLS"
export const KIND_TOPOLOGY = 1, KIND_FRAME = 2, KIND_GOODBYE = 3;
const MAX_PAYLOAD = 64 << 20;
const STOPS = ["converged", "iteration cap", "deadline"];

class Reader {
  constructor(buf, at, end, kind) {
    this.buf = buf; this.dv = new DataView(buf); this.at = at; this.end = end; this.kind = kind;
  }
  need(n, what) {
    if (this.end - this.at < n) throw new Error(`${this.kind}: truncated ${what} at byte ${this.at}`);
  }
  u8() { this.need(1, "u8"); return this.dv.getUint8(this.at++); }
  u16() { this.need(2, "u16"); const v = this.dv.getUint16(this.at, true); this.at += 2; return v; }
  u32() { this.need(4, "u32"); const v = this.dv.getUint32(this.at, true); this.at += 4; return v; }
  i32() { this.need(4, "i32"); const v = this.dv.getInt32(this.at, true); this.at += 4; return v; }
  f32() { this.need(4, "f32"); const v = this.dv.getFloat32(this.at, true); this.at += 4; return v; }
  f64() { this.need(8, "f64"); const v = this.dv.getFloat64(this.at, true); this.at += 8; return v; }
  u64() { const lo = this.u32(), hi = this.u32(); return hi * 4294967296 + lo; }
  string() {
    const n = this.u16(); this.need(n, "string");
    let s;
    try { s = new TextDecoder("utf-8", { fatal: true }).decode(new Uint8Array(this.buf, this.at, n)); } catch { throw new Error(`${this.kind}: string is not UTF-8`); }
    this.at += n; return s;
  }
  // A count of items of at least `minItem` bytes, checked against what is left.
  count(minItem) {
    const n = this.u32();
    if (n * minItem > this.end - this.at) throw new Error(`${this.kind}: count ${n} larger than the payload`);
    return n;
  }
  bytes(n) { this.need(n, "bytes"); const b = new Uint8Array(this.buf, this.at, n); this.at += n; return b; }
  // `n` floats: a view when aligned (the format keeps positions 4-byte aligned), else a copy.
  floats(n) {
    this.need(4 * n, "positions");
    let f;
    if (this.at % 4 === 0) f = new Float32Array(this.buf, this.at, n);
    else { f = new Float32Array(n); for (let i = 0; i < n; i++) f[i] = this.dv.getFloat32(this.at + 4 * i, true); }
    this.at += 4 * n; return f;
  }
  u32s(n) {
    this.need(4 * n, "indices");
    const out = new Uint32Array(n);
    for (let i = 0; i < n; i++) out[i] = this.dv.getUint32(this.at + 4 * i, true);
    this.at += 4 * n; return out;
  }
  done() { if (this.at !== this.end) throw new Error(`${this.kind}: trailing bytes at ${this.at}`); }
}

export function decodeMessage(buf) {
  if (buf.byteLength < 12) throw new Error("message shorter than its header");
  const dv = new DataView(buf);
  for (let i = 0; i < 4; i++) if (dv.getUint8(i) !== MAGIC[i]) throw new Error("bad magic");
  const version = dv.getUint16(4, true), kind = dv.getUint16(6, true), len = dv.getUint32(8, true);
  if (version < 1 || version > 4) throw new Error(`unsupported version ${version} (this viewer reads 1 to 4)`);
  if (len > MAX_PAYLOAD || 12 + len !== buf.byteLength) throw new Error(`bad payload length ${len}`);
  if (kind === KIND_TOPOLOGY) return { kind, version, topology: decodeTopology(new Reader(buf, 12, 12 + len, "topology"), version) };
  if (kind === KIND_FRAME) return { kind, version, frame: decodeFrame(new Reader(buf, 12, 12 + len, "frame"), version) };
  if (kind === KIND_GOODBYE) { const r = new Reader(buf, 12, 12 + len, "goodbye"); return { kind, version, reason: r.string() }; }
  return { kind, version }; // a kind this page does not know: skipped
}

function decodeTopology(r, version) {
  const t = { character: r.string(), rateHz: r.f32(), unit: r.string(), up: r.string(), handedness: r.string() };
  t.vertexCount = r.u32();
  const nt = r.count(12);
  t.triangles = r.u32s(3 * nt);
  for (const i of t.triangles) if (i >= t.vertexCount) throw new Error("topology: triangle index past the vertices");
  const nm = r.count(2);
  t.markerNames = []; for (let i = 0; i < nm; i++) t.markerNames.push(r.string());
  const nj = r.count(6);
  t.jointNames = []; t.jointParents = new Int32Array(nj);
  for (let j = 0; j < nj; j++) { t.jointNames.push(r.string()); t.jointParents[j] = r.i32(); }
  t.parts = [];
  if (version >= 2) {
    const np = r.count(18);
    for (let p = 0; p < np; p++) {
      const part = { name: r.string(), firstVertex: r.u32(), vertexCount: r.u32(), firstTriangle: r.u32(), triangleCount: r.u32() };
      if (part.firstVertex + part.vertexCount > t.vertexCount || part.firstTriangle + part.triangleCount > nt) throw new Error(`topology: part ${part.name} runs past the mesh`);
      t.parts.push(part);
    }
  }
  // Version 4: the actor this topology is for; before, the one actor, named after its character.
  t.actor = t.character; t.actorIndex = 0; t.actorCount = 1;
  if (version >= 4) {
    t.actorIndex = r.u8(); t.actorCount = r.u8();
    if (t.actorIndex >= t.actorCount) throw new Error(`topology: actor index ${t.actorIndex} not below the actor count ${t.actorCount}`);
    t.actor = r.string();
  }
  r.done();
  return t;
}

function decodeFrame(r, version) {
  const f = { frame: r.u64(), sourceTime: r.f64(), publishTime: r.f64(), iterations: r.u16() };
  const stop = r.u8(), actor = r.u8();
  // Byte 27 was reserved (zero) before version 4.
  f.actor = version >= 4 ? actor : 0;
  if (stop >= STOPS.length) throw new Error(`frame: unknown stop code ${stop}`);
  f.stop = STOPS[stop];
  f.solveMs = r.f32(); f.gcMs = r.f32(); f.rrms = r.f32(); f.boneLengthError = r.f32();
  f.jointLimitDeg = r.f32(); f.residualRmsMm = r.f32(); f.residualMaxMm = r.f32();
  const nm = r.count(13);
  f.states = r.bytes(nm);
  if (f.states.some((c) => c > 3)) throw new Error("frame: unknown marker state");
  r.bytes((4 - nm % 4) % 4);
  f.markers = r.floats(3 * nm);
  const nv = r.count(12);
  f.vertices = r.floats(3 * nv);
  f.receivedTime = 0; f.joints = new Float32Array(0);
  if (version >= 3) { f.receivedTime = r.f64(); const nj = r.count(12); f.joints = r.floats(3 * nj); }
  r.done();
  return f;
}

