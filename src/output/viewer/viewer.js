// rigless browser viewer. Reads the vertex stream (protocols/vertex-stream.md, versions 1
// to 3) from the WebSocket on the page's own host and port, and draws the newest frame
// with WebGL 2: the mesh lit with normals recomputed every frame, the markers coloured by
// fill state, the fitted skeleton, and an overlay of rates, solve time and latency.
// Frames that arrive faster than the page draws are dropped (only the newest is kept);
// a closed connection is retried with a back-off. `window.rigless` exposes the state for
// tests and scripts.

import { decodeMessage, KIND_TOPOLOGY, KIND_FRAME, KIND_GOODBYE } from "./decode.js";

// Fill state colours: measured, predicted, rigid-filled, held.
const STATE_RGB = [[0.30, 0.85, 0.39], [1.0, 0.8, 0.0], [0.35, 0.78, 0.98], [1.0, 0.23, 0.19]];
const SKIN_RGB = [0.93, 0.62, 0.45];


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
    this.meshVao = gl.createVertexArray(); this.flatVao = gl.createVertexArray();
    this.buf = { pos: gl.createBuffer(), normal: gl.createBuffer(), index: gl.createBuffer(), fpos: gl.createBuffer(), fcol: gl.createBuffer() };
    this.indexCount = 0;
  }
  setTopology(t) {
    const gl = this.gl;
    gl.bindVertexArray(this.meshVao);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, this.buf.index);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, t.triangles, gl.STATIC_DRAW);
    this.indexCount = t.triangles.length;
    for (const [loc, b] of [[0, this.buf.pos], [1, this.buf.normal]]) {
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.bufferData(gl.ARRAY_BUFFER, 12 * t.vertexCount, gl.DYNAMIC_DRAW);
      gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
    }
    gl.bindVertexArray(this.flatVao);
    for (const [loc, b] of [[0, this.buf.fpos], [1, this.buf.fcol]]) {
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
    }
    gl.bindVertexArray(null);
  }
  setMesh(vertices, normals) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buf.pos); gl.bufferSubData(gl.ARRAY_BUFFER, 0, vertices);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buf.normal); gl.bufferSubData(gl.ARRAY_BUFFER, 0, normals);
  }
  // Markers (points) then bones (lines), drawn over the mesh.
  setOverlay(positions, colors) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buf.fpos); gl.bufferData(gl.ARRAY_BUFFER, positions, gl.DYNAMIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buf.fcol); gl.bufferData(gl.ARRAY_BUFFER, colors, gl.DYNAMIC_DRAW);
  }
  draw(viewProj, key, markerCount, lineVertexCount) {
    const gl = this.gl, dpr = window.devicePixelRatio || 1;
    const w = Math.floor(this.canvas.clientWidth * dpr), h = Math.floor(this.canvas.clientHeight * dpr);
    if (this.canvas.width !== w || this.canvas.height !== h) { this.canvas.width = w; this.canvas.height = h; }
    gl.viewport(0, 0, w, h);
    gl.clearColor(0.114, 0.141, 0.188, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(this.mesh);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.mesh, "uViewProj"), false, viewProj);
    gl.uniform3fv(gl.getUniformLocation(this.mesh, "uColor"), SKIN_RGB);
    gl.uniform3fv(gl.getUniformLocation(this.mesh, "uKey"), key);
    gl.bindVertexArray(this.meshVao);
    gl.drawElements(gl.TRIANGLES, this.indexCount, gl.UNSIGNED_INT, 0);
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

