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

// A mesh goes to the GPU a chunk of 12.6M array elements at a time (src/web/viewer.rs), so the
// page's wasm memory never holds a big scene's whole mesh: a triangle whose vertices lie past the
// first chunk is drawn where it belongs, an index out of range is refused, and a replaced mesh's
// buffers are let go.
test('a mesh larger than one upload chunk is drawn whole; a bad index is refused', { timeout: 180_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await openPage(b, srv.url);
    await page.waitForFunction(() => document.body.dataset.state === 'ready', null, { timeout: 90_000 });
    const r = await page.evaluate(async () => {
      const v = window.nkrrViewer;
      const n = 4_300_000; // 12.9M floats: the last vertices are in the second chunk
      const positions = new Float32Array(3 * n);
      const normals = new Float32Array(3 * n);
      positions.set([-1, -1, 0, 1, -1, 0, 0, 1, 0], 3 * (n - 3));
      for (let i = n - 3; i < n; i++) normals[3 * i + 2] = 1;
      const triangle = new Uint32Array([n - 3, n - 2, n - 1]);
      const before = v.gpu_bytes();
      v.set_mesh(positions, normals, triangle);
      const held = v.gpu_bytes() - before;
      let refused = '';
      try { v.set_mesh(positions, normals, new Uint32Array([0, 1, n])); } catch (e) { refused = e.message; }
      const meshAfterRefusal = v.has_mesh;
      // The triangle drawn from the second chunk's vertices; the wireframe was not asked for.
      v.set_mesh(positions, normals, triangle);
      const heldAgain = v.gpu_bytes() - before;
      v.set_visible(false, true);
      v.fit();
      return { held, heldAgain, refused, n, meshAfterRefusal, coverage: await v.coverage(), wire: v.has_wireframe };
    });
    assert.match(r.refused, new RegExp(`index ${r.n} is out of range`));
    assert.equal(r.meshAfterRefusal, false, 'a refused mesh leaves no mesh behind');
    assert.ok(r.held >= 2 * 12 * r.n, `${r.held} bytes on the GPU for ${r.n} vertices`);
    assert.equal(r.heldAgain, r.held, 'the same mesh set again holds the same buffers, not twice');
    assert.ok(r.coverage > 0.05, `coverage ${r.coverage}`);
    assert.equal(r.wire, false);
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
