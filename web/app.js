// The page's wiring: drop zone and file picker, the cloud summary and memory preflight, a run in
// the reconstruction worker (web/reconstructor.js, web/worker.js) with its progress, share links
// (opening a cloud from ?cloud=), and input forwarding to the Rust viewer. The settings form is
// web/settings.js, the result panel web/result.js, the marks and objects tests read
// web/test-hooks.js. Parsing, drawing and reconstructing happen in the wasm module; the page only
// touches the DOM and passes messages.

import { Reconstructor } from './reconstructor.js';
import { Settings } from './settings.js';
import { ResultPanel } from './result.js';
import { mark, expose } from './test-hooks.js';
import { $, fmt, num, secs, setItems } from './util.js';

const NO_WEBGPU =
  'This browser has no WebGPU, which nkrr needs to run the reconstruction on your GPU. ' +
  'Use a current Chrome or Edge (113+), Safari 26+, or Firefox 141+ (Windows; other platforms behind a flag).';

// Cancel returns the page to idle at once and tells the worker, which stops at the pipeline's
// next step and keeps its engine. A worker that has not confirmed within this time (a long GPU
// batch, or CPU-bound work such as nkrr's tuning, which does not see messages) is terminated
// and replaced, and so is one still stopping when the next run starts.
const CANCEL_GRACE_MS = 5000;

function show(text, kind = '') {
  const m = $('message');
  m.textContent = text;
  m.className = `message ${kind}`;
  m.hidden = !text;
}

// Trunk's loader initialises the wasm module and announces it with this event.
function wasmReady() {
  if (window.wasmBindings) return Promise.resolve(window.wasmBindings);
  return new Promise((resolve) =>
    addEventListener('TrunkApplicationStarted', () => resolve(window.wasmBindings), { once: true }));
}

let nk = null;
let viewer = null;
/** The settings form (web/settings.js), built from nk.settings_table(). */
let settings = null;
/** The result panel (web/result.js). */
let resultPanel = null;
/** True once the viewer and the settings are up. */
let ready = false;
let frame = 0;
// The loaded input: its name, the File (cheap to keep: the worker reads it for each run), the
// URL it came from (if any), an even subsample of its points (for the live trim), its point
// count and whether it has colours (for the preflight).
let input = null;

function requestRender() {
  if (!viewer || frame) return;
  const draw = () => {
    // A frame still on the GPU (seconds on a software adapter with a big cloud): wait for it
    // rather than queue another behind it, and behind it a scene's tiles.
    if (viewer.frame_in_flight) { frame = requestAnimationFrame(draw); return; }
    frame = 0;
    try { viewer.render(); } catch (e) { console.error(`render failed: ${e.message ?? e}`); }
  };
  frame = requestAnimationFrame(draw);
}

function fitCanvas() {
  const c = $('view');
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(c.clientWidth * dpr));
  const h = Math.max(1, Math.round(c.clientHeight * dpr));
  if (c.width !== w || c.height !== h) {
    c.width = w;
    c.height = h;
    if (viewer) viewer.resize(w, h);
  }
  requestRender();
}

// ---- Loading a cloud -----------------------------------------------------------------------

