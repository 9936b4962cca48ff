// Runs the browser viewer's decoder (src/output/viewer/decode.js) under Node.js on the
// messages the Rust codec wrote to DIR (messages.bin, one after the other), then on
// arbitrary mutations of them and on arbitrary bytes: it must decode or throw a plain
// Error saying why, never anything else (a RangeError would be a read past the bytes).
// Prints one JSON line: what it decoded, and the counts.
//
//   node decode_check.mjs DIR CASES
//
// tests/client_decoders.rs runs it.

import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const { decodeMessage } = await import(path.join(here, "../../src/output/viewer/decode.js"));
const [dir, casesArg] = process.argv.slice(2);
const cases = Number(casesArg || 20000);

// The messages: split by their headers' lengths.
const all = fs.readFileSync(path.join(dir, "messages.bin"));
const messages = [];
for (let at = 0; at < all.length;) {
  const len = all.readUInt32LE(at + 8);
  messages.push(all.subarray(at, at + 12 + len));
  at += 12 + len;
}
const toBuffer = (u8) => u8.buffer.slice(u8.byteOffset, u8.byteOffset + u8.byteLength);

const decoded = messages.map((m) => {
  const d = decodeMessage(toBuffer(m));
  if (d.topology) {
    const t = d.topology;
    return { kind: d.kind, version: d.version, character: t.character, vertexCount: t.vertexCount, triangles: Array.from(t.triangles),
      markerNames: t.markerNames, jointNames: t.jointNames, jointParents: Array.from(t.jointParents), parts: t.parts,
      actor: t.actor, actorIndex: t.actorIndex, actorCount: t.actorCount };
  }
  if (d.frame) {
    const f = d.frame;
    return { kind: d.kind, version: d.version, frame: f.frame, actor: f.actor, sourceTime: f.sourceTime, publishTime: f.publishTime, receivedTime: f.receivedTime,
      iterations: f.iterations, stop: f.stop, solveMs: f.solveMs, states: Array.from(f.states), markers: Array.from(f.markers),
      vertices: Array.from(f.vertices), joints: Array.from(f.joints) };
  }
  return { kind: d.kind, version: d.version, reason: d.reason };
});

// A seeded generator (mulberry32), so that a failure repeats.
let seed = 0x5eed;
const rand = () => {
  seed |= 0; seed = (seed + 0x6d2b79f5) | 0;
  let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
  t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t;
  return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
};
const int = (n) => Math.floor(rand() * n);

let accepted = 0, refused = 0;
const bad = [];
for (let c = 0; c < cases; c++) {
  let b;
  const kind = c % 4;
  if (kind === 3) {
    b = new Uint8Array(int(300)).map(() => int(256));
  } else {
    b = new Uint8Array(messages[int(messages.length)]);
    if (kind === 0) {
      for (let k = 1 + int(8); k > 0; k--) b[int(b.length)] = int(256);
    } else if (kind === 1) {
      // A header or count field set to an arbitrary value: lengths, counts, version.
      const dv = new DataView(b.buffer);
      const at = int(Math.max(1, b.length - 4));
      dv.setUint32(at, rand() < 0.5 ? int(0x100000000) : [0, 1, 0xffffffff, 0x7fffffff, b.length][int(5)], true);
    } else {
      b = rand() < 0.5 ? b.subarray(0, int(b.length)) : Uint8Array.from([...b, ...new Uint8Array(1 + int(16))]);
    }
  }
  try {
    decodeMessage(toBuffer(b));
    accepted++;
  } catch (e) {
    if (e.constructor !== Error) bad.push(`${e.constructor.name}: ${e.message}`);
    else refused++;
  }
}
console.log(JSON.stringify({ decoded, cases, accepted, refused, bad: bad.slice(0, 5), bad_count: bad.length }));
