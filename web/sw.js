// The offline copy of the app (issue 17): a service worker that keeps everything the page needs
// (the page, its modules, the wasm module, which carries the network's weights, and the style),
// so that after one visit nkrr installs and works with the network off, as a one-job tool
// should (Squoosh is the model).
//
// Network first, the cache as the fallback: online, every load gets the files as served now
// (with the browser's own HTTP cache in front), so an update is never hidden behind an old
// copy; offline, the copy from the last visit answers. Every successful load of one of these
// files is written back, so the copy follows the deployed version. Paths are relative to this file, so
// the app works offline under any sub-path too.

const CACHE = 'nkrr-app';
const SHELL = [
  './', './index.html', './style.css', './nkrr.js', './nkrr_bg.wasm', './manifest.webmanifest',
  './web/app.js', './web/reconstructor.js', './web/worker.js', './web/settings.js', './web/result.js',
  './web/util.js', './web/test-hooks.js', './web/icon.svg', './meshopt_decoder.mjs', './meshopt_decoder.cjs',
  // The threaded build (cross-origin isolated pages); its pool's worker snippet, whose folder
  // name carries a hash, is kept when first loaded (THREADS below).
  './threads/nkrr.js', './threads/nkrr_bg.wasm',
];
const THREADS = new URL('./threads/', self.location).pathname;

self.addEventListener('install', (event) => {
  event.waitUntil(caches.open(CACHE).then((c) => c.addAll(SHELL.map((p) => new URL(p, self.location).href))));
  self.skipWaiting();
});

self.addEventListener('activate', (event) => event.waitUntil(self.clients.claim()));

const KEPT = new Set(SHELL.map((p) => new URL(p, self.location).pathname));

self.addEventListener('fetch', (event) => {
  const req = event.request;
  const url = new URL(req.url);
  // Only the app's own files: a cloud fetched from this site (?cloud=) can be hundreds of MB and
  // is the user's, not the app's, so it is neither kept nor answered from here.
  const kept = KEPT.has(url.pathname) || url.pathname.startsWith(THREADS);
  if (req.method !== 'GET' || url.origin !== self.location.origin || !kept) return;
  event.respondWith((async () => {
    const cache = await caches.open(CACHE);
    // One copy per file: a share link's query string names the same page.
    const key = url.origin + url.pathname;
    try {
      const res = await fetch(req);
      if (res.ok && res.type === 'basic') cache.put(key, res.clone());
      return res;
    } catch (e) {
      const hit = await cache.match(key);
      if (hit) return hit;
      throw e;
    }
  })());
});
