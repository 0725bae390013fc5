// The result panel: the mesh's statistics, the tuning summary, the live "Trim to the scan"
// slider (#live-trim: drops triangles far from the points, without a re-run) and the downloads,
// which follow the trim.

import { $, fmt, secs, setItems } from './util.js';
import { mark } from './test-hooks.js';

/** One line about nkrr's tuning: "tuned on 4,000 of 6,000 pairs, m 500; 30 steps (max steps),
 *  kept step 12 (lowest error on 1,000 held-out pairs); loss a → b". The kept parameters are those
 *  with the lowest error on held-out pairs, or (the paper's choice, selectBy 'training') the
 *  lowest training error; not the lowest loss, which is why the kept step need not be the last. */
export function tuningSummary(t) {
  const pairs = t.tunedOn < t.n ? `tuned on ${fmt.format(t.tunedOn)} of ${fmt.format(t.n)} pairs` : `n ${fmt.format(t.n)}`;
  const kept = t.heldOut > 0 ? `lowest error on ${fmt.format(t.heldOut)} held-out pairs` : 'lowest training error';
  return `${pairs}, m ${t.m}; ${t.stepsRun} steps (${t.stop}), kept step ${t.bestStep} (${kept}); ` +
    `loss ${t.initialLoss.toPrecision(4)} → ${t.finalLoss.toPrecision(4)}`;
}

export class ResultPanel {
  /**
   * @param {{ nk: object, viewer: object, requestRender: () => void, onError: (message: string) => void }} deps
   *   nk: the wasm module (trim_indices, mesh_file); viewer: the Rust viewer the mesh is shown in.
   */
  constructor({ nk, viewer, requestRender, onError }) {
    this.nk = nk;
    this.viewer = viewer;
    this.requestRender = requestRender;
    this.onError = onError;
    /** The shown result: { name, glb, stats, elapsed, points, mesh, indices }, or null. */
    this.result = null;
    $('live-trim').addEventListener('input', () => this.applyTrim());
    $('download').addEventListener('click', () => this.download('glb'));
    for (const f of ['ply', 'obj', 'stl']) $(`download-${f}`).addEventListener('click', () => this.download(f));
  }

  /**
   * Shows a result, or hides the panel for null. `r`: { name, glb: Uint8Array, stats, elapsed
   * (seconds), points (the cloud's subsample, for the trim), mesh: { positions, normals, indices,
   * colors, translation } }. The viewer is expected to show the whole mesh already.
   */
  set(r) {
    this.result = r;
    $('result').hidden = !r;
    if (!r) return;
    const s = r.stats;
    $('r-vertices').textContent = fmt.format(s.vertices);
    $('r-triangles').textContent = fmt.format(s.triangles);
    $('r-time').textContent = `${secs(r.elapsed)} (${s.method}, ${s.resolution}³)`;
    $('r-stages').textContent = s.timings.map((t) => `${t.stage} ${secs(t.seconds)}`).join(' · ');
    $('r-evals').textContent = `${fmt.format(s.evaluations)} (dense grid: ${fmt.format(s.denseEvaluations)})`;
    const t = s.tuning;
    $('r-tuning-label').hidden = $('r-tuning').hidden = !t;
    if (t) $('r-tuning').textContent = tuningSummary(t);
    setItems($('r-notices'), s.notices);
    $('download').textContent = `Download ${r.name}.glb`;
    r.indices = r.mesh.indices; // the triangles shown and downloaded (a subset when trimmed)
    $('live-trim').value = '0';
    this.applyTrim(true);
  }

  /** Applies the trim slider to the result: the view and the downloads follow it. */
  applyTrim(initial = false) {
    const result = this.result;
    if (!result) return;
    const f = Number($('live-trim').value);
    $('live-trim-value').textContent = f > 0 ? `${f} × spacing` : 'off';
    const m = result.mesh;
    result.indices = f > 0 && result.points ? this.nk.trim_indices(result.points, m.positions, m.indices, f) : m.indices;
    const removed = (m.indices.length - result.indices.length) / 3;
    mark('trimmed', removed);
    $('r-triangles').textContent = removed > 0
      ? `${fmt.format(result.indices.length / 3)} (${fmt.format(removed)} trimmed; open)`
      : fmt.format(result.stats.triangles);
    // The GLB the download will give: the reconstruction's own, or the trimmed one written now
    // (kept for the download), so the size shown follows the trim.
    result.trimmedGlb = null;
    if (removed > 0) {
      try {
        result.trimmedGlb = this.nk.mesh_file('glb', m.positions, m.normals, m.colors, result.indices, result.name, m.translation, result.stats.glb);
      } catch (e) {
        this.onError(e.message ?? String(e));
      }
    }
    const glbBytes = result.trimmedGlb ? result.trimmedGlb.length : result.stats.bytes;
    $('r-bytes').textContent = `${result.name}.glb, ${fmt.format(Math.round(glbBytes / 1024))} KiB${removed > 0 ? ' (trimmed)' : ''}`;
    const closed = removed === 0 && result.stats.watertight;
    $('r-watertight').textContent = removed > 0 ? 'no (trimmed)' : closed ? 'yes' : 'no';
    $('r-watertight').className = closed ? 'yes' : 'no';
    if (initial && f === 0) return; // the viewer shows the whole mesh already
    this.showMesh();
  }

  /** Puts the result's triangles (trimmed or not) in the viewer; again when the wireframe is
   *  first shown, whose edges the viewer builds only then. */
  showMesh() {
    const result = this.result;
    if (!result) return;
    const m = result.mesh;
    try {
      this.viewer.set_mesh(m.positions, m.normals, result.indices, m.colors?.length ? m.colors : undefined);
    } catch (e) {
      this.onError(e.message ?? String(e));
    }
    this.requestRender();
  }

  /** Downloads the shown (maybe trimmed) mesh as glb, ply, obj or stl. */
  download(format = 'glb') {
    const result = this.result;
    if (!result) return;
    let bytes = result.glb;
    let type = 'model/gltf-binary';
    const m = result.mesh;
    if (format === 'glb' && result.trimmedGlb) {
      bytes = result.trimmedGlb;
    } else if (format !== 'glb' || result.indices !== m.indices) {
      // Written on demand from the arrays the view holds, so a trimmed mesh downloads trimmed.
      bytes = this.nk.mesh_file(format, m.positions, m.normals, m.colors, result.indices, result.name, m.translation, result.stats.glb);
      if (format !== 'glb') type = 'application/octet-stream';
    }
    const url = URL.createObjectURL(new Blob([bytes], { type }));
    const a = Object.assign(document.createElement('a'), { href: url, download: `${result.name}.${format}` });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10_000);
  }
}
