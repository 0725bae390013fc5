// The layout from a phone to a wide screen: with a cloud loaded, the Reconstruct button and the
// message dock are inside the window without scrolling, the 3D view is usable, and the view's
// controls do not cover the drop zone. Screenshots go to artifacts/layout-*.png to be looked at.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import { serve, browser, requireDist, DIST, EVAL, ARTIFACTS } from './harness.mjs';

let srv;
before(async () => {
  requireDist();
  srv = await serve(DIST, { '/data/spot-3k.ply': path.join(EVAL, 'spot-3k.ply') });
});
after(() => srv?.server.close());

const SIZES = [
  { name: 'phone', width: 390, height: 844, minView: [350, 300] },
  { name: 'laptop', width: 1280, height: 800, minView: [800, 600] },
  { name: 'wide', width: 1920, height: 1080, minView: [1400, 900] },
];

for (const size of SIZES) {
  test(`layout at ${size.width}x${size.height} (${size.name}): main action, messages and the 3D view in reach`, { timeout: 180_000 }, async () => {
    const b = await browser();
    try {
      const page = await b.newPage({ viewport: { width: size.width, height: size.height } });
      const errors = [];
      page.on('pageerror', (e) => errors.push(String(e)));
      await page.goto(`${srv.url}/?cloud=/data/spot-3k.ply`);
      await page.waitForFunction(() => document.body.dataset.loaded === 'spot-3k.ply', null, { timeout: 90_000 });
      await page.waitForTimeout(300);
      const rect = (sel) => page.$eval(sel, (e) => { const r = e.getBoundingClientRect(); return { x: r.x, y: r.y, w: r.width, h: r.height }; });
      const inside = (r) => r.x >= 0 && r.y >= 0 && r.x + r.w <= size.width + 0.5 && r.y + r.h <= size.height + 0.5 && r.w > 0 && r.h > 0;
      // Every element id once: the settings form's ids come from the table's keys, and the
      // setting "fit" once took the id of the view's Fit button (it worked by wiring order only).
      const dupes = await page.evaluate(() => {
        const seen = new Map();
        for (const e of document.querySelectorAll('[id]')) seen.set(e.id, (seen.get(e.id) ?? 0) + 1);
        return [...seen].filter(([, n]) => n > 1).map(([id]) => id);
      });
      assert.deepEqual(dupes, [], `ids used more than once: ${dupes.join(', ')}`);
      const run = await rect('#run');
      assert.ok(inside(run), `Reconstruct is out of the window: ${JSON.stringify(run)}`);
      assert.equal(await page.isEnabled('#run'), true);
      // No mesh yet: its view box is neither checked nor usable.
      assert.deepEqual(await page.$eval('#show-mesh', (e) => [e.checked, e.disabled]), [false, true]);
      const dock = await rect('.dock');
      assert.ok(inside(dock), `the message dock is out of the window: ${JSON.stringify(dock)}`);
      const view = await rect('#view');
      assert.ok(view.w >= size.minView[0] && view.h >= size.minView[1], `3D view too small: ${JSON.stringify(view)}`);
      const controls = await rect('.view-controls');
      const drop = await rect('#drop-zone');
      const overlap = !(controls.x + controls.w <= drop.x || drop.x + drop.w <= controls.x || controls.y + controls.h <= drop.y || drop.y + drop.h <= controls.y);
      assert.ok(!overlap, `view controls ${JSON.stringify(controls)} cover the drop zone ${JSON.stringify(drop)}`);
      // A message shows in the dock, beside the button, and stays in the window.
      await page.evaluate(() => { const m = document.getElementById('message'); m.textContent = 'A message'; m.hidden = false; });
      assert.ok(inside(await rect('#message')), 'the message is out of the window');
      await page.evaluate(() => { document.getElementById('message').hidden = true; });
      await page.screenshot({ path: path.join(ARTIFACTS, `layout-${size.name}.png`) });
      assert.deepEqual(errors, []);
    } finally {
      await b.close();
    }
  });
}
