// Drives rigless's browser viewer in headless Chromium against a running `rigless demo`,
// as a user would open it, and checks it: frames advance, the page's vertices change and
// equal the vertex stream's for the same frame number (bytes read by a TCP client here),
// the character covers part of the picture, and the page reconnects by itself after the
// daemon restarts. With --actors 2 (the two-actor demo), it also follows each actor over
// a few seconds: drawn once its markers appear, labelled, and inside the picture.
// Prints one JSON line of measurements; exits 1 on a failed check.
//
//   node viewer_check.mjs RIGLESS_BINARY OUT_DIR [--character hand|body] [--actors 2]
//
// CHROMIUM names the browser (default /usr/bin/chromium). tests/browser_viewer.rs runs it.

import { chromium } from "playwright-core";
import { spawn } from "node:child_process";
import net from "node:net";
import fs from "node:fs";
import path from "node:path";

const [bin, outDir] = process.argv.slice(2, 4);
const flag = (name, dflt) => process.argv.includes(name) ? process.argv[process.argv.indexOf(name) + 1] : dflt;
const character = flag("--character", "hand"), actors = Number(flag("--actors", "1"));
if (!bin || !outDir) { console.error("usage: node viewer_check.mjs RIGLESS_BINARY OUT_DIR"); process.exit(2); }
const browserPath = process.env.CHROMIUM || "/usr/bin/chromium";
// Longest wait for anything the page or the daemon should do, ms.
const WAIT_MS = 30000;

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const fail = (what) => { throw new Error(what); };

async function freePort() {
  return new Promise((resolve, reject) => {
    const s = net.createServer();
    s.on("error", reject);
    s.listen(0, "127.0.0.1", () => { const p = s.address().port; s.close(() => resolve(p)); });
  });
}

// Starts `rigless demo` looping and resolves once it prints the viewer's address.
function startDemo(tcpPort, viewerPort) {
  const cast = actors > 1 ? ["--actors", String(actors)] : ["--character", character];
  const child = spawn(bin, ["demo", ...cast, "--loop", "--seconds", "120",
    "--stream", `127.0.0.1:${tcpPort}`, "--viewer", `127.0.0.1:${viewerPort}`, "--rerun", "off"],
  { stdio: ["ignore", "pipe", "pipe"] });
  let out = "", err = "";
  child.stderr.on("data", (d) => { err += d; });
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`the demo printed no viewer address in ${WAIT_MS} ms: ${err}`)), WAIT_MS);
    child.stdout.on("data", (d) => {
      out += d;
      const m = out.match(/viewer: open (http:\/\/\S+) in a browser/);
      if (m) { clearTimeout(timer); resolve({ child, url: m[1] }); }
    });
    child.on("exit", (code) => { clearTimeout(timer); reject(new Error(`the demo exited (${code}): ${err}`)); });
  });
}

async function stopDemo(child) {
  if (child.exitCode !== null) return;
  const exited = new Promise((r) => child.on("exit", r));
  child.kill("SIGINT");
  await Promise.race([exited, sleep(10000).then(() => child.kill("SIGKILL"))]);
}

// A TCP client of the vertex stream keeping the vertices of the last frames of actor 0
// (the page's snapshot's) by number.
function streamClient(port) {
  const frames = new Map();
  let buf = Buffer.alloc(0);
  const sock = net.connect(port, "127.0.0.1");
  sock.on("data", (d) => {
    buf = Buffer.concat([buf, d]);
    while (buf.length >= 12) {
      const version = buf.readUInt16LE(4), kind = buf.readUInt16LE(6), len = buf.readUInt32LE(8);
      if (buf.length < 12 + len) break;
      const p = buf.subarray(12, 12 + len);
      if (kind === 2 && p[27] === 0) {
        const frame = Number(p.readBigUInt64LE(0));
        const nm = p.readUInt32LE(56);
        let at = 60 + nm + ((4 - nm % 4) % 4) + 12 * nm;
        const nv = p.readUInt32LE(at); at += 4;
        const v = new Float32Array(3 * nv);
        for (let i = 0; i < 3 * nv; i++) v[i] = p.readFloatLE(at + 4 * i);
        frames.set(frame, { v, version });
        if (frames.size > 2000) frames.delete(frames.keys().next().value);
      }
      buf = buf.subarray(12 + len);
    }
  });
  sock.on("error", () => {});
  return { frames, close: () => sock.destroy() };
}

// Reads the page's actors every 250 ms for 6 s: how often each was drawn, labelled, and
// inside the picture (every corner of its box within the normalised -1..1), and the
// worst corner seen.
async function followActors(page) {
  await page.waitForFunction((n) => window.rigless.actors().filter((a) => a.shown).length >= n, actors, { timeout: WAIT_MS });
  const seen = {};
  for (let k = 0; k < 24; k++) {
    for (const a of await page.evaluate(() => window.rigless.actors())) {
      const s = seen[a.name] ??= { samples: 0, shown: 0, labelled: 0, inside: 0, worst: 0 };
      s.samples++;
      if (!a.shown) continue;
      s.shown++;
      if (a.label && a.label.startsWith(a.name)) s.labelled++;
      const w = Math.max(Math.abs(a.ndc.minX), Math.abs(a.ndc.maxX), Math.abs(a.ndc.minY), Math.abs(a.ndc.maxY));
      s.worst = Math.max(s.worst, w);
      if (w <= 1) s.inside++;
    }
    await sleep(250);
  }
  await page.screenshot({ path: path.join(outDir, "actors.png") });
  return { follow: await page.evaluate(() => window.rigless.follow), each: seen };
}

