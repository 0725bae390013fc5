// Shared pieces of the browser tests: a static server for dist/ on 127.0.0.1 and Debian's
// Chromium driven by playwright-core, with WebGPU on SwiftShader; and readers for the GLBs the
// page downloads.
import assert from 'node:assert/strict';
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

export const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
export const DIST = path.join(ROOT, 'dist');
export const EVAL = path.join(ROOT, 'tests/data/eval');
export const ARTIFACTS = path.join(ROOT, 'artifacts');

const TYPES = {
  '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript', '.cjs': 'text/javascript', '.wasm': 'application/wasm',
  '.css': 'text/css', '.ply': 'application/octet-stream', '.glb': 'model/gltf-binary', '.json': 'application/json',
  '.webmanifest': 'application/manifest+json', '.svg': 'image/svg+xml',
};

/** The headers that make a page cross-origin isolated, as trunk serves the app (Trunk.toml): the
 *  shared cancel flag and the worker's threaded build need them. For `serve`'s `headers`. */
export const ISOLATED = { 'Cross-Origin-Opener-Policy': 'same-origin', 'Cross-Origin-Embedder-Policy': 'require-corp' };

/** Serves `dir` on 127.0.0.1 (a free port); extra routes map URL paths to files; `headers` are
 *  added to every response (e.g. COOP/COEP for cross-origin isolation). */
export async function serve(dir, extra = {}, headers = {}) {
  const server = http.createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    let file = extra[url] ?? path.join(dir, url === '/' ? 'index.html' : url);
    if (!file.startsWith(dir) && !Object.values(extra).includes(file)) { res.writeHead(403).end(); return; }
    fs.readFile(file, (err, data) => {
      if (err) { res.writeHead(404).end('not found'); return; }
      res.writeHead(200, { ...headers, 'content-type': TYPES[path.extname(file)] ?? 'application/octet-stream' });
      res.end(data);
    });
  });
  await new Promise((r) => server.listen(0, '127.0.0.1', r));
  return { server, url: `http://127.0.0.1:${server.address().port}` };
}

/** Debian's Chromium, headless; `webgpu: false` leaves WebGPU off (the negative control);
 *  `args`: more command-line flags (e.g. --js-flags=--expose-gc). */
export async function browser({ webgpu = true, args: extra = [] } = {}) {
  if (!fs.existsSync('/usr/bin/chromium')) throw new Error('no /usr/bin/chromium: run scripts/setup.sh apt');
  const args = [
    '--no-sandbox', '--no-first-run', '--disable-background-networking', '--disable-component-update',
    '--disable-sync', '--disable-quic', '--disable-dev-shm-usage',
  ];
  // WebGPU on SwiftShader. The Vulkan/ANGLE flags matter as soon as a page presents to a
  // WebGPU canvas: without them the GPU process finds no shared-image backing for the swap
  // chain, dies, and every later buffer map fails ("no valid external Instance").
  if (webgpu) args.push('--enable-unsafe-webgpu', '--use-angle=vulkan', '--enable-features=Vulkan', '--use-vulkan=swiftshader');
  args.push(...extra);
  return chromium.launch({ executablePath: '/usr/bin/chromium', headless: true, args });
}

/** A page that records console errors and uncaught exceptions. */
export async function openPage(b, url) {
  const page = await b.newPage({ viewport: { width: 1200, height: 760 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  await page.goto(url);
  return { page, errors };
}

export function requireDist() {
  if (!fs.existsSync(path.join(DIST, 'index.html'))) {
    throw new Error('dist/ is missing: build it with NKRR_BUILD_ONLY=1 scripts/serve.sh');
  }
}

/** A GLB's JSON, its root node, the first primitive's accessors read as arrays (`vertices`:
 *  the position count), and the positions' min/max. */
export function readGlb(buf) {
  assert.equal(buf.readUInt32LE(0), 0x46546c67, 'glTF magic');
  assert.equal(buf.readUInt32LE(4), 2, 'glTF version 2');
  assert.equal(buf.readUInt32LE(8), buf.length, 'GLB length field');
  const jsonLen = buf.readUInt32LE(12);
  assert.equal(buf.readUInt32LE(16), 0x4e4f534a, 'JSON chunk');
  const json = JSON.parse(buf.subarray(20, 20 + jsonLen).toString('utf8'));
  const binAt = 20 + jsonLen;
  assert.equal(buf.readUInt32LE(binAt + 4), 0x004e4942, 'BIN chunk');
  const bin = buf.subarray(binAt + 8, binAt + 8 + buf.readUInt32LE(binAt));
  const COMPONENTS = { SCALAR: 1, VEC3: 3, VEC4: 4 };
  const READ = { 5121: [1, (o) => bin.readUInt8(o)], 5125: [4, (o) => bin.readUInt32LE(o)], 5126: [4, (o) => bin.readFloatLE(o)] };
  const read = (index) => {
    const acc = json.accessors[index];
    const view = json.bufferViews[acc.bufferView];
    const n = COMPONENTS[acc.type];
    const [size, get] = READ[acc.componentType];
    const stride = view.byteStride ?? n * size;
    const start = (view.byteOffset ?? 0) + (acc.byteOffset ?? 0);
    const out = new Float64Array(acc.count * n);
    for (let i = 0; i < acc.count; i++) for (let c = 0; c < n; c++) out[i * n + c] = get(start + i * stride + c * size);
    return { acc, n, data: out };
  };
  const prim = json.meshes[0].primitives[0];
  const positions = read(prim.attributes.POSITION);
  const indices = read(prim.indices);
  assert.equal(indices.acc.componentType, 5125, 'u32 indices');
  const colors = prim.attributes.COLOR_0 === undefined ? null : read(prim.attributes.COLOR_0);
  return { json, node: json.nodes[json.scenes[json.scene ?? 0].nodes[0]], prim, positions, indices, colors, vertices: positions.acc.count, min: positions.acc.min, max: positions.acc.max };
}

/** Every directed edge once, and its reverse present: closed and consistently oriented. */
export function watertight(indices, vertices) {
  const edges = new Map();
  for (let t = 0; t < indices.length; t += 3) {
    for (let k = 0; k < 3; k++) {
      const key = indices[t + k] * vertices + indices[t + ((k + 1) % 3)];
      edges.set(key, (edges.get(key) ?? 0) + 1);
    }
  }
  let bad = 0;
  for (const [key, n] of edges) {
    const a = Math.floor(key / vertices), b = key % vertices;
    if (n !== 1 || edges.get(b * vertices + a) !== 1) bad++;
  }
  return { edges: edges.size, bad };
}

/** Presses Reconstruct and waits (up to `timeout` ms) until the run has ended; its seconds. */
export async function runToEnd(page, timeout) {
  const t0 = Date.now();
  // Not page.click: its wait for a stable layout counts animation frames, which SwiftShader
  // delivers slowly while it draws millions of points.
  await page.evaluate(() => document.getElementById('run').click());
  // Started (and maybe already ended, if it failed at once).
  await page.waitForFunction(() => document.body.dataset.job === 'running' || document.body.dataset.outcome, null, { timeout: 30_000 });
  await page.waitForFunction(() => document.body.dataset.job === 'idle', null, { timeout, polling: 250 });
  return (Date.now() - t0) / 1000;
}
