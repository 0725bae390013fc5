// The page's threaded build (wasm atomics, a pool of Web Workers: scripts/web_threads.sh) where
// the page is cross-origin isolated, against the plain build (`?threads=1`) on the same cloud:
// the worker starts its pool, reports its threads, and makes the same GLB to the byte, since
// every kernel splits its output, never a sum. Times are printed (artifacts/threads.json), not
// asserted: a benchmark, not a timed test.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { serve, browser, openPage, requireDist, runToEnd, DIST, EVAL, ARTIFACTS, ISOLATED } from './harness.mjs';

// nkrr on a 500-point cloud tunes (the linear algebra of every step) and runs the last fit and
// the stray-point filter (the per-point loops); a 3k cloud takes the Poisson surface instead.
const CLOUDS = [
  { file: path.join(EVAL, 'suzanne-500.ply'), method: 'nkrr' },
  { file: path.join(EVAL, 'spot-3k.ply'), method: 'nkrr' },
];

let srv;
before(async () => {
  requireDist();
  assert.ok(fs.existsSync(path.join(DIST, 'threads', 'nkrr_bg.wasm')), 'dist/threads/ is missing: the web build makes it (scripts/web_threads.sh)');
  srv = await serve(DIST, {}, ISOLATED);
});
after(() => srv?.server.close());

async function run(b, query, { file, method }) {
  const { page, errors } = await openPage(b, `${srv.url}/${query}`);
  await page.waitForFunction(() => document.body.dataset.state === 'ready' && document.body.dataset.worker, null, { timeout: 120_000 });
  assert.equal(await page.evaluate(() => document.body.dataset.worker), 'ready', await page.textContent('#message'));
  const info = await page.evaluate(() => ({ isolated: crossOriginIsolated, cores: navigator.hardwareConcurrency, threads: Number(document.body.dataset.threads), footer: document.getElementById('adapter').textContent }));
  await page.setInputFiles('#file-input', file);
  await page.waitForFunction((n) => document.body.dataset.loaded === n, path.basename(file), { timeout: 60_000 });
  await page.selectOption('#method', method);
  await page.selectOption('#resolution', '64');
  const seconds = await runToEnd(page, 600_000);
  assert.equal(await page.evaluate(() => document.body.dataset.outcome), 'done', await page.textContent('#message'));
  const download = page.waitForEvent('download');
  await page.evaluate(() => document.getElementById('download').click());
  const glb = fs.readFileSync(await (await download).path());
  await page.close();
  return { ...info, seconds, glb, errors };
}

test('the threaded build runs where the page is isolated and makes the plain build\'s mesh to the byte', async () => {
  const b = await browser();
  const out = [];
  try {
    for (const cloud of CLOUDS) {
      const threaded = await run(b, '', cloud);
      const plain = await run(b, '?threads=1', cloud);
      assert.ok(threaded.isolated, 'the test server sends COOP/COEP: the page must be cross-origin isolated');
      assert.equal(threaded.threads, Math.min(threaded.cores, 16), `threads: ${threaded.footer}`);
      assert.equal(plain.threads, 1);
      assert.match(threaded.footer, new RegExp(`CPU: ${threaded.threads} thread`));
      assert.ok(threaded.glb.equals(plain.glb), `${path.basename(cloud.file)}: the GLBs differ (${threaded.glb.length} and ${plain.glb.length} bytes)`);
      assert.deepEqual([...threaded.errors, ...plain.errors], []);
      const row = { cloud: path.basename(cloud.file), method: cloud.method, threads: threaded.threads, threaded_s: threaded.seconds, plain_s: plain.seconds, ratio: threaded.seconds / plain.seconds, bytes: threaded.glb.length };
      console.log(`${row.cloud} ${row.method}: ${row.threads} threads ${row.threaded_s.toFixed(1)} s, one thread ${row.plain_s.toFixed(1)} s (${row.ratio.toFixed(2)}x), same ${row.bytes}-byte GLB`);
      out.push(row);
    }
  } finally {
    await b.close();
  }
  fs.mkdirSync(ARTIFACTS, { recursive: true });
  fs.writeFileSync(path.join(ARTIFACTS, 'threads.json'), JSON.stringify(out, null, 1));
});