class Camera {
  constructor() { this.target = [0, 1, 0]; this.distance = 3; this.yaw = 0.4; this.pitch = 0.2; this.fov = 40 * Math.PI / 180; }
  eye() {
    const cp = Math.cos(this.pitch);
    return [this.target[0] + this.distance * cp * Math.sin(this.yaw), this.target[1] + this.distance * Math.sin(this.pitch),
      this.target[2] + this.distance * cp * Math.cos(this.yaw)];
  }
  viewProj(aspect) {
    const eye = this.eye();
    return mul(perspective(this.fov, aspect, this.distance / 100, this.distance * 100), lookAt(eye, this.target, [0, 1, 0]));
  }
  frame(pos) {
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < pos.length; i++) { const a = i % 3; if (Number.isFinite(pos[i])) { lo[a] = Math.min(lo[a], pos[i]); hi[a] = Math.max(hi[a], pos[i]); } }
    if (!(hi[0] >= lo[0])) return;
    this.target = [0, 1, 2].map((a) => 0.5 * (lo[a] + hi[a]));
    const radius = 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;
    this.distance = 1.15 * radius / Math.sin(this.fov / 2);
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
        const s = this.distance * 0.0015, cy = Math.cos(this.yaw), sy = Math.sin(this.yaw);
        this.target = [this.target[0] - s * dx * cy, this.target[1] + s * dy, this.target[2] + s * dx * sy];
      } else {
        this.yaw -= dx * 0.008;
        this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + dy * 0.008));
      }
    });
    canvas.addEventListener("wheel", (e) => { e.preventDefault(); this.distance *= Math.exp(e.deltaY * 0.001); }, { passive: false });
  }
}

// ---------------------------------------------------------------- the page

const stateEl = document.getElementById("state"), statsEl = document.getElementById("stats");
const canvas = document.getElementById("view");
const camera = new Camera();
camera.attach(canvas);
let renderer = null;
try { renderer = new Renderer(canvas); } catch (e) { stateEl.textContent = `cannot draw: ${e.message}`; }

