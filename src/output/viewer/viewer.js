// rigless browser viewer. Reads the vertex stream (protocols/vertex-stream.md, versions 1
// to 4) from the WebSocket on the page's own host and port, and draws every actor's newest
// frame with WebGL 2: each mesh lit with normals recomputed every frame, in its own tint
// and labelled with its name, the markers coloured by fill state, the fitted skeletons,
// and an overlay of rates, solve time and latency. The camera follows: it keeps every
// actor in view as they move (orbiting keeps it following; panning or zooming frees it,
// F follows again). An actor is drawn from its first frame with a marker in view (until
// then it stands at rest, not where its performer is). Frames that arrive faster than
// the page draws are dropped (only each actor's newest is kept); a closed connection is
// retried with a back-off. `window.rigless` exposes the state for tests and scripts.

import { decodeMessage, KIND_TOPOLOGY, KIND_FRAME, KIND_GOODBYE } from "./decode.js";

// Fill state colours: measured, predicted, rigid-filled, held.
const STATE_RGB = [[0.30, 0.85, 0.39], [1.0, 0.8, 0.0], [0.35, 0.78, 0.98], [1.0, 0.23, 0.19]];
// Each actor's tint, by its index (the first is skin; then blue, green, violet, ...).
const ACTOR_RGB = [[0.93, 0.62, 0.45], [0.45, 0.62, 0.95], [0.55, 0.85, 0.50], [0.80, 0.55, 0.90],
  [0.95, 0.85, 0.45], [0.50, 0.85, 0.85]];
const HELD = 3;


// ---------------------------------------------------------------- maths (column-major 4x4)

function perspective(fovY, aspect, near, far) {
  const f = 1 / Math.tan(fovY / 2), nf = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
}
function lookAt(eye, target, up) {
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const norm = (a) => { const l = Math.hypot(...a) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const z = norm(sub(eye, target)), x = norm(cross(up, z)), y = cross(z, x);
  return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
}
function mul(a, b) {
  const o = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) for (let k = 0; k < 4; k++) o[c * 4 + r] += a[k * 4 + r] * b[c * 4 + k];
  return o;
}

// Area-weighted vertex normals of `pos` (x, y, z per vertex) into `out`, summed over the
// vertices that share a position (`weld[i]`: the first vertex at vertex i's rest place),
// so a mesh split at UV seams shades smoothly across them.
function computeNormals(pos, tris, weld, out) {
  out.fill(0);
  for (let t = 0; t < tris.length; t += 3) {
    const a = 3 * weld[tris[t]], b = 3 * weld[tris[t + 1]], c = 3 * weld[tris[t + 2]];
    const ux = pos[b] - pos[a], uy = pos[b + 1] - pos[a + 1], uz = pos[b + 2] - pos[a + 2];
    const vx = pos[c] - pos[a], vy = pos[c + 1] - pos[a + 1], vz = pos[c + 2] - pos[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    out[a] += nx; out[a + 1] += ny; out[a + 2] += nz;
    out[b] += nx; out[b + 1] += ny; out[b + 2] += nz;
    out[c] += nx; out[c + 1] += ny; out[c + 2] += nz;
  }
  for (let v = 0; v < weld.length; v++) {
    const w = 3 * weld[v], l = Math.hypot(out[w], out[w + 1], out[w + 2]) || 1;
    if (w === 3 * v) { out[w] /= l; out[w + 1] /= l; out[w + 2] /= l; }
  }
  for (let v = 0; v < weld.length; v++) {
    const w = 3 * weld[v];
    if (w !== 3 * v) { out[3 * v] = out[w]; out[3 * v + 1] = out[w + 1]; out[3 * v + 2] = out[w + 2]; }
  }
}

function weldMap(pos) {
  const n = pos.length / 3, weld = new Uint32Array(n), seen = new Map();
  for (let v = 0; v < n; v++) {
    const key = `${pos[3 * v]},${pos[3 * v + 1]},${pos[3 * v + 2]}`;
    const first = seen.get(key);
    if (first === undefined) { seen.set(key, v); weld[v] = v; } else weld[v] = first;
  }
  return weld;
}

// ---------------------------------------------------------------- rendering

const MESH_VS = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec3 aNormal;
uniform mat4 uViewProj;
out vec3 vNormal;
void main() { vNormal = aNormal; gl_Position = uViewProj * vec4(aPos, 1.0); }`;
const MESH_FS = `#version 300 es
precision highp float;
in vec3 vNormal;
uniform vec3 uColor;
uniform vec3 uKey;
out vec4 outColor;
void main() {
  vec3 n = normalize(vNormal) * (gl_FrontFacing ? 1.0 : -1.0);
  float hemi = 0.5 + 0.5 * n.y;
  float key = max(dot(n, uKey), 0.0);
  vec3 c = uColor * (0.25 + 0.25 * hemi + 0.6 * key);
  outColor = vec4(pow(c, vec3(1.0 / 1.2)), 1.0);
}`;
const FLAT_VS = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec3 aColor;
uniform mat4 uViewProj;
uniform float uPointSize;
out vec3 vColor;
void main() { vColor = aColor; gl_Position = uViewProj * vec4(aPos, 1.0); gl_PointSize = uPointSize; }`;
const FLAT_FS = `#version 300 es
precision mediump float;
in vec3 vColor;
out vec4 outColor;
void main() { outColor = vec4(vColor, 1.0); }`;

function program(gl, vs, fs) {
  const p = gl.createProgram();
  for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src); gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    gl.attachShader(p, s);
  }
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  return p;
}

