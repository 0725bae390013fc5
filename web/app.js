// The page: drop zone and file picker, the cloud summary, and input forwarding to the Rust
// viewer. Parsing and drawing happen in the wasm module; this file only touches the DOM.

const $ = (id) => document.getElementById(id);
const fmt = new Intl.NumberFormat('en-US');
const num = (x) => Number(x.toPrecision(5)).toString();

const NO_WEBGPU =
  'This browser has no WebGPU, which nkrr needs to run the reconstruction on your GPU. ' +
  'Use a current Chrome or Edge (113+), Safari 26+, or Firefox 141+ (Windows; other platforms behind a flag).';

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
let frame = 0;

function requestRender() {
  if (!viewer || frame) return;
  frame = requestAnimationFrame(() => {
    frame = 0;
    try { viewer.render(); } catch (e) { console.error(`render failed: ${e.message ?? e}`); }
  });
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

async function openFile(file) {
  if (!nk || !viewer) return;
  show(`Reading ${file.name}…`, 'busy');
  let cloud;
  try {
    const bytes = new Uint8Array(await file.arrayBuffer());
    cloud = nk.parse_ply(bytes);
  } catch (e) {
    $('cloud-info').hidden = true;
    show(`Could not read ${file.name}: ${e.message ?? e}`, 'error');
    return;
  }
  const b = cloud.bounds;
  $('file-name').textContent = file.name;
  $('point-count').textContent = fmt.format(cloud.count);
  $('bounds').textContent = `[${num(b[0])}, ${num(b[1])}, ${num(b[2])}] – [${num(b[3])}, ${num(b[4])}, ${num(b[5])}]`;
  $('extent').textContent = `${num(b[3] - b[0])} × ${num(b[4] - b[1])} × ${num(b[5] - b[2])}`;
  $('layout').textContent = cloud.layout;
  const ul = $('warnings');
  ul.replaceChildren(...cloud.warnings.map((w) => Object.assign(document.createElement('li'), { textContent: w })));
  $('cloud-info').hidden = false;
  viewer.set_cloud(cloud);
  cloud.free();
  show('');
  document.body.dataset.loaded = file.name;
  requestRender();
}

function wireInput() {
  const zone = $('drop-zone');
  $('file-input').addEventListener('change', (e) => {
    const f = e.target.files?.[0];
    if (f) openFile(f);
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
  $('fit').addEventListener('click', () => { viewer?.fit(); requestRender(); });
  addEventListener('keydown', (e) => { if (e.key === 'f' || e.key === 'F') { viewer?.fit(); requestRender(); } });
  $('point-size').addEventListener('input', (e) => { viewer?.set_point_size(Number(e.target.value) * (window.devicePixelRatio || 1)); requestRender(); });
  new ResizeObserver(fitCanvas).observe(canvas);
}

async function boot() {
  wireInput();
  if (!navigator.gpu) { show(NO_WEBGPU, 'error'); document.body.dataset.state = 'no-webgpu'; return; }
  try {
    nk = await wasmReady();
    fitCanvas();
    viewer = await nk.Viewer.create($('view'));
    $('adapter').textContent = `GPU: ${viewer.adapter}`;
  } catch (e) {
    show(`${NO_WEBGPU}\n(${e.message ?? e})`, 'error');
    document.body.dataset.state = 'no-webgpu';
    return;
  }
  fitCanvas();
  document.body.dataset.state = 'ready';
  // Exposed for tests and for embedding pages that want the view.
  window.nkrrViewer = viewer;
}

boot();
