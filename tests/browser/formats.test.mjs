// The scan formats on the page: LAS/LAZ, E57 and text clouds picked through the file input (or
// opened from a share link), told apart by content; the cloud panel (format, layout,
// attributes, units guess, memory preflight); reconstruction of each with the GLB checked
// (far-off origin as the root translation, colours, units scaling); and a file that is none of
// the formats, which is an error message and leaves the page working.
//
// Network method at 64³ throughout, to keep the runs short on SwiftShader.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { serve, browser, requireDist, readGlb, runToEnd, watertight, DIST, EVAL, ARTIFACTS, ROOT } from './harness.mjs';

const FIXTURES = path.join(ROOT, 'tests/fixtures/formats');
const MANIFEST = JSON.parse(fs.readFileSync(path.join(FIXTURES, 'manifest.json'), 'utf8'));
// spot-3k.ply's exact bounds (all 3000 points), and the offset the LAS/LAZ fixtures add.
const SPOT = { min: MANIFEST.colour_formula.min, max: MANIFEST.colour_formula.max };
const LAS_OFFSET = MANIFEST.las_common.offset_added; // [5e6, 5e6, 100]
const RUN_TIMEOUT = 600_000;
const MM_FILE = path.join(os.tmpdir(), 'nkrr-spot-mm.xyz');

let srv;
before(async () => {
  requireDist();
  fs.mkdirSync(ARTIFACTS, { recursive: true });
  // spot-3k in millimetres as an XYZ text cloud (x y z per line, no header).
  const spot = plyPoints(fs.readFileSync(path.join(EVAL, 'spot-3k.ply')));
  const lines = [];
  for (let i = 0; i < spot.length; i += 3) lines.push([0, 1, 2].map((a) => (spot[i + a] * 1000).toFixed(3)).join(' '));
  fs.writeFileSync(MM_FILE, `${lines.join('\n')}\n`);
  srv = await serve(DIST, { '/data/spot-mm.xyz': MM_FILE });
});
after(() => {
  srv?.server.close();
  fs.rmSync(MM_FILE, { force: true });
});

/** x y z of a binary little-endian PLY whose vertices are exactly `float x, float y, float z`. */
function plyPoints(buf) {
  const end = buf.indexOf('end_header\n') + 'end_header\n'.length;
  const header = buf.subarray(0, end).toString('latin1');
  assert.match(header, /format binary_little_endian 1\.0\nelement vertex \d+\nproperty float x\nproperty float y\nproperty float z\nend_header\n$/);
  const n = Number(header.match(/element vertex (\d+)/)[1]);
  const out = new Float32Array(3 * n);
  for (let i = 0; i < 3 * n; i++) out[i] = buf.readFloatLE(end + 4 * i);
  return out;
}

async function newPage(b, url) {
  const page = await b.newPage({ viewport: { width: 1200, height: 760 }, acceptDownloads: true });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  await page.goto(url);
  await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 90_000 });
  assert.equal(await page.evaluate(() => document.body.dataset.state), 'ready',
    `page did not become ready: ${await page.textContent('#message')}`);
  return { page, errors };
}

/** Picks `file` (a path, or { name, mimeType, buffer }) and waits until the page has loaded it. */
async function load(page, file) {
  const name = typeof file === 'string' ? path.basename(file) : file.name;
  await page.setInputFiles('#file-input', file);
  await page.waitForFunction((n) => document.body.dataset.loaded === n || document.querySelector('#message.error')?.textContent.includes(n), name, { timeout: 60_000 });
  assert.equal(await page.evaluate(() => document.body.dataset.loaded), name, await page.textContent('#message'));
}

/** The cloud panel, as text. */
const panel = (page) => page.evaluate(() => {
  const t = (id) => document.getElementById(id).textContent;
  return {
    name: t('file-name'), count: t('point-count'), format: t('format'), layout: t('layout'),
    attributes: t('attributes'), units: t('units-guess'), unitsWarn: document.getElementById('units-guess').classList.contains('warn'),
    preflight: [...document.querySelectorAll('#preflight-lines li')].map((l) => l.textContent),
    preflightSummary: t('preflight-summary'), preflightWarn: document.getElementById('preflight').classList.contains('warn'),
    warnings: [...document.querySelectorAll('#warnings li')].map((l) => l.textContent),
  };
});

async function reconstruct(page) {
  await page.selectOption('#method', 'network');
  await page.selectOption('#resolution', '64');
  const seconds = await runToEnd(page, RUN_TIMEOUT);
  assert.equal(await page.evaluate(() => document.body.dataset.outcome), 'done', await page.textContent('#message'));
  return seconds;
}

