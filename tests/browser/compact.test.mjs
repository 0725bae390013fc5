// Meshes for web viewers (issue 17): the GLB in each geometry form (plain floats,
// KHR_mesh_quantization, EXT_meshopt_compression) and a simplified one, reconstructed from a 10k
// eval cloud in the browser through the ES module, checked by the Khronos validator and loaded by
// three.js's GLTFLoader with meshoptimizer's decoder as the app serves it
// (dist/meshopt_decoder.mjs, never a CDN), and shown by model-viewer (which carries its own
// decoder), the two viewers the page's default download must work in.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { serve, browser, openPage, requireDist, DIST, EVAL, ROOT } from './harness.mjs';

const THREE = path.join(ROOT, 'node_modules/three');
const PAGE = `<!doctype html><meta charset="utf-8"><link rel="icon" href="data:,"><title>three.js loads nkrr's GLBs</title>
<script type="importmap">{ "imports": { "three": "/three/build/three.module.js" } }</script>
<script type="module" src="/model-viewer.min.js"></script>
<script type="module">
  import * as THREE from 'three';
  import { GLTFLoader } from '/three/examples/jsm/loaders/GLTFLoader.js';
  import { MeshoptDecoder } from '/meshopt_decoder.mjs';
  import { Reconstructor } from '/web/reconstructor.js';
  window.nk = new Reconstructor();
  // What three.js makes of a GLB: triangles, vertices, world bounds, attributes.
  window.load = (bytes) => new Promise((resolve, reject) => {
    const buf = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
    new GLTFLoader().setMeshoptDecoder(MeshoptDecoder).parse(buf, '', (gltf) => {
      gltf.scene.updateMatrixWorld(true);
      const box = new THREE.Box3();
      const out = { triangles: 0, vertices: 0, normals: true, unitNormals: true };
      gltf.scene.traverse((o) => {
        if (!o.isMesh) return;
        const g = o.geometry;
        out.triangles += g.index.count / 3;
        out.vertices += g.attributes.position.count;
        out.normals &&= !!g.attributes.normal;
        const n = new THREE.Vector3();
        for (let i = 0; i < g.attributes.normal.count; i += 97) {
          n.fromBufferAttribute(g.attributes.normal, i);
          out.unitNormals &&= Math.abs(n.length() - 1) < 0.02;
        }
        box.expandByObject(o, true);
      });
      resolve({ ...out, min: box.min.toArray(), max: box.max.toArray() });
    }, reject);
  });
  // What model-viewer makes of it: loaded or not, and the size of its bounding box.
  window.show = (bytes) => new Promise((resolve) => {
    const el = document.createElement('model-viewer');
    el.style.cssText = 'width: 320px; height: 240px';
    document.body.append(el);
    el.addEventListener('load', () => { const d = el.getDimensions(); resolve({ ok: true, size: [d.x, d.y, d.z] }); el.remove(); }, { once: true });
    el.addEventListener('error', (e) => { resolve({ ok: false, error: String(e.detail?.sourceError ?? e.detail?.type ?? e) }); el.remove(); }, { once: true });
    el.src = URL.createObjectURL(new Blob([bytes], { type: 'model/gltf-binary' }));
  });
  await customElements.whenDefined('model-viewer');
  // model-viewer needs to be told where the decoder is (a classic script): the app's copy.
  customElements.get('model-viewer').meshoptDecoderLocation = '/meshopt_decoder.cjs';
  window.ready = true;
</script>`;

let srv;
before(async () => {
  requireDist();
  const page = path.join(fs.mkdtempSync(path.join(os.tmpdir(), 'nkrr-three-')), 'three.html');
  fs.writeFileSync(page, PAGE);
  const three = (p) => path.join(THREE, p);
  srv = await serve(DIST, {
    '/three.html': page,
    '/data/spot-10k.ply': path.join(EVAL, 'spot-10k.ply'),
    '/three/build/three.module.js': three('build/three.module.js'),
    '/three/build/three.core.js': three('build/three.core.js'),
    '/three/examples/jsm/loaders/GLTFLoader.js': three('examples/jsm/loaders/GLTFLoader.js'),
    '/three/examples/jsm/utils/BufferGeometryUtils.js': three('examples/jsm/utils/BufferGeometryUtils.js'),
    '/three/examples/jsm/utils/SkeletonUtils.js': three('examples/jsm/utils/SkeletonUtils.js'),
    '/model-viewer.min.js': path.join(ROOT, 'node_modules/@google/model-viewer/dist/model-viewer.min.js'),
  });
});
after(() => srv?.server.close());

