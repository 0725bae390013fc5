// nkrr's reconstruction as an ES module for any page: point cloud in, GLB out, computed with
// WebGPU in a Web Worker (web/worker.js) so the page stays responsive. The nkrr page uses it,
// and so can yours (see web/examples/embed.html):
//
//   import { Reconstructor } from './web/reconstructor.js';
//   const r = new Reconstructor();
//   const out = await r.reconstruct(cloudBytes, { resolution: 128 }, { onProgress, signal });
//   // out.glb: Uint8Array (a .glb file); out.positions, out.normals: Float32Array (xyz per
//   // vertex); out.indices: Uint32Array (3 per triangle); out.colors: Uint8Array (RGBA per vertex,
//   // empty without colours); out.translation: Float64Array (xyz of a far-off cloud, or empty); out.stats: vertices, triangles,
//   // watertight, timings [{ stage, seconds }], notices, tuning, …
//
// Options (all optional): every key of the wasm module's settings_table() (method, resolution,
// m, steps, removeSmall, units, trim, …: the same settings, ranges and defaults as the CLI's
// flags, defined once in src/settings.rs; a value out of range rejects with a RangeError that
// names it), and name (the glTF node's name).
// Progress: onProgress({ stage: 'setup' | 'features' | 'pairs' | 'tuning' | 'surface' | 'meshing' | 'prior' | 'tiles' | 'done',
// step, of, loss, evaluated, expected, done }: meshing's evaluations so far and the typical count
// at this resolution, which a run may pass; a scene's tiles done of `of`). Aborting the signal rejects at once with an AbortError; the
// worker stops at its next step, or is replaced if it has not within `graceMs` (CPU-bound steps
// do not hear messages, unless the page is cross-origin isolated: then a SharedArrayBuffer flag
// reaches them).

const WORKER_URL = new URL('./worker.js', import.meta.url);

/** Every core where the worker can share memory with its pool (a cross-origin isolated page),
 *  at most 16 (each thread holds a stack and a worker); else 1. */
function defaultThreads() {
  return globalThis.crossOriginIsolated ? Math.min(navigator.hardwareConcurrency || 1, 16) : 1;
}
// A worker whose wasm memory grew past this in a run is ended once it has answered: wasm memory
// never shrinks, and a big scan's (the whole scene's mesh, its GLB, the last fit's tree) would
// stay held by the tab until it closes. The next run starts a new worker and GPU engine (seconds);
// clouds of an object's size stay well under it and keep theirs.
const RECYCLE_HEAP_BYTES = 256 * 2 ** 20;

export class Reconstructor {
  /**
   * @param {{ graceMs?: number, workerUrl?: string | URL, threads?: number }} [opts]
   *   graceMs: how long an aborted run may take to stop before its worker is replaced.
   *   threads: CPU threads for the reconstruction's loops and linear algebra (default: every
   *   core, where the page is cross-origin isolated; 1 otherwise, and 1 runs the plain build).
   *   The results are the same to the bit for any count.
   */
  constructor({ graceMs = 5000, workerUrl = WORKER_URL, threads = defaultThreads() } = {}) {
    this.graceMs = graceMs;
    this.workerUrl = workerUrl;
    this.threadsAsked = Math.max(1, Math.floor(threads) || 1);
    /** The threads the worker runs on, once it is ready (fewer than asked where it cannot share memory). */
    this.threads = null;
    this.worker = null;
    this.workersStarted = 0;
    this.job = null; // { id, resolve, reject, onProgress }
    this.stopping = null; // { id, timer }: an aborted run the worker has not confirmed
    this.nextId = 1;
    this._ready = null;
    /** Called when `workersStarted` or `stopping` change (for status displays and tests). */
    this.onstatechange = null;
  }

  /** Starts the worker and its GPU engine; resolves to a description of the GPU adapter. */
  prepare() {
    if (!this.worker) this._start();
    return this._ready;
  }

  /** True while a run is in progress. */
  get busy() {
    return this.job !== null;
  }

  /**
   * Reconstructs a surface from a cloud file's bytes (PLY, LAS/LAZ, E57 or XYZ/PTS/CSV text).
   * @param {ArrayBuffer | ArrayBufferView | Blob} cloud
   * @param {object} [options]
   * @param {{ onProgress?: (p: object) => void, signal?: AbortSignal }} [hooks]
   */
  reconstruct(cloud, options = {}, { onProgress, signal } = {}) {
    if (this.job) return Promise.reject(new DOMException('a reconstruction is already running', 'InvalidStateError'));
    if (signal?.aborted) return Promise.reject(signal.reason);
    // A Blob (a File) goes to the worker as is and is read there: the page holds no copy.
    // Bytes are copied, so the caller keeps its own.
    let bytes, transfer = [];
    if (cloud instanceof Blob) bytes = cloud;
    else if (cloud instanceof ArrayBuffer) transfer = [bytes = cloud.slice(0)];
    else if (ArrayBuffer.isView(cloud)) transfer = [bytes = cloud.buffer.slice(cloud.byteOffset, cloud.byteOffset + cloud.byteLength)];
    else return Promise.reject(new TypeError('cloud must be an ArrayBuffer, a typed array or a Blob'));
    // A worker still busy with an aborted run would make this one wait: start afresh.
    if (!this.worker || this.stopping) this._replace();
    const id = this.nextId++;
    return new Promise((resolve, reject) => {
      const onAbort = () => this._abort(id, signal.reason);
      const done = (fn) => (v) => {
        signal?.removeEventListener('abort', onAbort);
        this.job = null;
        fn(v);
      };
      // Where the page is cross-origin isolated, a shared flag reaches the worker even while it
      // computes on the CPU, so no abort needs the worker replaced.
      const cancelFlag = globalThis.crossOriginIsolated ? new Int32Array(new SharedArrayBuffer(4)) : undefined;
      this.job = { id, resolve: done(resolve), reject: done(reject), onProgress, cancelFlag };
      signal?.addEventListener('abort', onAbort, { once: true });
      onProgress?.({ stage: 'setup' });
      this.worker.postMessage({ type: 'run', id, bytes, options, cancelFlag }, transfer);
    });
  }

