// The app served under a sub-folder (/nkrr/, as a project page or a docs site would host it):
// every asset loads relative to the page, the page gets ready, and a reconstruction runs.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { browser, openPage, requireDist, DIST, EVAL } from './harness.mjs';

const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.wasm': 'application/wasm', '.css': 'text/css', '.ply': 'application/octet-stream' };

/** Serves dist/ under /nkrr/ only: anything asked from the site's root is a 404 (and counted). */
async function serveUnder(prefix) {
  const rootHits = [];
  const server = http.createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    let file = null;
    if (url === '/data/spot-3k.ply') file = path.join(EVAL, 'spot-3k.ply');
    else if (url.startsWith(prefix)) file = path.join(DIST, url === prefix ? 'index.html' : url.slice(prefix.length));
    else rootHits.push(url);
    if (!file || !file.startsWith(DIST) && !file.startsWith(EVAL)) { res.writeHead(404).end(); return; }
    fs.readFile(file, (err, data) => {
      if (err) { res.writeHead(404).end(); return; }
      res.writeHead(200, { 'content-type': TYPES[path.extname(file)] ?? 'application/octet-stream' });
      res.end(data);
    });
  });
  await new Promise((r) => server.listen(0, '127.0.0.1', r));
  return { server, url: `http://127.0.0.1:${server.address().port}`, rootHits };
}

test('served under a sub-folder, the app loads its assets relative to the page and reconstructs', { timeout: 240_000 }, async () => {
  requireDist();
  const srv = await serveUnder('/nkrr/');
  const b = await browser();
  try {
    const { page, errors } = await openPage(b, `${srv.url}/nkrr/?cloud=/data/spot-3k.ply&method=network&resolution=64&run`);
    await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 90_000 });
    assert.equal(await page.evaluate(() => document.body.dataset.state), 'ready', await page.textContent('#message'));
    // Styled: the stylesheet under /nkrr/ applied (the body is not the browser's default white).
    const bg = await page.evaluate(() => getComputedStyle(document.body).backgroundColor);
    assert.notEqual(bg, 'rgba(0, 0, 0, 0)', 'the stylesheet did not load');
    await page.waitForFunction(() => document.body.dataset.outcome, null, { timeout: 200_000 });
    assert.equal(await page.evaluate(() => document.body.dataset.outcome), 'done', await page.textContent('#message'));
    assert.deepEqual(srv.rootHits.filter((u) => u !== '/favicon.ico'), [], 'assets asked from the site root');
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
    srv.server.close();
  }
});