/** Opens a cloud file; `source` is its URL when it came from one (then the page can link to it). */
async function openFile(file, source = null) {
  if (!nk || !viewer) return;
  if (job) cancel('');
  show(`Reading ${file.name}…`, 'busy');
  let cloud, bytes;
  try {
    bytes = new Uint8Array(await file.arrayBuffer());
    cloud = nk.parse_cloud(bytes, file.name);
  } catch (e) {
    // An earlier cloud stays loaded (in the view, and for Run): keep its panel.
    $('cloud-info').hidden = !input;
    show(`Could not read ${file.name}: ${e.message ?? e}`, 'error');
    return;
  }
  const b = cloud.bounds;
  $('file-name').textContent = file.name;
  $('point-count').textContent = fmt.format(cloud.count);
  // Far-off clouds are read relative to an origin (kept as the GLB's root translation): show
  // the bounds in the file's coordinates.
  const o = cloud.origin;
  const far = o.some((v) => v !== 0);
  const at = far ? (x) => x.toFixed(3) : num;
  $('bounds').textContent = `[${at(b[0] + o[0])}, ${at(b[1] + o[1])}, ${at(b[2] + o[2])}] – ` +
    `[${at(b[3] + o[0])}, ${at(b[4] + o[1])}, ${at(b[5] + o[2])}]` +
    (far ? ` (read relative to [${o.join(', ')}], kept in the GLB as its root translation)` : '');
  $('extent').textContent = `${num(b[3] - b[0])} × ${num(b[4] - b[1])} × ${num(b[5] - b[2])}`;
  $('format').textContent = cloud.format;
  $('layout').textContent = cloud.layout;
  const zeros = cloud.zero_normals;
  $('attributes').textContent = [
    cloud.has_colors ? 'colours (carried to the mesh)' : 'no colours',
    cloud.has_normals
      ? `normals (not needed, ignored${zeros ? `; ${fmt.format(zeros)} are zero` : ''})`
      : 'no normals (none needed)',
  ].join('; ');
  const g = cloud.units_guess;
  $('units-guess').textContent = g.stated ? `${g.units} (${g.reason})` : `${g.units ? `${g.units}?` : 'unknown'} — ${g.reason}`;
  $('units-guess').classList.toggle('warn', g.warn);
  const warnings = cloud.warnings;
  if (g.warn) {
    const units = settings.byKey.get('units')?.label ?? 'Units';
    warnings.push(`Units: ${g.reason}. If they are millimetres, choose them under “${units}”: glTF is in metres.`);
  }
  setItems($('warnings'), warnings);
  $('cloud-info').hidden = false;
  viewer.set_cloud(cloud); // also removes an earlier mesh
  if (viewer.drawn_points < cloud.count) {
    $('warnings').append(Object.assign(document.createElement('li'), {
      textContent: `The view shows ${fmt.format(viewer.drawn_points)} of the points (an even subsample).`,
    }));
  }
  // No mesh yet: its box is off and disabled until one arrives.
  Object.assign($('show-mesh'), { disabled: true, checked: false });
  $('show-wire').disabled = true;
  // An even subsample of at most 100k points stays on the page for the live trim.
  const points = cloud.sample_positions(100_000);
  // The worker reads the file itself for each run; the preflight needs only the counts (read
  // before free: the Cloud's getters fail once it is freed).
  input = { name: file.name, file, source, points, count: cloud.count, colours: cloud.has_colors, units: g.units, stated: g.stated };
  cloud.free();
  updatePreflight();
  updateShareLink();
  resultPanel.set(null);
  $('progress').hidden = true;
  show('');
  mark('loaded', file.name);
  updateRunButton();
  requestRender();
}

/** The memory each stage will need on this adapter, for the loaded cloud and the settings. */
function updatePreflight() {
  const ul = $('preflight-lines');
  if (!input || !nk || !viewer) { ul.replaceChildren(); return; }
  let lines;
  try {
    // The sample lets a scene be planned in tiles as the worker will cut it.
    lines = nk.preflight(input.count, input.colours, settings.readOptions(), viewer.binding_limit, viewer.software,
      input.points, input.units ?? undefined, input.stated);
  } catch (e) {
    lines = [`no estimate: ${e.message ?? e}`];
  }
  setItems(ul, lines);
  const will = lines.filter((l) => l.startsWith('will '));
  $('preflight-summary').textContent = will.length ? `Memory: ${will.join('; ')}` : 'Memory: fits this GPU';
  $('preflight').classList.toggle('warn', will.length > 0);
  $('preflight').open = will.length > 0;
}

// ---- A run -----------------------------------------------------------------------------

// `?threads=N` sets the worker's CPU threads (1: the plain single-threaded build); the default is
// every core where the page is cross-origin isolated. Not a setting: results do not depend on it.
const THREADS_ASKED = Number(new URLSearchParams(location.search).get('threads')) || undefined;
const reconstructor = new Reconstructor({ graceMs: CANCEL_GRACE_MS, threads: THREADS_ASKED });