  /** Ends the worker and frees its GPU device; a later call starts a new one. */
  dispose() {
    this.job?.reject(new DOMException('the reconstructor was disposed', 'AbortError'));
    this._end();
  }

  /**
   * Benchmark hook (tests/browser/tuning-step.test.mjs): milliseconds of one tuning step's CPU
   * share with `m` inducing points, median of `reps`, on the worker's threads. Resolves to
   * `{ ms, threads }`.
   */
  async tuningStepMs(m, reps) {
    await this.prepare();
    const w = this.worker;
    return new Promise((resolve, reject) => {
      const on = ({ data }) => {
        if (data.type === 'tuning-step') { w.removeEventListener('message', on); resolve({ ms: data.ms, threads: data.threads }); }
        else if (data.type === 'error' && data.id === undefined) { w.removeEventListener('message', on); reject(workerError(data)); }
      };
      w.addEventListener('message', on);
      w.postMessage({ type: 'tuning-step', m, reps });
    });
  }

  /** Test hook: the worker's GPU device is destroyed as if the driver had reset. */
  simulateDeviceLoss() {
    this.worker?.postMessage({ type: 'simulate-device-loss' });
  }

  _start() {
    const w = new Worker(this.workerUrl, { type: 'module', name: 'nkrr' });
    this.worker = w;
    this.workersStarted++;
    this._ready = new Promise((resolve, reject) => {
      w.addEventListener('message', ({ data }) => {
        if (data.type === 'ready') {
          this.threads = data.threads;
          resolve(data.adapter);
        }
        else if (data.type === 'error' && data.id === undefined) reject(workerError(data));
      });
      w.addEventListener('error', (e) => reject(new Error(e.message || 'the reconstruction worker failed to start')));
    });
    this._ready.catch(() => {}); // a run that needs it reports the error
    w.addEventListener('message', ({ data }) => this._onMessage(w, data));
    w.addEventListener('error', (e) => {
      e.preventDefault();
      if (w === this.worker) {
        this.job?.reject(new Error(`the reconstruction worker failed: ${e.message || 'unknown error'}`));
        this.worker = null; // the next run starts a new one
        w.terminate();
      }
    });
    w.postMessage({ type: 'prepare', threads: this.threadsAsked });
    this.onstatechange?.();
  }

  /** Ends the worker (and its wasm memory and GPU device); a later run starts a new one. */
  _end() {
    this.worker?.terminate();
    this.worker = null;
    this._settle();
  }

  _replace() {
    this._end();
    this._start();
  }

  _settle() {
    if (!this.stopping) return;
    clearTimeout(this.stopping.timer);
    this.stopping = null;
    this.onstatechange?.();
  }

  _abort(id, reason) {
    if (this.job?.id !== id) return;
    if (this.job.cancelFlag) Atomics.store(this.job.cancelFlag, 0, 1);
    this.worker.postMessage({ type: 'cancel', id });
    this._settle();
    this.stopping = { id, timer: setTimeout(() => { if (this.stopping?.id === id) this._replace(); }, this.graceMs) };
    this.onstatechange?.();
    this.job.reject(reason instanceof Error || reason instanceof DOMException ? reason : new DOMException('cancelled', 'AbortError'));
  }

  _onMessage(w, data) {
    if (w !== this.worker) return; // from a terminated worker
    if (this.stopping?.id === data.id && data.type !== 'progress') this._settle(); // it has stopped
    const job = this.job;
    if (!job || data.id !== job.id) return; // from an aborted run
    switch (data.type) {
      case 'progress': {
        const { type, id, ...p } = data;
        try { job.onProgress?.(p); } catch (e) { console.error(e); }
        break;
      }
      case 'done':
        if (data.result?.stats?.heapBytes > RECYCLE_HEAP_BYTES) this._end();
        job.resolve(data.result);
        break;
      case 'cancelled': job.reject(new DOMException('cancelled', 'AbortError')); break;
      case 'error':
        // A lost or failing device: the next run gets a fresh worker and device.
        if (data.name === 'GpuError') this._replace();
        job.reject(workerError(data));
        break;
    }
  }
}

function workerError({ name, message }) {
  const e = new Error(message);
  e.name = name || 'Error';
  return e;
}

/** One-shot convenience: a new worker for one reconstruction, ended afterwards. */
export async function reconstruct(cloud, options, hooks) {
  const r = new Reconstructor();
  try {
    return await r.reconstruct(cloud, options, hooks);
  } finally {
    r.dispose();
  }
}
