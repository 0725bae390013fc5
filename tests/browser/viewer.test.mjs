// The page as a user meets it: load, pick a scan from tests/data/eval, see it.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { serve, browser, openPage, requireDist, DIST, EVAL, ARTIFACTS } from './harness.mjs';

let srv;
before(async () => { requireDist(); srv = await serve(DIST); fs.mkdirSync(ARTIFACTS, { recursive: true }); });
after(() => srv?.server.close());

test('a PLY picked in the file input is parsed by wasm and drawn', { timeout: 180_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await openPage(b, srv.url);
    await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 90_000 });
    assert.equal(await page.evaluate(() => document.body.dataset.state), 'ready',
      `page did not become ready: ${await page.textContent('#message')}`);
    await page.setInputFiles('#file-input', path.join(EVAL, 'spot-3k.ply'));
    await page.waitForFunction(() => document.body.dataset.loaded === 'spot-3k.ply', null, { timeout: 60_000 });
    assert.equal(await page.textContent('#point-count'), '3,000');
    assert.match(await page.textContent('#layout'), /binary_little_endian/);
    // The cloud really is on screen: an offscreen render of the same view covers pixels.
    const coverage = await page.evaluate(() => window.nkrrViewer.coverage());
    assert.ok(coverage > 0.01 && coverage < 0.9, `coverage ${coverage}`);
    // The frame clock a scene's preview is spaced by (web/app.js): the GPU's time for the last
    // frame, reported once its work is done.
    await page.waitForFunction(() => window.nkrrViewer.frame_ms > 0 && !window.nkrrViewer.frame_in_flight, null, { timeout: 30_000 });
    await page.waitForTimeout(300);
    await page.screenshot({ path: path.join(ARTIFACTS, 'viewer-spot-3k.png') });
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});

test('a malformed PLY gives a clear error, not a crash', { timeout: 120_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await openPage(b, srv.url);
    await page.waitForFunction(() => document.body.dataset.state === 'ready', null, { timeout: 90_000 });
    const bad = Buffer.from('ply\nformat binary_little_endian 1.0\nelement vertex 2147483648\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x00\x00');
    await page.setInputFiles('#file-input', { name: 'huge.ply', mimeType: 'application/octet-stream', buffer: bad });
    await page.waitForSelector('#message.error', { timeout: 30_000 });
    const msg = await page.textContent('#message');
    assert.match(msg, /huge\.ply/);
    assert.match(msg, /vertex/i);
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});

test('without WebGPU the page says so and names browsers that have it', { timeout: 120_000 }, async () => {
  const b = await browser({ webgpu: false });
  try {
    const { page } = await openPage(b, srv.url);
    await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 60_000 });
    assert.equal(await page.evaluate(() => document.body.dataset.state), 'no-webgpu');
    assert.match(await page.textContent('#message'), /WebGPU.*Chrome/s);
  } finally {
    await b.close();
  }
});