/** Downloads the GLB, saves it under artifacts/, validates it (Khronos) and reads it. */
async function downloadGlb(page, expectedName) {
  const [download] = await Promise.all([page.waitForEvent('download'), page.click('#download')]);
  assert.equal(download.suggestedFilename(), expectedName);
  const file = path.join(ARTIFACTS, `formats-${expectedName}`);
  await download.saveAs(file);
  // Exit code 0: no errors and no warnings.
  execFileSync('node', [path.join(ROOT, 'tests/validate_glb.mjs'), file], { stdio: 'pipe' });
  return readGlb(fs.readFileSync(file));
}

/** The mesh's box (positions + root translation) against `want`, within `frac` of the extent per axis. */
function assertBoundsNear(glb, want, frac, label) {
  const t = glb.node.translation ?? [0, 0, 0];
  for (let a = 0; a < 3; a++) {
    const tol = frac * (want.max[a] - want.min[a]);
    const lo = glb.min[a] + t[a], hi = glb.max[a] + t[a];
    assert.ok(Math.abs(lo - want.min[a]) <= tol, `${label}, axis ${a}: mesh min ${lo} vs ${want.min[a]} (tolerance ${tol})`);
    assert.ok(Math.abs(hi - want.max[a]) <= tol, `${label}, axis ${a}: mesh max ${hi} vs ${want.max[a]} (tolerance ${tol})`);
  }
}

test('LAZ (LAS 1.4, point format 7, far-off coordinates, colours): panel, preflight, reconstruction with origin and colours', { timeout: RUN_TIMEOUT + 120_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await newPage(b, srv.url);
    await load(page, path.join(FIXTURES, 'spot-las14-pf7.laz'));
    const p = await panel(page);
    assert.equal(p.name, 'spot-las14-pf7.laz');
    assert.equal(p.count, '3,000');
    assert.equal(p.format, 'LAS/LAZ');
    assert.match(p.layout, /point format 7/);
    assert.match(p.layout, /LAZ-compressed/);
    assert.match(p.attributes, /^colours/);
    assert.equal(p.unitsWarn, false, p.units);
    // Bounds in the file's coordinates (x ≈ 5e6 − 0.47), and the origin they were read against.
    const bounds = await page.textContent('#bounds');
    assert.match(bounds, /^\[4999999\.534, 4999999\.252, 99\.32\d\]/, bounds);
    assert.match(bounds, /read relative to \[5000000, 5000000, 0\]/, bounds);
    // One line per stage, the limits, and no "will …" line: it all fits.
    for (const stage of ['load', 'features', 'meshing', 'finish']) {
      assert.ok(p.preflight.some((l) => new RegExp(`^${stage}\\s+GPU\\s+[\\d.]+ MiB`).test(l)), `no ${stage} line in ${JSON.stringify(p.preflight)}`);
    }
    assert.ok(p.preflight.some((l) => /^limits\s/.test(l)), JSON.stringify(p.preflight));
    assert.ok(!p.preflight.some((l) => l.startsWith('will ')), JSON.stringify(p.preflight));
    assert.equal(p.preflightSummary, 'Memory: fits this GPU');
    assert.equal(p.preflightWarn, false);
    await page.evaluate(() => { document.getElementById('preflight').open = true; });
    await page.waitForTimeout(300);
    await page.screenshot({ path: path.join(ARTIFACTS, 'formats-laz-panel.png') });

    const seconds = await reconstruct(page);
    assert.equal(await page.textContent('#r-watertight'), 'yes');
    // The preflight follows the settings (64³ now) and still fits.
    assert.equal(await page.textContent('#preflight-summary'), 'Memory: fits this GPU');

    const glb = await downloadGlb(page, 'spot-las14-pf7.glb');
    // The origin (the first point's x and y rounded; z is near enough to 0 to stay) is the root
    // translation, so the f32 positions keep their precision.
    const t = glb.node.translation;
    assert.ok(Array.isArray(t), `no root translation: ${JSON.stringify(glb.node)}`);
    const origin = [LAS_OFFSET[0], LAS_OFFSET[1], 0];
    for (let a = 0; a < 3; a++) assert.ok(Math.abs(t[a] - origin[a]) <= 1, `translation ${t} vs ${origin}`);
    const lasBounds = { min: SPOT.min.map((v, a) => v + LAS_OFFSET[a]), max: SPOT.max.map((v, a) => v + LAS_OFFSET[a]) };
    assertBoundsNear(glb, lasBounds, 0.08, 'LAZ');
    const w = watertight(glb.indices.data, glb.vertices);
    assert.equal(w.bad, 0, `${w.bad} of ${w.edges} directed edges lack a unique reverse`);

    // COLOR_0 carries the cloud's colours: the fixture's colour is a ramp over the original
    // coordinates (r from x, g from y, b from z), so each vertex's colour should match its place.
    assert.ok(glb.colors, `no COLOR_0 in ${JSON.stringify(glb.prim.attributes)}`);
    assert.equal(glb.colors.acc.count, glb.positions.acc.count);
    let err = 0;
    const nv = glb.positions.acc.count;
    for (let i = 0; i < nv; i++) {
      for (let a = 0; a < 3; a++) {
        const x = glb.positions.data[3 * i + a] + t[a] - LAS_OFFSET[a];
        const want = 255 * (x - SPOT.min[a]) / (SPOT.max[a] - SPOT.min[a]);
        err += Math.abs(glb.colors.data[glb.colors.n * i + a] - want);
      }
    }
    const meanErr = err / (3 * nv);
    assert.ok(meanErr < 20, `COLOR_0 is ${meanErr.toFixed(1)} (of 255) from the colour ramp on average`);
    console.log(`LAZ: ${seconds.toFixed(1)} s; ${nv} vertices; translation ${t.join(', ')}; COLOR_0 mean error ${meanErr.toFixed(2)}/255`);

    // The viewer draws the mesh in those colours: most of its pixels are saturated (the grey
    // mesh of an uncoloured cloud has almost none: the spot-3k test checks that).
    await page.uncheck('#show-cloud');
    const saturation = await page.evaluate(() => window.nkrrViewer.saturation());
    assert.ok(saturation > 0.3, `only ${(100 * saturation).toFixed(1)}% of the mesh's pixels are coloured`);
    await page.waitForTimeout(300);
    await page.screenshot({ path: path.join(ARTIFACTS, 'reconstruct-laz-colours.png') });
    await page.check('#show-cloud');
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});

