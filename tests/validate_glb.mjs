#!/usr/bin/env node
// Runs the Khronos glTF validator (npm `gltf-validator`) on each GLB named on the command line.
//
//   node tests/validate_glb.mjs a.glb b.glb ...
//
// Prints, per file, the issue counts and every message (errors, warnings, infos, hints), then a
// summary line `TOTAL errors=E warnings=W infos=I hints=H`. Exits 1 if any file has an error or
// a warning, 2 if the validator cannot be loaded or a file cannot be read/parsed; infos and
// hints are printed but allowed. Used by `tests/gltf.rs`.

import { readFileSync } from 'node:fs';
import { basename } from 'node:path';

const SEVERITY = ['error', 'warning', 'info', 'hint'];
const MAX_PRINTED = 100; // messages printed per file (all are counted)

let validator;
try {
    validator = await import('gltf-validator');
} catch (e) {
    console.error(`cannot load the npm package gltf-validator (${e.code ?? e.message}); ` +
        'run `scripts/setup.sh npm` in the repository root');
    process.exit(2);
}

const files = process.argv.slice(2);
if (files.length === 0) {
    console.error('usage: node tests/validate_glb.mjs FILE.glb...');
    process.exit(2);
}

console.log(`gltf-validator ${validator.version()}`);
const total = { errors: 0, warnings: 0, infos: 0, hints: 0 };
let failed = false;
for (const file of files) {
    let report;
    try {
        const bytes = new Uint8Array(readFileSync(file));
        report = await validator.validateBytes(bytes, {
            uri: basename(file),
            format: 'glb',
            maxIssues: 0, // unlimited
            writeTimestamp: false,
        });
    } catch (e) {
        console.error(`${file}: validator could not run: ${e}`);
        process.exit(2);
    }
    const is = report.issues;
    const info = report.info ?? {};
    console.log(`${file}: errors=${is.numErrors} warnings=${is.numWarnings} ` +
        `infos=${is.numInfos} hints=${is.numHints}` +
        (is.truncated ? ' (truncated)' : '') +
        ` | generator=${JSON.stringify(info.generator)} vertices=${info.totalVertexCount} ` +
        `triangles=${info.totalTriangleCount} drawCalls=${info.drawCallCount}`);
    for (const m of is.messages.slice(0, MAX_PRINTED)) {
        const where = m.pointer ?? (m.offset !== undefined ? `@${m.offset}` : '');
        console.log(`  [${SEVERITY[m.severity] ?? m.severity}] ${m.code} ${where}: ${m.message}`);
    }
    if (is.messages.length > MAX_PRINTED) {
        console.log(`  ... ${is.messages.length - MAX_PRINTED} more`);
    }
    total.errors += is.numErrors;
    total.warnings += is.numWarnings;
    total.infos += is.numInfos;
    total.hints += is.numHints;
    if (is.numErrors > 0 || is.numWarnings > 0) failed = true;
}
console.log(`TOTAL errors=${total.errors} warnings=${total.warnings} ` +
    `infos=${total.infos} hints=${total.hints}`);
process.exit(failed ? 1 : 0);
