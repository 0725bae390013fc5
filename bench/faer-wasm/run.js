// node run.js [pkg dir] [rounds]: calls src/lib.rs's run() `rounds` times (default 5) in one
// process, prints each table, then a summary: per row, the median over rounds 2.. (round 1 is
// V8's warm-up: wasm starts in the baseline compiler, Liftoff, and tiers up to TurboFan) of
// each time and of the ratio faer/ours (per round, from unrounded times), with the hashes and max |diff| (which must not change between rounds).
const path = require('path');
const dir = process.argv[2] || './pkg';
const rounds = Number(process.argv[3] || 5);
const { run } = require(path.resolve(dir, 'faer_wasm.js'));
const rows = new Map();
let head = [];
for (let r = 0; r < rounds; r++) {
  const out = run();
  process.stdout.write(`round ${r + 1}\n${out}\n`);
  const lines = out.trim().split('\n');
  head = lines.slice(0, 3);
  for (const line of lines.slice(3)) {
    const c = line.split('|').slice(1, -1).map((s) => s.trim());
    const key = `${c[0]} | ${c[1]}`;
    if (!rows.has(key)) rows.set(key, { ours: [], faer: [], ratio: [], rest: c.slice(5).join(' | ') });
    const e = rows.get(key);
    if (e.rest !== c.slice(5).join(' | ')) throw new Error(`results changed between rounds: ${key}`);
    if (r > 0 || rounds === 1) { e.ours.push(Number(c[2])); e.faer.push(Number(c[3])); e.ratio.push(Number(c[4])); }
  }
}
const med = (v) => { const s = [...v].sort((a, b) => a - b); return s[s.length >> 1]; };
process.stdout.write(`summary: median of rounds 2..${rounds}\n${head.slice(1).join('\n')}\n`);
for (const [key, e] of rows) {
  const o = med(e.ours), f = med(e.faer);
  const dp = key.endsWith('solve') ? 5 : 4;
  process.stdout.write(`| ${key} | ${o.toFixed(dp)} | ${f.toFixed(dp)} | ${med(e.ratio).toFixed(2)} | ${e.rest} |\n`);
}