test('E57 with two posed scans: panel, stated metres, a watertight mesh where spot-3k is', { timeout: RUN_TIMEOUT + 120_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await newPage(b, srv.url);
    await load(page, path.join(FIXTURES, 'spot-two-scans.e57'));
    const p = await panel(page);
    assert.equal(p.count, '3,000');
    assert.equal(p.format, 'E57');
    assert.match(p.layout, /\b2 scans\b/);
    assert.match(p.units, /^m \(the file states m\)/);
    assert.equal(p.unitsWarn, false);
    assert.match(p.attributes, /^colours/);
    assert.equal(p.preflightSummary, 'Memory: fits this GPU');

    const seconds = await reconstruct(page);
    assert.equal(await page.textContent('#r-watertight'), 'yes');
    const glb = await downloadGlb(page, 'spot-two-scans.glb');
    const w = watertight(glb.indices.data, glb.vertices);
    assert.equal(w.bad, 0, `${w.bad} of ${w.edges} directed edges lack a unique reverse`);
    assert.equal(glb.node.translation, undefined);
    assert.ok(glb.colors, 'no COLOR_0');
    // Both scans' poses applied: the mesh covers spot-3k (a wrong pose would move half of it).
    assertBoundsNear(glb, SPOT, 0.08, 'E57');
    console.log(`E57 two scans: ${seconds.toFixed(1)} s; ${glb.positions.acc.count} vertices`);
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});

test('a text cloud in millimetres: the units warning, units=mm scales the mesh to metres, the share link keeps units', { timeout: RUN_TIMEOUT + 120_000 }, async () => {
  const b = await browser();
  try {
    // Opened from a URL, so the page offers a share link (it does so only for such clouds).
    const { page, errors } = await newPage(b, `${srv.url}/?cloud=/data/spot-mm.xyz&method=network&resolution=64`);
    await page.waitForFunction(() => document.body.dataset.loaded === 'spot-mm.xyz' || document.querySelector('#message.error'), null, { timeout: 90_000 });
    assert.equal(await page.evaluate(() => document.body.dataset.loaded), 'spot-mm.xyz', await page.textContent('#message'));
    const p = await panel(page);
    assert.equal(p.count, '3,000');
    assert.match(p.format, /^text/);
    assert.equal(p.unitsWarn, true, p.units);
    assert.match(p.units, /^mm\?/);
    assert.ok(p.warnings.some((w) => /millimetres/.test(w)), JSON.stringify(p.warnings));
    assert.equal(await page.inputValue('#units'), '');
    assert.equal(new URL(await page.getAttribute('#share', 'href')).searchParams.has('units'), false);

    await page.selectOption('#units', 'mm');
    const share = new URL(await page.getAttribute('#share', 'href'));
    assert.equal(share.searchParams.get('cloud'), '/data/spot-mm.xyz');
    assert.equal(share.searchParams.get('units'), 'mm');

    const seconds = await reconstruct(page);
    // Units were given: no "no units given" notice on the result.
    assert.ok(!/no units given/.test(await page.textContent('#r-notices')), await page.textContent('#r-notices'));
    const glb = await downloadGlb(page, 'spot-mm.glb');
    assert.equal(glb.node.translation, undefined);
    // Scaled by 1/1000: the mesh is spot-3k's size in metres (tolerance as in reconstruct.test.mjs).
    assertBoundsNear(glb, SPOT, 0.1, 'mm → m');
    console.log(`mm text cloud: ${seconds.toFixed(1)} s; mesh box [${glb.min.map((v) => v.toFixed(3))}] – [${glb.max.map((v) => v.toFixed(3))}]`);
    assert.deepEqual(errors, []);

    // The share link sets the units when opened (without `run`, to skip a second reconstruction).
    share.searchParams.delete('run');
    const again = await newPage(b, share.href);
    await again.page.waitForFunction(() => document.body.dataset.loaded === 'spot-mm.xyz', null, { timeout: 90_000 });
    assert.equal(await again.page.inputValue('#units'), 'mm');
    assert.equal(new URL(await again.page.getAttribute('#share', 'href')).searchParams.get('units'), 'mm');
    assert.deepEqual(again.errors, []);
  } finally {
    await b.close();
  }
});