// Shares of the overall bar per stage, by method. Meshing has no known end: its share fills as
// field evaluations approach the typical count the event carries (MeshingSize::expected).
const SHARES = {
  network: { features: [0, 0.15], meshing: [0.15, 0.9], surface: [0.9, 0.98], tiles: [0, 0.98] },
  nkrr: { features: [0, 0.05], pairs: [0.05, 0.1], tuning: [0.1, 0.7], meshing: [0.7, 0.9], surface: [0.9, 0.98], prior: [0.9, 0.98], tiles: [0, 0.98] },
};

/** ", about m:ss left" in a stage whose steps cost about the same (tiles, tuning steps), from
 * the time since its first event; empty until a few seconds and one step have passed. Made when
 * `done` moves and kept until it moves again: a scene's tile is reported again while its
 * regression tunes (so that cancel reaches it), and the estimate must not creep up meanwhile. */
function left(p, done, of, what) {
  const since = job.stageStart[p.stage] ??= performance.now();
  const kept = job.stageLeft[p.stage];
  if (kept && kept.done === done) return kept.text;
  const t = (performance.now() - since) / 1000;
  let text = '';
  if (done > 0 && done < of && t > 3) {
    const s = Math.round((t / done) * (of - done));
    text = `, about ${Math.floor(s / 60)}:${String(s % 60).padStart(2, '0')} left${what}`;
  }
  job.stageLeft[p.stage] = { done, text };
  return text;
}

function stageText(p, opts) {
  switch (p.stage) {
    case 'setup': return 'Preparing the GPU…';
    case 'features': return 'Computing features (network encoder)…';
    case 'pairs': return 'Sampling and labelling training pairs…';
    case 'tuning': return `Tuning: step ${p.step} of ${p.of}, loss ${p.loss.toPrecision(4)}${left(p, p.step, p.of, ' for the tuning')}`;
    case 'surface': return 'Solving the Poisson surface (normals signed by the field’s mesh)…';
    case 'prior': return 'Meshing the network’s own field, to compare with the tuned field’s…';
    // Past the typical count the bar stays full (it cannot know the end): the words say why.
    case 'meshing': return `Meshing at ${opts.resolution}³: ${fmt.format(p.evaluated)} field evaluations${
      p.expected && p.evaluated > p.expected ? `, more than the usual ${fmt.format(p.expected)}: an intricate surface` : ''}`;
    case 'tiles': return `Scene: tile ${fmt.format(p.done)} of ${fmt.format(p.of)}${left(p, p.done, p.of, '')}`;
    case 'done': return 'Writing the GLB…';
    default: return p.stage;
  }
}

// A scene's finished pieces (the worker's 'meshed' events), drawn while the other tiles run;
// the result replaces them. Each piece goes to the viewer's GPU buffers as it comes and is not
// kept here (a 5M-point room sends hundreds: gathering them for each redraw grew the page past a
// gigabyte); the view is redrawn at most every PREVIEW_MS, and at most PREVIEW_GPU_SHARE of the
// time by the last frame's GPU time: the tiles run on the same GPU, and on a software adapter a
// frame of a million points and the growing mesh takes seconds (redrawn after every tile, the 1M
// room ran 27 s a tile in the page against 3.5 s with the points hidden).
const PREVIEW_MS = 400;
const PREVIEW_GPU_SHARE = 0.2;
const preview = {
  timer: null,
  triangles: 0,
  add(p) {
    if (!job) return;
    try {
      viewer.add_mesh_piece(p.positions, p.normals, p.indices);
    } catch (e) {
      console.warn(`a piece of the scene is not shown: ${e.message ?? e}`);
      return;
    }
    this.triangles += p.indices.length / 3;
    this.timer ??= setTimeout(() => this.draw(), Math.max(PREVIEW_MS, viewer.frame_ms / PREVIEW_GPU_SHARE));
  },
  draw() {
    this.timer = null;
    if (!job || !this.triangles) return;
    $('show-mesh').checked = true;
    applyVisibility();
    mark('preview', String(this.triangles));
  },
  /** Forgets the pieces (and removes them from the view unless `keep`: the result replaces them). */
  reset(keep = false) {
    clearTimeout(this.timer);
    const shown = this.triangles > 0;
    Object.assign(this, { timer: null, triangles: 0 });
    mark('preview', null);
    if (shown && !keep) {
      viewer.clear_mesh();
      requestRender();
    }
  },
};

