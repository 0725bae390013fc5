// Offline (issue 17): after one visit the app works with the network off. The first load
// registers the service worker (web/sw.js), which keeps the page, its modules and the wasm
// module (with the network's weights); then the network is cut (the browser context goes
// offline and the server is closed), the page is reloaded and a cloud from the disk is
// reconstructed to the end.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import { serve, browser, requireDist, runToEnd, DIST, EVAL } from './harness.mjs';

let srv;
before(async () => {
  requireDist();
  srv = await serve(DIST);
});
after(() => srv?.server.close());

const ready = (page) => page.waitForFunction(() => document.body.dataset.state, null, { timeout: 90_000 });

test('after one visit the app loads and reconstructs with the network off', { timeout: 600_000 }, async () => {
  const b = await browser();
  try {
    const page = await b.newPage({ viewport: { width: 1200, height: 760 } });
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    await page.goto(`${srv.url}/`);
    await ready(page);
    await page.waitForFunction(() => document.body.dataset.offline === 'registered', null, { timeout: 60_000 });
    // Installed: the worker is active and its copy holds the app shell, the wasm included.
    const kept = await page.evaluate(async () => {
      await navigator.serviceWorker.ready;
      const keys = await (await caches.open('nkrr-app')).keys();
      return keys.map((r) => new URL(r.url).pathname);
    });
    for (const f of ['/index.html', '/nkrr.js', '/nkrr_bg.wasm', '/web/app.js', '/web/worker.js', '/style.css']) {
      assert.ok(kept.includes(f), `${f} is not in the offline copy: ${kept.join(', ')}`);
    }

    // The network goes away: no server, and the browser offline.
    await new Promise((r) => srv.server.close(r));
    srv = null;
    await page.context().setOffline(true);
    await page.reload();
    await ready(page);
    assert.equal(await page.evaluate(() => document.body.dataset.state), 'ready', await page.textContent('#message'));
    assert.equal(await page.evaluate(() => navigator.onLine), false);
    assert.ok(await page.evaluate(() => !!navigator.serviceWorker.controller), 'the page should be served by the worker');

    await page.setInputFiles('#file-input', path.join(EVAL, 'spot-3k.ply'));
    await page.waitForFunction(() => document.body.dataset.loaded === 'spot-3k.ply', null, { timeout: 60_000 });
    await page.selectOption('#method', 'network');
    await page.selectOption('#resolution', '64');
    const seconds = await runToEnd(page, 300_000);
    assert.equal(await page.evaluate(() => document.body.dataset.outcome), 'done', await page.textContent('#message'));
    console.log(`offline reconstruction: ${seconds.toFixed(1)} s`);
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});