test('a file in none of the formats is an error message naming the problem; the page keeps working', { timeout: 180_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await newPage(b, srv.url);
    // 64 pseudo-random bytes (not text: they hold NULs and high bytes), named like a LAS file.
    let seed = 7;
    const junk = Buffer.alloc(64);
    for (let i = 0; i < junk.length; i++) junk[i] = (seed = (seed * 1103515245 + 12345) % 2147483648) >> 16 & 0xff;
    junk[0] = 0x00;
    await page.setInputFiles('#file-input', { name: 'junk.las', mimeType: 'application/octet-stream', buffer: junk });
    await page.waitForSelector('#message.error', { timeout: 30_000 });
    const msg = await page.textContent('#message');
    assert.match(msg, /junk\.las/);
    assert.match(msg, /not a point cloud nkrr can read/);
    assert.equal(await page.isVisible('#cloud-info'), false);
    assert.equal(await page.isDisabled('#run'), true);

    // Files that start like a format and then break off are errors too, not crashes.
    const laz = fs.readFileSync(path.join(FIXTURES, 'spot-las14-pf7.laz'));
    const e57 = fs.readFileSync(path.join(FIXTURES, 'spot-two-scans.e57'));
    for (const [name, buffer, pattern] of [
      ['cut.laz', laz.subarray(0, 400), /LAS\/LAZ/],
      ['cut-points.laz', laz.subarray(0, Math.floor(laz.length / 2)), /LAS\/LAZ/],
      ['cut.e57', e57.subarray(0, 2048), /E57/],
    ]) {
      await page.evaluate(() => document.getElementById('message').classList.remove('error'));
      await page.setInputFiles('#file-input', { name, mimeType: 'application/octet-stream', buffer });
      await page.waitForFunction(() => document.querySelector('#message.error') || document.body.dataset.loaded, null, { timeout: 30_000 });
      const m = await page.textContent('#message');
      console.log(`${name}: ${m}`);
      assert.ok(await page.$('#message.error'), `${name}: no error shown (loaded: ${await page.evaluate(() => document.body.dataset.loaded)})`);
      assert.match(m, new RegExp(`Could not read ${name.replace('.', '\\.')}: `));
      assert.match(m, pattern);
    }

    // A valid file afterwards loads as usual.
    await load(page, path.join(FIXTURES, 'spot-las12-pf0.las'));
    assert.equal(await page.isVisible('#message'), false);
    const p = await panel(page);
    assert.equal(p.count, '3,000');
    assert.equal(p.format, 'LAS/LAZ');
    assert.match(p.layout, /point format 0/);
    assert.match(p.attributes, /^no colours/);
    assert.equal(await page.isDisabled('#run'), false);

    // A bad file after a good one: the error, and the good cloud stays loaded and shown.
    await page.setInputFiles('#file-input', { name: 'junk.las', mimeType: 'application/octet-stream', buffer: junk });
    await page.waitForSelector('#message.error', { timeout: 30_000 });
    assert.match(await page.textContent('#message'), /not a point cloud nkrr can read/);
    assert.equal(await page.evaluate(() => document.body.dataset.loaded), 'spot-las12-pf0.las');
    assert.equal(await page.isVisible('#cloud-info'), true);
    assert.equal(await page.textContent('#file-name'), 'spot-las12-pf0.las');
    assert.equal(await page.isDisabled('#run'), false);
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});