// Whether WebGL runs in software (SwiftShader, llvmpipe: a headless browser or a machine
// without a GPU driver), where multisampling costs more than it is worth.
function softwareGL() {
  const gl = document.createElement("canvas").getContext("webgl2");
  const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
  const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : "";
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}

class Renderer {
  constructor(canvas) {
    const gl = canvas.getContext("webgl2", { antialias: !softwareGL(), preserveDrawingBuffer: true });
    if (!gl) throw new Error("this browser has no WebGL 2");
    this.gl = gl; this.canvas = canvas;
    this.mesh = program(gl, MESH_VS, MESH_FS);
    this.flat = program(gl, FLAT_VS, FLAT_FS);
    this.flatVao = gl.createVertexArray();
    this.buf = { fpos: gl.createBuffer(), fcol: gl.createBuffer() };
    gl.bindVertexArray(this.flatVao);
    for (const [loc, b] of [[0, this.buf.fpos], [1, this.buf.fcol]]) {
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
    }
    gl.bindVertexArray(null);
  }
  // An actor's mesh on the GPU: its triangles, and room for its positions and normals.
  addMesh(t) {
    const gl = this.gl;
    const m = { vao: gl.createVertexArray(), pos: gl.createBuffer(), normal: gl.createBuffer(), index: gl.createBuffer(), indexCount: t.triangles.length };
    gl.bindVertexArray(m.vao);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, m.index);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, t.triangles, gl.STATIC_DRAW);
    for (const [loc, b] of [[0, m.pos], [1, m.normal]]) {
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.bufferData(gl.ARRAY_BUFFER, 12 * t.vertexCount, gl.DYNAMIC_DRAW);
      gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
    }
    gl.bindVertexArray(null);
    return m;
  }
  dropMesh(m) {
    const gl = this.gl;
    gl.deleteVertexArray(m.vao);
    for (const b of [m.pos, m.normal, m.index]) gl.deleteBuffer(b);
  }
  setMesh(m, vertices, normals) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, m.pos); gl.bufferSubData(gl.ARRAY_BUFFER, 0, vertices);
    gl.bindBuffer(gl.ARRAY_BUFFER, m.normal); gl.bufferSubData(gl.ARRAY_BUFFER, 0, normals);
  }
  // Every actor's markers (points) then bones (lines), drawn over the meshes.
  setOverlay(positions, colors) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buf.fpos); gl.bufferData(gl.ARRAY_BUFFER, positions, gl.DYNAMIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buf.fcol); gl.bufferData(gl.ARRAY_BUFFER, colors, gl.DYNAMIC_DRAW);
  }
  // Draws `meshes` ([{ gpu, rgb }]) and the overlay.
  draw(viewProj, key, meshes, markerCount, lineVertexCount) {
    const gl = this.gl, dpr = window.devicePixelRatio || 1;
    const w = Math.floor(this.canvas.clientWidth * dpr), h = Math.floor(this.canvas.clientHeight * dpr);
    if (this.canvas.width !== w || this.canvas.height !== h) { this.canvas.width = w; this.canvas.height = h; }
    gl.viewport(0, 0, w, h);
    gl.clearColor(0.114, 0.141, 0.188, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(this.mesh);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.mesh, "uViewProj"), false, viewProj);
    gl.uniform3fv(gl.getUniformLocation(this.mesh, "uKey"), key);
    for (const { gpu, rgb } of meshes) {
      gl.uniform3fv(gl.getUniformLocation(this.mesh, "uColor"), rgb);
      gl.bindVertexArray(gpu.vao);
      gl.drawElements(gl.TRIANGLES, gpu.indexCount, gl.UNSIGNED_INT, 0);
    }
    gl.disable(gl.DEPTH_TEST);
    gl.useProgram(this.flat);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.flat, "uViewProj"), false, viewProj);
    gl.uniform1f(gl.getUniformLocation(this.flat, "uPointSize"), 7 * dpr);
    gl.bindVertexArray(this.flatVao);
    if (lineVertexCount > 0) gl.drawArrays(gl.LINES, markerCount, lineVertexCount);
    if (markerCount > 0) gl.drawArrays(gl.POINTS, 0, markerCount);
    gl.bindVertexArray(null);
  }
}

