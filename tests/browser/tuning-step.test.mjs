// The browser build's CPU share of one tuning step (issue 15): with a real GPU the objective's
// n-sized products run on the device, and the f64 m × m algebra (Cholesky factors, inverses,
// the gradient's m × m products) runs in wasm on one thread at every step. This measures it at
// m = 500 and m = 1000 through the wasm export tuning_step_ms and writes
// artifacts/tuning-step.json; it is a benchmark that prints figures, so it asserts only that the
// step ran and gave a time, never how fast.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { serve, browser, openPage, requireDist, DIST, ARTIFACTS } from './harness.mjs';

let srv;
before(async () => {
  requireDist();
  srv = await serve(DIST);
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
    const result = { m500_ms: ms500, m1000_ms: ms1000, wasm_simd_supported: simd, userAgent: await page.evaluate(() => navigator.userAgent) };
    console.log(`tuning step, CPU share in the browser build: m 500 ${ms500.toFixed(1)} ms, m 1000 ${ms1000.toFixed(1)} ms (wasm SIMD supported: ${simd})`);
    fs.mkdirSync(ARTIFACTS, { recursive: true });
    fs.writeFileSync(path.join(ARTIFACTS, 'tuning-step.json'), JSON.stringify(result, null, 1));
    for (const v of [ms500, ms1000]) assert.ok(Number.isFinite(v) && v > 0, `no time measured: ${v}`);
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});
