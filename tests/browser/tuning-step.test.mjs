// The browser build's CPU share of one tuning step (issue 15): with a real GPU the objective's
// n-sized products run on the device, and the f64 m × m algebra (Cholesky factors, inverses,
// the gradient's m × m products) runs in wasm at every step. This measures it at m = 500 and
// m = 1000 through the wasm export tuning_step_ms: on the page's main thread (the plain build,
// one thread) and in the reconstruction worker, which runs the threaded build on every core
// where the page is cross-origin isolated, as this server makes it (issue 27). It writes
// artifacts/tuning-step.json; it is a benchmark that prints figures, so it asserts only that the
// step ran and gave a time, never how fast.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { serve, browser, openPage, requireDist, DIST, ARTIFACTS, ISOLATED } from './harness.mjs';

let srv;
before(async () => {
  requireDist();
  srv = await serve(DIST, {}, ISOLATED);
});
after(() => srv?.server.close());

test('one tuning step\'s m x m algebra, timed in the browser build', async () => {
  const b = await browser();
  try {
    const { page, errors } = await openPage(b, `${srv.url}/`);
    await page.waitForFunction(() => window.wasmBindings?.tuning_step_ms, null, { timeout: 90_000 });
    const ms500 = await page.evaluate(() => window.wasmBindings.tuning_step_ms(500, 3));
    const ms1000 = await page.evaluate(() => window.wasmBindings.tuning_step_ms(1000, 1));
    const simd = await page.evaluate(() => WebAssembly.validate(new Uint8Array([
      0, 97, 115, 109, 1, 0, 0, 0, 1, 5, 1, 96, 0, 1, 123, 3, 2, 1, 0, 10, 10, 1, 8, 0, 65, 0, 253, 15, 253, 98, 11])));
    // The worker's: its own instance, the threaded build on its pool.
    await page.waitForFunction(() => document.body.dataset.worker === 'ready', null, { timeout: 120_000 });
    const w500 = await page.evaluate(() => window.nkrrReconstructor.tuningStepMs(500, 3));
    const w1000 = await page.evaluate(() => window.nkrrReconstructor.tuningStepMs(1000, 1));
    const result = {
      m500_ms: ms500, m1000_ms: ms1000, worker_threads: w500.threads, worker_m500_ms: w500.ms, worker_m1000_ms: w1000.ms,
      wasm_simd_supported: simd, cores: await page.evaluate(() => navigator.hardwareConcurrency), userAgent: await page.evaluate(() => navigator.userAgent),
    };
    console.log(`tuning step, CPU share in the browser build: m 500 ${ms500.toFixed(1)} ms, m 1000 ${ms1000.toFixed(1)} ms on one thread; `
      + `in the worker on ${w500.threads} threads: m 500 ${w500.ms.toFixed(1)} ms, m 1000 ${w1000.ms.toFixed(1)} ms (wasm SIMD supported: ${simd})`);
    fs.mkdirSync(ARTIFACTS, { recursive: true });
    fs.writeFileSync(path.join(ARTIFACTS, 'tuning-step.json'), JSON.stringify(result, null, 1));
    for (const v of [ms500, ms1000, w500.ms, w1000.ms]) assert.ok(Number.isFinite(v) && v > 0, `no time measured: ${v}`);
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});