test('three.js loads every GLB form and a simplified mesh, with the decoder the app serves', { timeout: 900_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await openPage(b, `${srv.url}/three.html`);
    await page.waitForFunction(() => window.ready === true, null, { timeout: 60_000 });
    const runs = await page.evaluate(async () => {
      const bytes = await (await fetch('/data/spot-10k.ply')).arrayBuffer();
      const out = {};
      const base = { method: 'network', resolution: 64 };
      for (const [name, extra] of [['plain', { glb: 'plain' }], ['quantized', { glb: 'quantized' }], ['meshopt', { glb: 'meshopt' }]]) {
        const r = await window.nk.reconstruct(bytes.slice(0), { ...base, ...extra });
        out[name] = { stats: r.stats, bytes: r.glb.length, three: await window.load(r.glb), mv: await window.show(r.glb), glb: Array.from(r.glb) };
      }
      const tenth = Math.floor(out.plain.stats.triangles / 10);
      const r = await window.nk.reconstruct(bytes.slice(0), { ...base, glb: 'meshopt', triangles: tenth });
      out.simplified = { stats: r.stats, bytes: r.glb.length, three: await window.load(r.glb), mv: await window.show(r.glb), tenth, glb: Array.from(r.glb) };
      return out;
    });
    const plain = runs.plain;
    const extent = Math.max(...[0, 1, 2].map((a) => plain.three.max[a] - plain.three.min[a]));
    const validator = await import('gltf-validator');
    for (const [name, r] of Object.entries(runs)) {
      const report = await validator.validateBytes(new Uint8Array(r.glb), { format: 'glb', maxIssues: 0, writeTimestamp: false });
      assert.equal(report.issues.numErrors, 0, `${name}: ${JSON.stringify(report.issues.messages)}`);
      assert.equal(report.issues.numWarnings, 0, `${name}: ${JSON.stringify(report.issues.messages)}`);
      console.log(`${name}: ${r.stats.triangles} triangles, ${r.bytes} bytes, three.js: ${JSON.stringify(r.three)}, model-viewer: ${JSON.stringify(r.mv)}`);
      assert.equal(r.stats.glb, name === 'simplified' ? 'meshopt' : name);
      assert.equal(r.three.triangles, r.stats.triangles, `${name}: three.js sees the triangles written`);
      assert.ok(r.mv.ok, `${name}: model-viewer did not load it: ${r.mv.error}`);
      for (let a = 0; a < 3; a++) {
        const size = r.three.max[a] - r.three.min[a];
        assert.ok(Math.abs(r.mv.size[a] - size) <= 0.02 * size, `${name}: model-viewer's size ${r.mv.size} vs three.js's`);
      }
      assert.ok(r.three.normals && r.three.unitNormals, `${name}: normals`);
      assert.equal(r.stats.watertight, true, name);
      // The same object in the same place: bounds within a quantization step or two (the
      // simplified mesh keeps vertices of the full one, so it can only shrink a little).
      const tol = name === 'simplified' ? 0.02 * extent : 1e-3 * extent;
      for (let a = 0; a < 3; a++) {
        assert.ok(Math.abs(r.three.min[a] - plain.three.min[a]) <= tol, `${name}: min ${r.three.min} vs ${plain.three.min}`);
        assert.ok(Math.abs(r.three.max[a] - plain.three.max[a]) <= tol, `${name}: max ${r.three.max} vs ${plain.three.max}`);
      }
    }
    assert.equal(runs.meshopt.three.triangles, plain.three.triangles);
    assert.ok(4 * runs.meshopt.bytes <= plain.bytes, `meshopt ${runs.meshopt.bytes} vs plain ${plain.bytes}`);
    assert.ok(runs.quantized.bytes < plain.bytes * 0.6, `quantized ${runs.quantized.bytes} vs plain ${plain.bytes}`);
    assert.ok(runs.simplified.stats.triangles <= runs.simplified.tenth, `${runs.simplified.stats.triangles} > ${runs.simplified.tenth}`);
    assert.ok(runs.simplified.stats.notices.some((n) => n.startsWith('simplified from')), runs.simplified.stats.notices.join('; '));
    // model-viewer also tries to draw: this headless Chromium has WebGPU (SwiftShader) but no
    // WebGL context, which it reports as errors; loading (parsing, decoding, the bounds above)
    // does not need one. Every other error fails the test.
    assert.deepEqual(errors.filter((e) => !/WebGL context/.test(e)), []);
  } finally {
    await b.close();
  }
});