// ---------------------------------------------------------------- camera (Y up)

// The box of the finite positions of `pos` (x, y, z per point), or null.
function bounds(pos) {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < pos.length; i++) { const a = i % 3; if (Number.isFinite(pos[i])) { lo[a] = Math.min(lo[a], pos[i]); hi[a] = Math.max(hi[a], pos[i]); } }
  return hi[0] >= lo[0] ? { lo, hi } : null;
}
function corners(b) {
  const out = [];
  for (let k = 0; k < 8; k++) out.push([k & 1 ? b.hi[0] : b.lo[0], k & 2 ? b.hi[1] : b.lo[1], k & 4 ? b.hi[2] : b.lo[2]]);
  return out;
}
// Room around what the camera frames: 1 is touching the picture's edge.
const FRAME_MARGIN = 1.15;

class Camera {
  constructor() { this.target = [0, 1, 0]; this.distance = 3; this.yaw = 0.4; this.pitch = 0.2; this.fov = 40 * Math.PI / 180; this.follow = true; this.aspect = 1; }
  eye() {
    const cp = Math.cos(this.pitch);
    return [this.target[0] + this.distance * cp * Math.sin(this.yaw), this.target[1] + this.distance * Math.sin(this.pitch),
      this.target[2] + this.distance * cp * Math.cos(this.yaw)];
  }
  viewProj(aspect) {
    this.aspect = aspect;
    const eye = this.eye();
    return mul(perspective(this.fov, aspect, this.distance / 100, this.distance * 100), lookAt(eye, this.target, [0, 1, 0]));
  }
  // The distance at which a sphere of `radius` around the target fills the narrower of
  // the picture's two angles, with the margin.
  distanceFor(radius) {
    const half = Math.min(this.fov / 2, Math.atan(Math.tan(this.fov / 2) * this.aspect));
    return FRAME_MARGIN * Math.max(radius, 0.05) / Math.sin(half);
  }
  // Frames box `b` at once: its centre, and the whole box in the picture.
  frame(b) {
    if (!b) return;
    this.target = [0, 1, 2].map((a) => 0.5 * (b.lo[a] + b.hi[a]));
    this.distance = this.distanceFor(0.5 * Math.hypot(b.hi[0] - b.lo[0], b.hi[1] - b.lo[1], b.hi[2] - b.lo[2]));
  }
  // Follows box `b` smoothly: the target eases towards its centre; the distance keeps
  // every corner of it in view from wherever the target is now (at once when it must
  // grow, slowly when it may shrink), so nothing leaves the picture while it eases.
  track(b) {
    if (!b) return;
    this.target = this.target.map((x, a) => x + 0.15 * (0.5 * (b.lo[a] + b.hi[a]) - x));
    const r = Math.max(...corners(b).map((c) => Math.hypot(c[0] - this.target[0], c[1] - this.target[1], c[2] - this.target[2])));
    const want = this.distanceFor(r);
    this.distance = want > this.distance ? want : this.distance + 0.06 * (want - this.distance);
  }
  attach(canvas) {
    let drag = null;
    canvas.addEventListener("contextmenu", (e) => e.preventDefault());
    canvas.addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener("pointerup", () => { drag = null; });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = e.clientX - drag.x, dy = e.clientY - drag.y; drag.x = e.clientX; drag.y = e.clientY;
      if (drag.pan) {
        this.follow = false;
        const s = this.distance * 0.0015, cy = Math.cos(this.yaw), sy = Math.sin(this.yaw);
        this.target = [this.target[0] - s * dx * cy, this.target[1] + s * dy, this.target[2] + s * dx * sy];
      } else {
        this.yaw -= dx * 0.008;
        this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + dy * 0.008));
      }
    });
    canvas.addEventListener("wheel", (e) => { e.preventDefault(); this.follow = false; this.distance *= Math.exp(e.deltaY * 0.001); }, { passive: false });
  }
}