function onProgress(p) {
  if (p.stage === 'meshed') {
    preview.add(p);
    return;
  }
  const opts = job.options;
  const share = SHARES[opts.method]?.[p.stage];
  let f = job.fraction;
  if (share) {
    let within = 0;
    if (p.stage === 'tuning') within = p.of ? p.step / p.of : 1;
    if (p.stage === 'meshing') within = Math.min(1, p.evaluated / Math.max(1, p.expected));
    if (p.stage === 'tiles') within = p.of ? p.done / p.of : 1;
    f = share[0] + (share[1] - share[0]) * within;
  } else if (p.stage === 'done') {
    f = 0.99;
  }
  job.fraction = Math.max(job.fraction, f);
  job.stage = p.stage;
  $('progress-bar').value = job.fraction;
  $('stage').textContent = stageText(p, opts);
  mark('stage', p.stage);
}

function tick() {
  if (job) $('elapsed').textContent = secs((performance.now() - job.started) / 1000);
}

// body[data-job] is 'running' or 'idle'; body[data-outcome] says how the last run ended
// ('done', 'cancelled', 'error'). Tests and embedding pages wait on these.
function setJobState(state) {
  const running = state === 'running';
  mark('job', running ? 'running' : 'idle');
  mark('outcome', running ? null : state);
  $('run').hidden = running;
  $('cancel').hidden = !running;
  for (const el of $('settings').elements) if (el.id !== 'cancel' && el.id !== 'run') el.disabled = running;
  if (!running) settings.sync();
  updateRunButton();
}

function updateRunButton() {
  $('run').disabled = !input || !!job || !ready;
}

let job = null; // { options, started, timer, fraction, stage, abort }

async function run() {
  if (!input || job || !ready) return;
  const options = settings.readOptions();
  // The download is named after the input, without a cloud extension (the readers' own list).
  const ext = input.name.match(/\.[^.]+$/)?.[0].toLowerCase();
  options.name = (nk.cloud_extensions().includes(ext) ? input.name.slice(0, -ext.length) : input.name) || 'mesh';
  const abort = new AbortController();
  const me = { options, started: performance.now(), fraction: 0, stage: 'setup', stageStart: {}, stageLeft: {}, timer: setInterval(tick, 100), abort };
  job = me;
  resultPanel.set(null);
  viewer.clear_mesh();
  requestRender();
  $('progress').hidden = false;
  $('progress-bar').value = 0;
  $('stage').textContent = 'Preparing the GPU…';
  tick();
  show('');
  mark('stage', null);
  setJobState('running');
  let r;
  try {
    r = await reconstructor.reconstruct(input.file, options, {
      onProgress: (p) => { if (job === me) onProgress(p); },
      signal: abort.signal,
    });
  } catch (e) {
    if (job !== me) return;
    if (e.name === 'AbortError') finish('cancelled', me.cancelMessage ?? CANCELLED);
    else if (e.name === 'GpuError') finish('error', `Reconstruction failed: ${e.message}. The next run gets a fresh GPU device.`);
    else finish('error', `Reconstruction failed: ${e.message}`);
    return;
  }
  if (job === me) onDone(r);
}

const CANCELLED = 'Cancelled. The cloud is still loaded; change settings or run again.';

/** Stops the run (the page is idle at once); `message` is then shown. */
function cancel(message = CANCELLED) {
  if (!job) return;
  job.cancelMessage = message;
  job.abort.abort();
}

function finish(state, message) {
  if (!job) return;
  preview.reset(state === 'done');
  clearInterval(job.timer);
  tick();
  job = null;
  if (state !== 'done') $('progress').hidden = true;
  show(message ?? '', state === 'error' ? 'error' : '');
  setJobState(state);
}

