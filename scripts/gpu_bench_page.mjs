// The browser half of the GPU benchmark (scripts/gpu_bench.py runs it, once per run): serves a
// built web app, opens it in headless Chromium with WebGPU on the machine's GPU (or on
// SwiftShader), loads one cloud, runs one method to the end and prints one JSON line:
//   { ok, wall_s, worker_s, stages: { stage: seconds }, adapter_page, adapter_worker, adapter_info,
//     software, ready_s, outcome, message, errors }
// wall_s: from pressing Reconstruct to the page being idle again (the worker's engine is
// prepared when the page loads, so page load and the wasm's compilation are outside it, in
// ready_s); worker_s and stages: the worker's own stats (src/web/worker_api.rs: setup, the
// pipeline's stages, glb).
//
//   node scripts/gpu_bench_page.mjs --dist DIST --cloud CLOUD.ply --method nkrr|network
//        [--gpu real|swiftshader] [--chromium /usr/bin/chromium] [--timeout-s 600] [--resolution N]
//        [--threads N]
//
// The app is served cross-origin isolated (COOP/COEP), as trunk serves it (Trunk.toml), so the
// worker runs the threaded build on every core unless --threads says otherwise (1: the plain
// build); `threads` in the output is what it ran on.
//
// Reuses tests/browser/harness.mjs (the static server, runToEnd); playwright-core comes from the
// repository's node_modules.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { chromium } from 'playwright-core';
import { serve, runToEnd, ISOLATED } from '../tests/browser/harness.mjs';

/** Chromium's flags for WebGPU in headless mode. `real`: the machine's GPU through Vulkan
 *  (Dawn's Vulkan backend; ANGLE on Vulkan so that the page's canvas has a shared-image
 *  backing; the GPU blocklist ignored, since server GPUs and headless setups are often on it;
 *  no Vulkan surface, there is no display). `swiftshader`: the browser tests' software Vulkan. */
export function chromiumFlags(gpu) {
  const args = [
    '--no-sandbox', '--no-first-run', '--disable-background-networking', '--disable-component-update',
    '--disable-sync', '--disable-quic', '--disable-dev-shm-usage', '--enable-unsafe-webgpu', '--use-angle=vulkan',
  ];
  if (gpu === 'real') {
    args.push('--enable-features=Vulkan,VulkanFromANGLE,DefaultANGLEVulkan', '--ignore-gpu-blocklist',
      '--enable-gpu', '--disable-vulkan-surface', '--disable-software-rasterizer');
  } else {
    args.push('--enable-features=Vulkan', '--use-vulkan=swiftshader', '--use-webgpu-adapter=swiftshader');
  }
  return args;
}

async function main() {
  const { values: a } = parseArgs({
    options: {
      dist: { type: 'string' }, cloud: { type: 'string' }, method: { type: 'string', default: 'nkrr' },
      gpu: { type: 'string', default: 'real' }, chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
      'timeout-s': { type: 'string', default: '600' }, resolution: { type: 'string' }, threads: { type: 'string' },
    },
  });
  const out = { ok: false, errors: [] };
  if (!a.dist || !fs.existsSync(path.join(a.dist, 'index.html'))) throw new Error(`--dist ${a.dist}: no index.html`);
  if (!a.cloud || !fs.existsSync(a.cloud)) throw new Error(`--cloud ${a.cloud}: no such file`);
  if (!['real', 'swiftshader'].includes(a.gpu)) throw new Error(`--gpu ${a.gpu}: real or swiftshader`);
  if (!fs.existsSync(a.chromium)) throw new Error(`no Chromium at ${a.chromium} (set CHROMIUM=/path/to/chrome)`);
  const deadline = Date.now() + 1000 * Number(a['timeout-s']);
  const left = () => Math.max(1000, deadline - Date.now());
  const dist = path.resolve(a.dist);
  const srv = await serve(dist, {}, ISOLATED);
  const b = await chromium.launch({ executablePath: a.chromium, headless: true, args: chromiumFlags(a.gpu) });
  try {
    const page = await b.newPage({ viewport: { width: 1200, height: 760 } });
    page.on('pageerror', (e) => out.errors.push(String(e)));
    page.on('console', (m) => { if (m.type() === 'error') out.errors.push(m.text()); });
    const t0 = Date.now();
    await page.goto(a.threads ? `${srv.url}/?threads=${Number(a.threads)}` : srv.url);
    await page.waitForFunction(() => document.body.dataset.state, null, { timeout: left() });
    const state = await page.evaluate(() => document.body.dataset.state);
    out.adapter_page = (await page.textContent('#adapter')).replace(/^GPU: /, '');
    out.software = (await page.evaluate(() => document.body.dataset.software)) === 'true';
    // wgpu names a browser's adapter "unnamed adapter": WebGPU's own GPUAdapterInfo says more
    // (vendor and architecture, e.g. "nvidia hopper" or "google swiftshader").
    out.adapter_info = await page.evaluate(async () => {
      const ad = await navigator.gpu?.requestAdapter({ powerPreference: 'high-performance' });
      const i = ad?.info;
      return i ? { vendor: i.vendor, architecture: i.architecture, device: i.device, description: i.description } : null;
    });
    if (state !== 'ready') {
      out.message = `page not ready (${state}): ${await page.textContent('#message')}`;
      return out;
    }
    // The worker's engine too (the page prepares it on load), so that wall_s is the run alone.
    out.adapter_worker_ready = await page.evaluate(() => window.nkrrReconstructor.prepare());
    out.ready_s = (Date.now() - t0) / 1000;
    out.threads = await page.evaluate(() => window.nkrrReconstructor.threads);
    // The run's full stats: the page's reconstructor, wrapped, keeps the last result's.
    await page.evaluate(() => {
      const r = window.nkrrReconstructor;
      const run = r.reconstruct.bind(r);
      r.reconstruct = async (...args) => { const res = await run(...args); window.__benchStats = res.stats; return res; };
    });
    await page.setInputFiles('#file-input', a.cloud);
    const name = path.basename(a.cloud);
    await page.waitForFunction((n) => document.body.dataset.loaded === n, name, { timeout: left() });
    await page.selectOption('#method', a.method);
    if (a.resolution) await page.selectOption('#resolution', a.resolution);
    out.wall_s = await runToEnd(page, left());
    out.outcome = await page.evaluate(() => document.body.dataset.outcome);
    const stats = await page.evaluate(() => window.__benchStats ?? null);
    if (out.outcome !== 'done' || !stats) {
      out.message = `run ended ${out.outcome}: ${await page.textContent('#message')}`;
      return out;
    }
    out.worker_s = stats.seconds;
    out.stages = Object.fromEntries(stats.timings.map((t) => [t.stage, t.seconds]));
    out.adapter_worker = stats.adapter;
    out.method = stats.method;
    out.resolution = stats.resolution;
    out.points = stats.points;
    out.triangles = stats.triangles;
    out.ok = true;
    return out;
  } finally {
    await b.close().catch(() => {});
    srv.server.close();
  }
}

if (import.meta.url === `file://${process.argv[1]}`) {
  main().then(
    (out) => { console.log(JSON.stringify(out)); process.exit(0); },
    (e) => { console.log(JSON.stringify({ ok: false, message: String(e.message ?? e).split('\n')[0] })); process.exit(1); },
  );
}