const page = {
  state: "connecting", topology: null, pending: null, drawn: null, weld: null, normals: null,
  framed: false, connects: 0, goodbye: null, error: null,
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
  ws.onopen = () => { page.state = "connected"; page.connects++; backoffMs = 250; };
  ws.onmessage = (ev) => {
    let m;
    try { m = decodeMessage(ev.data); } catch (e) { page.error = e.message; ws.close(); return; }
    if (m.kind === KIND_TOPOLOGY) {
      page.topology = m.topology; page.pending = null; page.drawn = null; page.weld = null;
      page.normals = new Float32Array(3 * m.topology.vertexCount);
      if (renderer) renderer.setTopology(m.topology);
    } else if (m.kind === KIND_FRAME && page.topology) {
      if (m.frame.vertices.length !== 3 * page.topology.vertexCount) { page.error = "frame and topology disagree on the vertex count"; return; }
      page.pending = m.frame; page.received++; page.recvTimes.push(performance.now());
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

function overlayColors(t, f) {
  const nm = f.states.length, nj = f.joints.length / 3;
  let bones = 0;
  for (let j = 0; j < nj; j++) if (t.jointParents[j] >= 0 && t.jointParents[j] < nj) bones++;
  const pos = new Float32Array(3 * (nm + 2 * bones)), col = new Float32Array(pos.length);
  pos.set(f.markers, 0);
  for (let k = 0; k < nm; k++) col.set(STATE_RGB[f.states[k]] ?? STATE_RGB[3], 3 * k);
  let at = 3 * nm;
  for (let j = 0; j < nj; j++) {
    const p = t.jointParents[j];
    if (p < 0 || p >= nj) continue;
    pos.set(f.joints.subarray(3 * p, 3 * p + 3), at); col.set([0.95, 0.95, 0.95], at); at += 3;
    pos.set(f.joints.subarray(3 * j, 3 * j + 3), at); col.set([0.95, 0.95, 0.95], at); at += 3;
  }
  return { pos, col, markers: nm, lineVertices: 2 * bones };
}

let overlay = { markers: 0, lineVertices: 0 };
function draw() {
  requestAnimationFrame(draw);
  const t = page.topology, f = page.pending;
  if (renderer && t && f && f !== page.drawn) {
    if (!page.weld) page.weld = weldMap(f.vertices);
    computeNormals(f.vertices, t.triangles, page.weld, page.normals);
    renderer.setMesh(f.vertices, page.normals);
    const o = overlayColors(t, f);
    renderer.setOverlay(o.pos, o.col);
    overlay = o;
    if (!page.framed) { camera.frame(f.vertices); page.framed = true; }
    page.drawn = f; page.drawnCount++; page.drawTimes.push(performance.now());
    // The overlay speaks of the frame on screen (at most four times a second).
    if (performance.now() - lastOverlay >= 250) updateOverlay();
    if (f.receivedTime > 0) { page.latencies.push(nowUnixMs() - 1000 * f.receivedTime); if (page.latencies.length > 240) page.latencies.shift(); }
  }
  if (renderer && t) {
    const eye = camera.eye(), d = Math.hypot(eye[0] - camera.target[0], eye[1] - camera.target[1], eye[2] - camera.target[2]) || 1;
    const key = [(eye[0] - camera.target[0]) / d, (eye[1] - camera.target[1]) / d + 0.5, (eye[2] - camera.target[2]) / d];
    const kl = Math.hypot(...key);
    renderer.draw(camera.viewProj(canvas.clientWidth / Math.max(1, canvas.clientHeight)), key.map((x) => x / kl), overlay.markers, overlay.lineVertices);
  }
}

let lastOverlay = 0;
function updateOverlay() {
  const now = performance.now(), f = page.drawn, t = page.topology;
  lastOverlay = now;
  stateEl.textContent = page.state + (page.error ? ` · error: ${page.error}` : "");
  stateEl.className = page.state === "connected" ? "connected" : "waiting";
  if (!t) { statsEl.textContent = ""; return; }
  const lines = [`${t.character} · ${t.vertexCount} vertices · ${t.markerNames.length} markers · solver ${t.rateHz} Hz`];
  lines.push(`drawn ${rate(page.drawTimes, now).toFixed(1)} fps · received ${rate(page.recvTimes, now).toFixed(1)} fps`);
  if (f) {
    const counts = [0, 0, 0, 0];
    for (const s of f.states) counts[Math.min(s, 3)]++;
    const lat = median(page.latencies);
    lines.push(`frame ${f.frame} · solve ${f.solveMs.toFixed(2)} ms · ${f.iterations} iterations (${f.stop})`);
    lines.push(`latency ${Number.isFinite(lat) ? lat.toFixed(1) + " ms" : "n/a"} (marker received → drawn, median)`);
    lines.push(`markers ${counts[0]} measured · ${counts[1]} predicted · ${counts[2]} rigid-filled · ${counts[3]} held`);
  }
  statsEl.textContent = "\n" + lines.join("\n");
}

window.addEventListener("keydown", (e) => { if ((e.key === "f" || e.key === "F") && page.drawn) camera.frame(page.drawn.vertices); });

// For tests and scripts: the page's state, read-only.
window.rigless = {
  get state() { return page.state; },
  get connects() { return page.connects; },
  get framesReceived() { return page.received; },
  get framesDrawn() { return page.drawnCount; },
  get error() { return page.error; },
  get topology() { const t = page.topology; return t && { character: t.character, vertexCount: t.vertexCount, triangleCount: t.triangles.length / 3, markers: t.markerNames.length, joints: t.jointNames.length }; },
  stats() { const now = performance.now(); return { drawnFps: rate(page.drawTimes, now), receivedFps: rate(page.recvTimes, now), latencyMsMedian: median(page.latencies), latencyMs: [...page.latencies] }; },
  // The drawn frame's number, and its vertices and joints as plain arrays.
  snapshot() { const f = page.drawn; return f && { frame: f.frame, vertices: Array.from(f.vertices), joints: Array.from(f.joints), states: Array.from(f.states) }; },
};

connect();
requestAnimationFrame(draw);
// Without frames (connecting, reconnecting) the overlay still follows the state.
setInterval(() => { if (performance.now() - lastOverlay >= 250) updateOverlay(); }, 250);