async function main() {
  fs.mkdirSync(outDir, { recursive: true });
  const [tcpPort, viewerPort] = [await freePort(), await freePort()];
  let demo = await startDemo(tcpPort, viewerPort);
  const client = streamClient(tcpPort);
  const browser = await chromium.launch({
    executablePath: browserPath,
    headless: true,
    args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
      "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"],
  });
  const result = { url: demo.url };
  try {
    const page = await browser.newPage({ viewport: { width: 960, height: 720 } });
    const errors = [];
    page.on("pageerror", (e) => errors.push(String(e)));
    await page.goto(demo.url);
    await page.waitForFunction(() => window.rigless && window.rigless.framesDrawn > 30, null, { timeout: WAIT_MS });
    result.topology = await page.evaluate(() => window.rigless.topology);

    // Frames advance, vertices change, and equal the stream's for the same frame.
    let compared = 0, maxDiff = 0, changed = 0, advanced = 0;
    for (let attempt = 0; attempt < 20 && compared < 5; attempt++) {
      const a = await page.evaluate(() => window.rigless.snapshot());
      await sleep(150);
      const b = await page.evaluate(() => window.rigless.snapshot());
      if (b.frame > a.frame) advanced++;
      let d = 0;
      for (let i = 0; i < a.vertices.length; i++) d = Math.max(d, Math.abs(a.vertices[i] - b.vertices[i]));
      if (d > 0) changed++;
      for (const s of [a, b]) {
        const ref = client.frames.get(s.frame);
        if (!ref) continue;
        if (ref.v.length !== s.vertices.length) fail(`frame ${s.frame}: ${s.vertices.length / 3} vertices in the page, ${ref.v.length / 3} in the stream`);
        for (let i = 0; i < ref.v.length; i++) maxDiff = Math.max(maxDiff, Math.abs(ref.v[i] - s.vertices[i]));
        compared++;
      }
    }
    Object.assign(result, { compared_frames: compared, max_vertex_diff_m: maxDiff, reads_advanced: advanced, reads_changed: changed });

    // Let it run a few seconds, then read the page's own rates and latency.
    await sleep(3000);
    const stats = await page.evaluate(() => window.rigless.stats());
    const lat = [...stats.latencyMs].sort((x, y) => x - y);
    Object.assign(result, {
      drawn_fps: stats.drawnFps, received_fps: stats.receivedFps,
      latency_ms_p50: lat[Math.floor(lat.length / 2)], latency_ms_p90: lat[Math.floor(lat.length * 0.9)],
      latency_samples: lat.length,
    });

    // The picture: pixels of the character's colour (warm: red well above blue) against
    // the blue-grey background.
    await page.screenshot({ path: path.join(outDir, "viewer.png") });
    result.pixels = await page.evaluate(() => {
      const src = document.getElementById("view");
      const c = document.createElement("canvas"); c.width = src.width; c.height = src.height;
      const ctx = c.getContext("2d"); ctx.drawImage(src, 0, 0);
      const d = ctx.getImageData(0, 0, c.width, c.height).data;
      // Markers in any fill state's colour: which state a marker is in at the moment of
      // the picture depends on how late the replay's samples are on a loaded machine.
      let skin = 0, marker = 0;
      for (let i = 0; i < d.length; i += 4) {
        const [r, g, b] = [d[i], d[i + 1], d[i + 2]];
        const measured = g > 180 && r < 120 && b < 140;
        const predicted = r > 200 && g > 150 && b < 60;
        const rigid = b > 200 && r < 150;
        const held = r > 200 && g < 90 && b < 90;
        if (measured || predicted || rigid || held) marker++;
        else if (r > 60 && r > b + 40 && r >= g) skin++;
      }
      return { total: d.length / 4, skin, marker };
    });

    if (actors > 1) result.actors = await followActors(page);

    // Restart the daemon on the same ports: the page reconnects by itself.
    const before = await page.evaluate(() => ({ connects: window.rigless.connects, drawn: window.rigless.framesDrawn }));
    await stopDemo(demo.child);
    await page.waitForFunction(() => window.rigless.state !== "connected", null, { timeout: WAIT_MS });
    const restartAt = Date.now();
    demo = await startDemo(tcpPort, viewerPort);
    await page.waitForFunction((n) => window.rigless.connects > n, before.connects, { timeout: WAIT_MS });
    await page.waitForFunction((n) => window.rigless.framesDrawn > n + 30, before.drawn, { timeout: WAIT_MS });
    result.reconnect = { connects: await page.evaluate(() => window.rigless.connects), seconds_to_frames: (Date.now() - restartAt) / 1000 };
    result.page_errors = errors.concat(await page.evaluate(() => window.rigless.error ? [window.rigless.error] : []));
  } finally {
    await browser.close();
    client.close();
    await stopDemo(demo.child);
  }
  console.log(JSON.stringify(result));
}

main().catch((e) => { console.error(`viewer check failed: ${e.stack || e}`); process.exit(1); });
