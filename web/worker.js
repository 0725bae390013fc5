// The reconstruction, off the page's main thread: this module worker loads its own instance of
// the wasm module, makes a WebGPU device here (one engine, kept for later runs) and answers the
// page's messages.
//
//   page → worker  { type: 'prepare', threads? }          threads: the CPU threads to use (1: the plain build)
//                  { type: 'run', id, bytes: ArrayBuffer | Blob, options, cancelFlag?: Int32Array }
//                  { type: 'cancel', id }
//                  { type: 'simulate-device-loss' }       (tests: destroys the GPU device)
//                  { type: 'tuning-step', m, reps }     benchmark: one tuning step's CPU share here
//   worker → page  { type: 'ready', adapter, threads }  the engine is up (answer to 'prepare')
//                  { type: 'tuning-step', ms, threads }
//                  { type: 'progress', id, stage, … }   see `reconstruct` in src/web/api.rs
//                  { type: 'done', id, result }          glb, positions, normals, indices, colors, translation, stats
//                                                        (stats.heapBytes: this worker's wasm memory now)
//                  { type: 'cancelled', id }
//                  { type: 'error', id?, name, message }
//
// Cancelling: 'cancel' sets a flag that the progress callback reads, so the pipeline stops at its
// next step. Messages only arrive while the pipeline awaits the GPU; a step that computes on the
// CPU for long (nkrr's tuning, for now) does not see them. `cancelFlag`, a SharedArrayBuffer view
// the page can send when it is cross-origin isolated, is read synchronously and has no such gap;
// without one, the page terminates this worker when a cancel is not answered in time.

// Two builds of the wasm module sit next to web/, wherever the site is mounted: the plain one
// (nkrr.js) and, in threads/, one with wasm atomics whose loops and linear algebra split over a
// pool of Web Workers sharing its memory (scripts/web_threads.sh). The threaded one needs a
// cross-origin isolated page (SharedArrayBuffer); where it is not, where one thread is asked for,
// or where it fails to start, the plain one runs, with the same results to the bit.
let ready = null; // { nk: the module's exports, wasm: its instance's exports, threads }

function load(threads) {
  return (ready ??= (async () => {
    if (threads > 1 && self.crossOriginIsolated) {
      try {
        const nk = await import('../threads/nkrr.js');
        const wasm = await nk.default();
        await nk.initThreadPool(threads);
        nk.usePoolThreads(threads);
        return { nk, wasm, threads: nk.poolThreads() };
      } catch (e) {
        console.warn(`nkrr: the threaded build did not start (${e?.message ?? e}); running on one thread`);
      }
    }
    const nk = await import('../nkrr.js');
    return { nk, wasm: await nk.default(), threads: 1 };
  })());
}

const cancelled = new Set();

function fail(id, e) {
  postMessage({ type: 'error', id, name: e?.name ?? 'Error', message: e?.message ?? String(e) });
}

async function run({ id, bytes, options, cancelFlag }) {
  const { nk, wasm } = await load(1);
  const stopped = () => cancelled.has(id) || (cancelFlag ? Atomics.load(cancelFlag, 0) !== 0 : false);
  if (stopped()) { postMessage({ type: 'cancelled', id }); return; }
  const onProgress = (p) => {
    const go = !stopped();
    // A scene's piece is handed over, not copied (hundreds of them in a big scan).
    const transfer = p.stage === 'meshed' ? [p.positions.buffer, p.normals.buffer, p.indices.buffer] : [];
    if (go) postMessage({ type: 'progress', id, ...p }, transfer);
    return go;
  };
  try {
    const data = new Uint8Array(bytes instanceof Blob ? await bytes.arrayBuffer() : bytes);
    if (stopped()) { postMessage({ type: 'cancelled', id }); return; }
    const r = await nk.reconstruct(data, options ?? {}, onProgress);
    // The wasm memory keeps its high-water mark for the worker's life: the page replaces a
    // worker that a big scan grew (web/reconstructor.js).
    r.stats.heapBytes = wasm.memory.buffer.byteLength;
    r.stats.threads = nk.poolThreads();
    const transfer = [r.glb.buffer, r.positions.buffer, r.normals.buffer, r.indices.buffer, r.colors.buffer];
    postMessage({ type: 'done', id, result: r }, transfer);
  } catch (e) {
    if (e?.name === 'AbortError') postMessage({ type: 'cancelled', id });
    else fail(id, e);
  } finally {
    cancelled.delete(id);
  }
}

// Runs one at a time, in order: a second 'run' waits for the first.
let queue = Promise.resolve();

onmessage = ({ data }) => {
  switch (data?.type) {
    case 'prepare':
      queue = queue.then(async () => {
        try {
          const { nk, threads } = await load(data.threads ?? 1);
          postMessage({ type: 'ready', adapter: await nk.prepareEngine(), threads });
        } catch (e) {
          fail(undefined, e);
        }
      });
      break;
    case 'run':
      queue = queue.then(() => run(data));
      break;
    case 'cancel':
      cancelled.add(data.id);
      break;
    case 'simulate-device-loss': // test hook: as if the driver had reset
      load(1).then(({ nk }) => nk.simulateDeviceLoss());
      break;
    case 'tuning-step': // benchmark (tests/browser/tuning-step.test.mjs): on this worker's threads
      queue = queue.then(async () => {
        try {
          const { nk } = await load(1);
          postMessage({ type: 'tuning-step', ms: nk.tuning_step_ms(data.m, data.reps), threads: nk.poolThreads() });
        } catch (e) {
          fail(undefined, e);
        }
      });
      break;
    default:
      fail(undefined, new Error(`unknown message ${JSON.stringify(data?.type)}`));
  }
};