// ---------------------------------------------------------------- the page

const stateEl = document.getElementById("state"), statsEl = document.getElementById("stats");
const labelsEl = document.getElementById("labels");
const canvas = document.getElementById("view");
const camera = new Camera();
camera.attach(canvas);
let renderer = null;
try { renderer = new Renderer(canvas); } catch (e) { stateEl.textContent = `cannot draw: ${e.message}`; }

// Each actor, by its index: its topology, newest and drawn frames, GPU mesh, the box of
// its drawn vertices, whether a frame of it has had a marker in view, and its label.
function newActor(t) {
  const label = document.createElement("div");
  label.className = "actor-label";
  label.style.color = `rgb(${(ACTOR_RGB[t.actorIndex % ACTOR_RGB.length]).map((c) => Math.round(255 * c)).join(",")})`;
  labelsEl.appendChild(label);
  return { t, pending: null, drawn: null, weld: null, normals: new Float32Array(3 * t.vertexCount),
    gpu: renderer ? renderer.addMesh(t) : null, box: null, seen: false, label };
}
function dropActors() {
  for (const a of page.actors) { if (a && renderer) renderer.dropMesh(a.gpu); if (a) a.label.remove(); }
  page.actors = [];
}

const page = {
  state: "connecting", actors: [], framed: false, connects: 0, goodbye: null, error: null,
  received: 0, drawnCount: 0, recvTimes: [], drawTimes: [], latencies: [],
};
const nowUnixMs = () => performance.timeOrigin + performance.now();
const median = (xs) => { if (!xs.length) return NaN; const s = [...xs].sort((a, b) => a - b); return s[Math.floor(s.length / 2)]; };
// Events per second over the last two seconds.
const rate = (times, now) => { while (times.length && times[0] < now - 2000) times.shift(); return times.length / 2; };

