// Shared pieces of the browser tests: a static server for dist/ on 127.0.0.1 and Debian's
// Chromium driven by playwright-core, with WebGPU on SwiftShader.
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

export const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
export const DIST = path.join(ROOT, 'dist');
export const EVAL = path.resolve(ROOT, '../shared/data/eval');
export const ARTIFACTS = path.join(ROOT, 'artifacts');

const TYPES = {
  '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript', '.wasm': 'application/wasm',
  '.css': 'text/css', '.ply': 'application/octet-stream', '.glb': 'model/gltf-binary', '.json': 'application/json',
};

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

/** Debian's Chromium, headless; `webgpu: false` leaves WebGPU off (the negative control). */
export async function browser({ webgpu = true } = {}) {
  if (!fs.existsSync('/usr/bin/chromium')) throw new Error('no /usr/bin/chromium: run scripts/setup.sh apt');
  const args = [
    '--no-sandbox', '--no-first-run', '--disable-background-networking', '--disable-component-update',
    '--disable-sync', '--disable-quic', '--disable-dev-shm-usage',
  ];
  // WebGPU on SwiftShader. The Vulkan/ANGLE flags matter as soon as a page presents to a
  // WebGPU canvas: without them the GPU process finds no shared-image backing for the swap
  // chain, dies, and every later buffer map fails ("no valid external Instance").
  if (webgpu) args.push('--enable-unsafe-webgpu', '--use-angle=vulkan', '--enable-features=Vulkan', '--use-vulkan=swiftshader');
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
