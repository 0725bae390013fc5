// Everything the page shows about itself to the outside: the status marks on <body> that tests
// (tests/browser/*.mjs) and embedding pages wait on, and the objects put on `window` for them.
// The page's own logic reads none of these; they are gathered here so that they are easy to find,
// keep and change together with the tests.
//
// <body data-…> marks (set with `mark`):
//   state     'ready' once the viewer and the settings are up; 'no-webgpu' or 'error' when not
//   job       'running' | 'idle'                            (embedding pages too)
//   outcome   how the last run ended: 'done' | 'cancelled' | 'error'   (embedding pages too)
//   loaded    the name of the loaded cloud
//   stage     the progress stage of the running job ('setup', 'features', … 'done')
//   software  'true' when WebGPU runs on a software adapter (then the method defaults to network)
//   worker    'ready' | 'error': whether the reconstruction worker has its engine
//   threads   the CPU threads the worker runs on, once ready (1: the plain build)
//   workers   how many workers have been started (a cancelled CPU-bound run replaces one)
//   stopping  the id of a cancelled run its worker has not confirmed yet
//   trimmed   triangles the result panel's live trim slider removes
//   offline   'registered' once the service worker that keeps the offline copy is registered
//
// window:
//   nkrrViewer         the Rust viewer (coverage(), saturation(), set_point_budget(), gpu_bytes(), …)
//   nkrrReconstructor  the page's Reconstructor (web/reconstructor.js)
//   nkrrSettings       { table(): the wasm settings_table(), readOptions({ all }), shareParams(),
//                        problems(): what the share link's settings had wrong }

/** Sets body[data-name] to `value` (a string of it), or removes it for null/undefined. */
export function mark(name, value) {
  if (value === null || value === undefined) delete document.body.dataset[name];
  else document.body.dataset[name] = String(value);
}

/** Puts the page's objects on `window` and follows the reconstructor's worker state. */
export function expose({ nk, viewer, reconstructor, settings }) {
  window.nkrrViewer = viewer;
  window.nkrrReconstructor = reconstructor;
  window.nkrrSettings = {
    table: () => nk.settings_table(),
    readOptions: (opts) => settings.readOptions(opts),
    shareParams: () => Object.fromEntries(settings.shareParams()),
    problems: () => [...settings.problems],
  };
  const follow = () => {
    mark('workers', reconstructor.workersStarted);
    mark('stopping', reconstructor.stopping ? reconstructor.stopping.id : null);
  };
  reconstructor.onstatechange = follow;
  follow();
}