let backoffMs = 250;
function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/stream`);
  ws.binaryType = "arraybuffer";
  page.state = "connecting";
  ws.onopen = () => { page.state = "connected"; page.connects++; backoffMs = 250; dropActors(); page.framed = false; };
  ws.onmessage = (ev) => {
    let m;
    try { m = decodeMessage(ev.data); } catch (e) { page.error = e.message; ws.close(); return; }
    if (m.kind === KIND_TOPOLOGY) {
      const t = m.topology, old = page.actors[t.actorIndex];
      if (old) { if (renderer) renderer.dropMesh(old.gpu); old.label.remove(); }
      page.actors[t.actorIndex] = newActor(t);
    } else if (m.kind === KIND_FRAME) {
      const a = page.actors[m.frame.actor];
      if (!a) { page.error = `a frame of actor ${m.frame.actor} before its topology`; return; }
      if (m.frame.vertices.length !== 3 * a.t.vertexCount) { page.error = `${a.t.actor}: frame and topology disagree on the vertex count`; return; }
      a.pending = m.frame; page.received++; page.recvTimes.push(performance.now());
    } else if (m.kind === KIND_GOODBYE) {
      page.goodbye = m.reason;
    }
  };
  ws.onclose = () => {
    page.state = `reconnecting in ${(backoffMs / 1000).toFixed(2)} s` + (page.goodbye ? ` (server: ${page.goodbye})` : "");
    setTimeout(connect, backoffMs);
    backoffMs = Math.min(2 * backoffMs, 2000);
  };
}

// The markers and bones of the actors shown, markers first.
function overlayOf(shown) {
  let nm = 0, bones = 0;
  for (const a of shown) {
    const nj = a.drawn.joints.length / 3;
    nm += a.drawn.states.length;
    for (let j = 0; j < nj; j++) if (a.t.jointParents[j] >= 0 && a.t.jointParents[j] < nj) bones++;
  }
  const pos = new Float32Array(3 * (nm + 2 * bones)), col = new Float32Array(pos.length);
  let m = 0, at = 3 * nm;
  for (const a of shown) {
    const f = a.drawn, t = a.t, nj = f.joints.length / 3;
    pos.set(f.markers, 3 * m);
    for (let k = 0; k < f.states.length; k++) col.set(STATE_RGB[f.states[k]] ?? STATE_RGB[HELD], 3 * (m + k));
    m += f.states.length;
    for (let j = 0; j < nj; j++) {
      const p = t.jointParents[j];
      if (p < 0 || p >= nj) continue;
      pos.set(f.joints.subarray(3 * p, 3 * p + 3), at); col.set([0.95, 0.95, 0.95], at); at += 3;
      pos.set(f.joints.subarray(3 * j, 3 * j + 3), at); col.set([0.95, 0.95, 0.95], at); at += 3;
    }
  }
  return { pos, col, markers: nm, lineVertices: 2 * bones };
}

// The box around every actor shown.
function sceneBox() {
  let b = null;
  for (const a of page.actors) {
    if (!a || !a.seen || !a.box) continue;
    b = b ? { lo: b.lo.map((x, i) => Math.min(x, a.box.lo[i])), hi: b.hi.map((x, i) => Math.max(x, a.box.hi[i])) } : { lo: [...a.box.lo], hi: [...a.box.hi] };
  }
  return b;
}

// Takes each actor's newest frame: normals, box, GPU buffers. Whether any was new.
function takeFrames() {
  let any = false;
  for (const a of page.actors) {
    const f = a && a.pending;
    if (!f || f === a.drawn) continue;
    a.seen = a.seen || f.states.some((s) => s !== HELD);
    if (!a.weld) a.weld = weldMap(f.vertices);
    computeNormals(f.vertices, a.t.triangles, a.weld, a.normals);
    if (renderer) renderer.setMesh(a.gpu, f.vertices, a.normals);
    a.box = bounds(f.vertices);
    a.drawn = f; any = true;
    if (f.receivedTime > 0) { page.latencies.push(nowUnixMs() - 1000 * f.receivedTime); if (page.latencies.length > 240) page.latencies.shift(); }
  }
  return any;
}

// Screen position of world point `p` under `viewProj`, in normalised device
// coordinates (x, y in -1..1 on screen), or null behind the camera.
function project(viewProj, p) {
  const v = [0, 1, 2, 3].map((r) => viewProj[r] * p[0] + viewProj[4 + r] * p[1] + viewProj[8 + r] * p[2] + viewProj[12 + r]);
  return v[3] > 0 ? [v[0] / v[3], v[1] / v[3]] : null;
}

// Puts each shown actor's label above its head, moving a label up while it would cover
// one placed before it (two performers side by side).
function placeLabels(viewProj) {
  const placed = [];
  for (const a of page.actors) {
    if (!a) continue;
    // A stage of one needs no name over its one character.
    const s = a.t.actorCount > 1 && a.seen && a.box && project(viewProj, [0.5 * (a.box.lo[0] + a.box.hi[0]), a.box.hi[1], 0.5 * (a.box.lo[2] + a.box.hi[2])]);
    if (!s) { if (a.label.style.display !== "none") a.label.style.display = "none"; continue; }
    const held = a.drawn.states.every((st) => st === HELD);
    const text = a.t.actor + (held ? " (no marker in view: holding)" : "");
    // Measured only when the text changes (a read after a change costs a layout).
    if (a.label.textContent !== text || a.label.style.display !== "block") {
      a.label.textContent = text; a.label.style.display = "block";
      a.labelSize = [a.label.offsetWidth, a.label.offsetHeight];
    }
    const x = (0.5 + 0.5 * s[0]) * canvas.clientWidth, [w, h] = a.labelSize;
    let y = (0.5 - 0.5 * s[1]) * canvas.clientHeight;
    // The label's box: centred on x, its bottom a little above y (as the CSS places it).
    const box = (yy) => ({ l: x - w / 2, r: x + w / 2, t: yy - 1.3 * h, b: yy - 0.3 * h });
    for (let moved = true, k = 0; moved && k < 16; k++) {
      moved = false;
      for (const o of placed) {
        const b = box(y);
        if (b.l < o.r && o.l < b.r && b.t < o.b && o.t < b.b) { y = o.t + 0.3 * h - 2; moved = true; }
      }
    }
    placed.push(box(y));
    a.label.style.left = `${x}px`;
    a.label.style.top = `${y}px`;
  }
}

let overlay = { markers: 0, lineVertices: 0 };
let lastViewProj = null;
function draw() {
  requestAnimationFrame(draw);
  if (takeFrames()) {
    const shown = page.actors.filter((a) => a && a.seen && a.drawn);
    overlay = overlayOf(shown);
    if (renderer) renderer.setOverlay(overlay.pos, overlay.col);
    page.drawnCount++; page.drawTimes.push(performance.now());
    const box = sceneBox();
    if (box && !page.framed) { camera.frame(box); page.framed = true; } else if (box && camera.follow) camera.track(box);
    // The overlay speaks of the frames on screen (at most four times a second).
    if (performance.now() - lastOverlay >= 250) updateOverlay();
  }
  if (renderer && page.actors.length) {
    const eye = camera.eye(), d = Math.hypot(eye[0] - camera.target[0], eye[1] - camera.target[1], eye[2] - camera.target[2]) || 1;
    const key = [(eye[0] - camera.target[0]) / d, (eye[1] - camera.target[1]) / d + 0.5, (eye[2] - camera.target[2]) / d];
    const kl = Math.hypot(...key);
    const viewProj = camera.viewProj(canvas.clientWidth / Math.max(1, canvas.clientHeight));
    const meshes = page.actors.filter((a) => a && a.seen && a.drawn).map((a) => ({ gpu: a.gpu, rgb: ACTOR_RGB[a.t.actorIndex % ACTOR_RGB.length] }));
    renderer.draw(viewProj, key.map((x) => x / kl), meshes, overlay.markers, overlay.lineVertices);
    placeLabels(viewProj);
    lastViewProj = viewProj;
  }
}

let lastOverlay = 0;
function updateOverlay() {
  const now = performance.now();
  lastOverlay = now;
  stateEl.textContent = page.state + (page.error ? ` · error: ${page.error}` : "");
  stateEl.className = page.state === "connected" ? "connected" : "waiting";
  const actors = page.actors.filter(Boolean);
  if (!actors.length) { statsEl.textContent = ""; return; }
  const lines = [`drawn ${rate(page.drawTimes, now).toFixed(1)} fps · received ${rate(page.recvTimes, now).toFixed(1)} fps · solver ${actors[0].t.rateHz} Hz`];
  const lat = median(page.latencies);
  lines.push(`latency ${Number.isFinite(lat) ? lat.toFixed(1) + " ms" : "n/a"} (marker received → drawn, median)`);
  lines.push(`camera ${camera.follow ? "follows every actor" : "free (F: follow again)"}`);
  for (const a of actors) {
    const t = a.t, f = a.drawn, name = t.actor === t.character ? t.character : `${t.actor} (${t.character})`;
    lines.push(`${name} · ${t.vertexCount} vertices · ${t.markerNames.length} markers`);
    if (!f) continue;
    const counts = [0, 0, 0, 0];
    for (const s of f.states) counts[Math.min(s, HELD)]++;
    lines.push(`  frame ${f.frame} · solve ${f.solveMs.toFixed(2)} ms · ${f.iterations} iterations (${f.stop})`);
    lines.push(`  markers ${counts[0]} measured · ${counts[1]} predicted · ${counts[2]} rigid-filled · ${counts[3]} held` + (a.seen ? "" : " · not drawn before a marker is in view"));
  }
  statsEl.textContent = "\n" + lines.join("\n");
}

window.addEventListener("keydown", (e) => {
  if (e.key === "f" || e.key === "F") { camera.follow = true; camera.frame(sceneBox()); }
});

// For tests and scripts: the page's state, read-only. `topology` and `snapshot` are the
// first actor's; `actors()` describes each.
const first = () => page.actors[0];
window.rigless = {
  get state() { return page.state; },
  get connects() { return page.connects; },
  get framesReceived() { return page.received; },
  get framesDrawn() { return page.drawnCount; },
  get error() { return page.error; },
  get follow() { return camera.follow; },
  get topology() { const a = first(), t = a && a.t; return t && { character: t.character, actor: t.actor, actors: t.actorCount, vertexCount: t.vertexCount, triangleCount: t.triangles.length / 3, markers: t.markerNames.length, joints: t.jointNames.length }; },
  stats() { const now = performance.now(); return { drawnFps: rate(page.drawTimes, now), receivedFps: rate(page.recvTimes, now), latencyMsMedian: median(page.latencies), latencyMs: [...page.latencies] }; },
  // The first actor's drawn frame's number, and its vertices and joints as plain arrays.
  snapshot() { const f = first() && first().drawn; return f && { frame: f.frame, vertices: Array.from(f.vertices), joints: Array.from(f.joints), states: Array.from(f.states) }; },
  // Each actor: its name, whether it is drawn, its frame, its label, and where the
  // corners of its box fall on the picture (normalised device coordinates, -1..1 inside).
  actors() {
    return page.actors.filter(Boolean).map((a) => {
      const ndc = a.box && lastViewProj ? corners(a.box).map((c) => project(lastViewProj, c)) : [];
      const xs = ndc.map((p) => (p ? p[0] : Infinity)), ys = ndc.map((p) => (p ? p[1] : Infinity));
      return { index: a.t.actorIndex, name: a.t.actor, character: a.t.character, shown: a.seen && !!a.drawn, frame: a.drawn ? a.drawn.frame : null,
        label: a.label.style.display === "none" ? null : a.label.textContent,
        ndc: ndc.length ? { minX: Math.min(...xs), maxX: Math.max(...xs), minY: Math.min(...ys), maxY: Math.max(...ys) } : null };
    });
  },
};

connect();
requestAnimationFrame(draw);
// Without frames (connecting, reconnecting) the overlay still follows the state.
setInterval(() => { if (performance.now() - lastOverlay >= 250) updateOverlay(); }, 250);