function onDone(r) {
  const elapsed = (performance.now() - job.started) / 1000;
  const name = job.options.name;
  let notShown = null;
  try {
    viewer.set_mesh(r.positions, r.normals, r.indices, r.colors?.length ? r.colors : undefined);
  } catch (e) {
    notShown = e.message ?? String(e);
    viewer.clear_mesh(); // not a scene's pieces in place of the result
  }
  Object.assign($('show-mesh'), { disabled: false, checked: true });
  $('show-wire').disabled = false;
  applyVisibility();
  requestRender();
  $('progress-bar').value = 1;
  $('stage').textContent = `Done in ${secs(elapsed)}`;
  mark('heap', String(r.stats.heapBytes ?? ''));
  resultPanel.set({
    name, glb: r.glb, stats: r.stats, elapsed, points: input?.points,
    mesh: { positions: r.positions, normals: r.normals, indices: r.indices, colors: r.colors, translation: r.translation },
  });
  finish('done', notShown ?? '');
  $('result').scrollIntoView({ block: 'nearest' });
}

function applyVisibility() {
  const wire = $('show-wire').checked;
  viewer?.set_visible($('show-cloud').checked, $('show-mesh').checked);
  viewer?.set_wireframe(wire);
  // The viewer builds a mesh's wireframe only while it is shown (a sort of every edge, which a
  // big scene's mesh would hold in the page for a view few use): the first time, set it again.
  if (wire && viewer?.has_mesh && !viewer.has_wireframe && resultPanel.result) resultPanel.showMesh();
  requestRender();
}

// ---- Share links: ?cloud=URL&<setting>=<value>…&run --------------------------------------
// Every setting's key works (web/settings.js applies and checks them); `run` starts at once.

/** Loads `cloud` from its URL, and runs when `run` is given and the link's settings all fit. */
async function openFromQuery(q) {
  const url = q.get('cloud');
  if (!url) return;
  let file;
  try {
    const abs = new URL(url, location.href);
    show(`Fetching ${abs.href}…`, 'busy');
    const res = await fetch(abs);
    if (!res.ok) throw new Error(`HTTP ${res.status} ${res.statusText}`);
    const name = decodeURIComponent(abs.pathname.split('/').pop() || 'cloud.ply');
    file = new File([await res.blob()], name);
  } catch (e) {
    show(`Could not fetch the cloud at ${url}: ${e.message ?? e}. ` +
      'It must be reachable from this page (same site, or served with CORS).', 'error');
    return;
  }
  await openFile(file, url);
  if (!q.has('run') || !input) return;
  // A link whose settings did not all fit (listed above the form) does not start by itself.
  if (settings.problems.length) show('The link’s settings did not all fit (see above the settings): not started.', 'error');
  else run();
}

/** The link that reopens this cloud with these settings (only for clouds from a URL). */
function updateShareLink() {
  const a = $('share');
  if (!input?.source || !settings) { a.hidden = true; return; }
  const q = new URLSearchParams({ cloud: input.source });
  // The method is always written: its default on the page depends on the machine (the network
  // on a software adapter), and the link should mean the same everywhere.
  for (const [k, v] of settings.shareParams({ always: ['method'] })) q.set(k, v);
  q.set('run', '');
  a.href = `${location.origin}${location.pathname}?${q.toString().replace(/run=$/, 'run')}`;
  a.hidden = false;
}

// ---- Input -----------------------------------------------------------------------------

function wireInput() {
  const zone = $('drop-zone');
  $('file-input').addEventListener('change', (e) => {
    const f = e.target.files?.[0];
    if (f) openFile(f);
    e.target.value = ''; // picking the same file again still fires
  });
  for (const t of ['dragenter', 'dragover']) {
    addEventListener(t, (e) => { e.preventDefault(); zone.classList.add('over'); });
  }
  for (const t of ['dragleave', 'drop']) {
    addEventListener(t, (e) => { e.preventDefault(); zone.classList.remove('over'); });
  }
  addEventListener('drop', (e) => {
    const f = e.dataTransfer?.files?.[0];
    if (f) openFile(f);
  });

  const canvas = $('view');
  let drag = null;
  canvas.addEventListener('pointerdown', (e) => { drag = { x: e.clientX, y: e.clientY }; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag || !viewer) return;
    viewer.orbit(e.clientX - drag.x, e.clientY - drag.y);
    drag = { x: e.clientX, y: e.clientY };
    requestRender();
  });
  canvas.addEventListener('wheel', (e) => { e.preventDefault(); viewer?.zoom(e.deltaY); requestRender(); }, { passive: false });
  canvas.addEventListener('dblclick', () => { viewer?.fit(); requestRender(); });
  $('fit-view').addEventListener('click', () => { viewer?.fit(); requestRender(); });
  addEventListener('keydown', (e) => {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    if (e.key === 'f' || e.key === 'F') { viewer?.fit(); requestRender(); }
  });
  $('point-size').addEventListener('input', (e) => { viewer?.set_point_size(Number(e.target.value) * (window.devicePixelRatio || 1)); requestRender(); });
  $('show-cloud').addEventListener('change', applyVisibility);
  $('show-mesh').addEventListener('change', applyVisibility);
  $('show-wire').addEventListener('change', applyVisibility);
  new ResizeObserver(fitCanvas).observe(canvas);

  $('settings').addEventListener('change', updateShareLink);
  $('settings').addEventListener('change', updatePreflight);
  $('settings').addEventListener('submit', (e) => { e.preventDefault(); run(); });
  $('cancel').addEventListener('click', () => cancel());
}

/** Builds the settings form from the wasm module's table. */
function buildSettings() {
  settings = new Settings(nk.settings_table(), $('settings-form'), nk.parse_setting);
}

/** The offline copy (web/sw.js), relative to this page so that any sub-path works; without it
 *  (a file:// page, a browser without service workers) the app still runs, online only. */
function keepOfflineCopy() {
  if (!('serviceWorker' in navigator)) return;
  navigator.serviceWorker.register('./sw.js').then(
    () => mark('offline', 'registered'),
    (e) => console.warn(`no offline copy: ${e.message ?? e}`));
}

async function boot() {
  wireInput();
  keepOfflineCopy();
  if (!navigator.gpu) {
    show(NO_WEBGPU, 'error');
    mark('state', 'no-webgpu');
    // The settings still show what a run would use.
    wasmReady().then((m) => { nk = m; buildSettings(); }).catch((e) => console.warn(`no settings form: ${e.message ?? e}`));
    return;
  }
  try {
    nk = await wasmReady();
    buildSettings();
  } catch (e) {
    show(`The page could not start: ${e.message ?? e}`, 'error');
    mark('state', 'error');
    return;
  }
  try {
    // The file picker offers what the readers accept (the same list as the CLI).
    $('file-input').accept = [...nk.cloud_extensions(), 'application/octet-stream', 'text/plain'].join(',');
    fitCanvas();
    viewer = await nk.Viewer.create($('view'));
    $('adapter').textContent = `GPU: ${viewer.adapter}`;
    // nkrr (the default) tunes on the GPU; on a software adapter that would take minutes, so the
    // network alone becomes the default there (a share link's own method still wins: it is
    // applied below). Software or not is the Rust side's one rule (Gpu::is_software).
    settings.softwareAdapter = viewer.software;
    mark('software', settings.softwareAdapter);
    if (settings.softwareAdapter && settings.byKey.has('method')) settings.setFromText('method', 'network');
    settings.sync();
  } catch (e) {
    show(`${NO_WEBGPU}\n(${e.message ?? e})`, 'error');
    mark('state', 'no-webgpu');
    return;
  }
  resultPanel = new ResultPanel({ nk, viewer, requestRender, onError: (m) => show(m, 'error') });
  expose({ nk, viewer, reconstructor, settings });
  // A share link's settings (every key of the table), checked; what does not fit is listed.
  const query = new URLSearchParams(location.search);
  settings.applyQuery(query);
  fitCanvas();
  ready = true;
  mark('state', 'ready');
  mark('job', 'idle');
  updateRunButton();
  // The worker loads the module and prepares its engine while the user picks a file.
  reconstructor.prepare().then(
    () => {
      mark('worker', 'ready');
      mark('threads', reconstructor.threads);
      const n = reconstructor.threads;
      $('adapter').textContent = `GPU: ${viewer.adapter} · CPU: ${n} thread${n === 1 ? '' : 's'}`;
    },
    (e) => { mark('worker', 'error'); console.warn(`the reconstruction worker is not ready: ${e.message}`); },
  );
  openFromQuery(query);
}

boot();
