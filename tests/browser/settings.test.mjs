// The settings form and share links, derived from the wasm module's settings_table()
// (src/settings.rs): one field per setting with the table's default, range and choices; a share
// link that sets every setting to a value other than its default round-trips through the form
// and back into a link; values that do not fit their setting are reported, not used, and such a
// link does not start a run.
//
// The page is reached through window.nkrrSettings (web/test-hooks.js): table(), readOptions({ all }),
// shareParams() and problems().
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import { serve, browser, openPage, requireDist, DIST, EVAL } from './harness.mjs';

let srv;
before(async () => {
  requireDist();
  srv = await serve(DIST, { '/data/spot-3k.ply': path.join(EVAL, 'spot-3k.ply') });
});
after(() => srv?.server.close());

const kebab = (key) => key.replace(/[A-Z]/g, (c) => `-${c.toLowerCase()}`);

async function readyPage(b, query = '') {
  const { page, errors } = await openPage(b, `${srv.url}/${query}`);
  await page.waitForFunction(() => document.body.dataset.state, null, { timeout: 90_000 });
  assert.equal(await page.evaluate(() => document.body.dataset.state), 'ready',
    `page did not become ready: ${await page.textContent('#message')}`);
  return { page, errors };
}

const table = (page) => page.evaluate(() => window.nkrrSettings.table());
const readOptions = (page) => page.evaluate(() => window.nkrrSettings.readOptions({ all: true }));
const shareParams = (page) => page.evaluate(() => window.nkrrSettings.shareParams());
const problems = (page) => page.evaluate(() => window.nkrrSettings.problems());

/** Each setting's control as the page built it (by id = the key in kebab case). */
const readForm = (page, keys) => page.evaluate((keys) => {
  const kebab = (key) => key.replace(/[A-Z]/g, (c) => `-${c.toLowerCase()}`);
  return Object.fromEntries(keys.map((key) => {
    const el = document.getElementById(kebab(key));
    if (!el) return [key, null];
    const field = el.closest('label.field');
    return [key, {
      tag: el.tagName.toLowerCase(), type: el.type, name: el.name,
      min: el.getAttribute('min'), max: el.getAttribute('max'), step: el.getAttribute('step'),
      defaultValue: el.defaultValue, defaultChecked: el.defaultChecked,
      defaultOption: el.tagName === 'SELECT' ? [...el.options].find((o) => o.defaultSelected)?.value ?? null : null,
      options: el.tagName === 'SELECT' ? [...el.options].map((o) => ({ value: o.value, label: o.textContent })) : null,
      label: field?.querySelector('span')?.textContent, help: field?.querySelector('small')?.textContent,
      advanced: !!el.closest('#advanced-settings'), nkrrOnly: !!el.closest('fieldset.nkrr-only'),
    }];
  }));
}, keys);

const inRange = (s, x) => (s.min == null || x >= s.min) && (s.max == null || x <= s.max);

/** A value for `s` other than its default, as share-link text, and what readOptions then gives. */
function otherValue(s) {
  if (s.kind === 'switch') return { text: s.default ? '0' : '1', want: !s.default };
  if (s.kind === 'choice') {
    const c = s.choices.find((c) => c.value !== (s.default ?? ''));
    assert.ok(c, `${s.key}: no choice other than its default`);
    return { text: c.value, want: c.value };
  }
  const lo = s.min ?? 0, hi = s.max ?? lo + 100;
  const int = s.kind === 'int';
  const cut = (x) => (int ? Math.round(x) : Number(x.toPrecision(3)));
  // Off the preset list where there is one: the page adds such a value to its menu.
  const presets = (s.presets ?? []).map((p) => Number(p.value));
  const candidates = [cut(lo + 0.37 * (hi - lo)), cut((lo + hi) / 2), hi, lo, int ? lo + 1 : cut(lo + 0.01 * (hi - lo))];
  const ok = (x) => Number.isFinite(x) && inRange(s, x) && x !== s.default && x !== 0 && (!int || Number.isInteger(x));
  const x = candidates.find((x) => ok(x) && !presets.includes(x)) ?? candidates.find(ok);
  assert.ok(x !== undefined, `${s.key}: no value other than its default in ${lo}..${hi}`);
  return { text: String(x), want: x };
}

/** What readOptions({ all: true }) gives for `s` on a page that has not changed it. */
function defaultOption(s) {
  if (s.kind === 'switch') return !!s.default;
  if (s.kind === 'choice') return s.default || undefined; // '' (as in the file) is left out
  return s.default ?? 0; // off is 0
}

test('the settings form has one field per setting of settings_table(), with its default, range and choices', { timeout: 180_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await readyPage(b);
    const t = await table(page);
    assert.ok(Array.isArray(t) && t.length >= 16, `settings_table() gave ${JSON.stringify(t)}`);
    const keys = t.map((s) => s.key);
    for (const key of ['method', 'resolution', 'removeSmall', 'units', 'maxPoints', 'm', 'steps', 'lambda', 'tuneTheta',
      'tuneZ', 'knnK', 'labelClip', 'euclidean', 'krrBackend', 'trim', 'colors']) {
      assert.ok(keys.includes(key), `no ${key} in settings_table(): ${keys.join(', ')}`);
    }
    // One control per setting, named by its key, in the table's order (the advanced ones
    // after the others, in their own section).
    const names = await page.$$eval('#settings-form [name]', (els) => els.map((e) => e.name));
    assert.deepEqual(names, [...t.filter((s) => !s.advanced), ...t.filter((s) => s.advanced)].map((s) => s.key));

    const form = await readForm(page, keys);
    for (const s of t) {
      const f = form[s.key];
      const at = `${s.key}: ${JSON.stringify(f)}`;
      assert.ok(f, `no #${kebab(s.key)} for ${s.key}`);
      assert.equal(f.label, s.label, at);
      assert.equal(f.help, s.help, at);
      assert.equal(f.advanced, !!s.advanced, at);
      assert.equal(f.nkrrOnly, !!s.nkrrOnly, at);
      const presets = s.presets ?? [];
      if (s.kind === 'switch') {
        assert.equal(f.type, 'checkbox', at);
        assert.equal(f.defaultChecked, !!s.default, at);
      } else if (s.kind === 'choice') {
        assert.equal(f.tag, 'select', at);
        assert.deepEqual(f.options, s.choices.map((c) => ({ value: c.value, label: c.label })), at);
        assert.equal(f.defaultOption, s.default ?? '', at);
      } else if (presets.length) {
        assert.equal(f.tag, 'select', at);
        for (const p of presets) {
          assert.ok(f.options.some((o) => Number(o.value) === Number(p.value) && o.label === p.label), `${at}: no preset ${JSON.stringify(p)}`);
        }
        for (const o of f.options) {
          const x = Number(o.value);
          assert.ok(inRange(s, x) || (s.canBeOff && x === 0), `${at}: option ${o.value} out of range`);
        }
        assert.equal(Number(f.defaultOption), s.default ?? 0, at);
      } else {
        assert.equal(f.tag, 'input', at);
        assert.equal(f.type, 'number', at);
        if (s.kind === 'int') assert.equal(f.step, '1', at);
        if (s.min != null) assert.equal(Number(f.min), s.canBeOff ? Math.min(0, s.min) : s.min, at);
        if (s.max != null) assert.equal(Number(f.max), s.max, at);
        if (s.default == null) assert.equal(f.defaultValue, '', at);
        else assert.equal(Number(f.defaultValue), s.default, at);
      }
    }
    // The options a run gets are the defaults (the method aside: a software adapter such as
    // SwiftShader makes the network the page's default).
    const software = await page.evaluate(() => document.body.dataset.software === 'true');
    const o = await readOptions(page);
    for (const s of t) {
      if (s.key === 'method' && software) { assert.equal(o.method, 'network'); continue; }
      assert.deepEqual(o[s.key], defaultOption(s), `${s.key}: readOptions gives ${JSON.stringify(o[s.key])}`);
    }
    assert.deepEqual(await problems(page), []);
    assert.equal(await page.isVisible('#settings-problems'), false);
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});

test('a share link setting every key to a non-default value round-trips through the form', { timeout: 180_000 }, async () => {
  const b = await browser();
  try {
    const first = await readyPage(b);
    const t = await table(first.page);
    await first.page.close();
    const values = Object.fromEntries(t.map((s) => [s.key, otherValue(s)]));
    const q = new URLSearchParams(Object.entries(values).map(([k, v]) => [k, v.text]));
    const { page, errors } = await readyPage(b, `?${q}`);
    assert.deepEqual(await problems(page), []);
    assert.equal(await page.isVisible('#settings-problems'), false);

    const o = await readOptions(page);
    for (const s of t) assert.deepEqual(o[s.key], values[s.key].want, `${s.key}=${values[s.key].text} read back as ${JSON.stringify(o[s.key])}`);
    // The advanced section opens to show the settings the link changed.
    if (t.some((s) => s.advanced)) assert.equal(await page.$eval('#advanced-settings', (d) => d.open), true);

    // The link the page would write names every setting (nkrr-only ones only with nkrr).
    const expectLink = async (nkrr) => {
      const got = await shareParams(page);
      const want = t.filter((s) => nkrr || !s.nkrrOnly);
      assert.deepEqual(Object.keys(got).sort(), want.map((s) => s.key).sort(), JSON.stringify(got));
      for (const s of want) {
        const v = values[s.key].want;
        const text = got[s.key];
        if (s.kind === 'switch') assert.equal(text, v ? '1' : '0', s.key);
        else if (s.kind === 'choice') assert.equal(text, v, s.key);
        else assert.equal(Number(text), v, s.key);
      }
    };
    const method = t.find((s) => s.key === 'method');
    await expectLink(values.method.want === 'nkrr');
    if (values.method.want !== 'nkrr' && method.choices.some((c) => c.value === 'nkrr')) {
      await page.selectOption('#method', 'nkrr');
      const got = await shareParams(page);
      assert.equal('method' in got, method.default !== 'nkrr', JSON.stringify(got)); // a default is not written
      for (const s of t.filter((s) => s.nkrrOnly)) assert.ok(s.key in got, `${s.key} missing from ${JSON.stringify(got)}`);
    }
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});

test('a share link value that does not fit its setting is reported and not used; such a link does not run', { timeout: 240_000 }, async () => {
  const b = await browser();
  try {
    const fresh = await readyPage(b);
    const t = await table(fresh.page);
    const defaults = await readOptions(fresh.page);
    await fresh.page.close();

    const bad = {};
    const int = t.find((s) => s.kind === 'int' && s.max != null);
    bad[int.key] = String(int.max + 1);
    const float = t.find((s) => s.kind === 'float');
    bad[float.key] = 'abc';
    const choice = t.find((s) => s.kind === 'choice');
    bad[choice.key] = 'bogus';
    const sw = t.find((s) => s.kind === 'switch');
    bad[sw.key] = 'maybe';
    const { page, errors } = await readyPage(b, `?${new URLSearchParams(bad)}`);
    const p = await problems(page);
    assert.equal(p.length, 4, JSON.stringify(p));
    for (const key of Object.keys(bad)) assert.ok(p.some((l) => l.includes(`${key}=${bad[key]}`)), `${key} not reported: ${JSON.stringify(p)}`);
    // The wording is the settings table's (the CLI's): the setting, its range and what was given.
    assert.ok(p.some((l) => l.includes(`${int.key} must be a whole number from ${int.min} to ${int.max}`)), JSON.stringify(p));
    assert.equal(await page.isVisible('#settings-problems'), true);
    assert.equal(await page.$$eval('#settings-problems li', (l) => l.length), 4);
    const o = await readOptions(page);
    for (const key of Object.keys(bad)) assert.deepEqual(o[key], defaults[key], `${key}: the bad value was used (${JSON.stringify(o[key])})`);
    assert.deepEqual(errors, []);

    // With a cloud and `run`: the cloud loads, the run does not start.
    const { page: p2, errors: e2 } = await readyPage(b, `?cloud=/data/spot-3k.ply&${int.key}=${int.max + 1}&run`);
    await p2.waitForFunction(() => document.body.dataset.loaded === 'spot-3k.ply', null, { timeout: 90_000 });
    await p2.waitForTimeout(1500);
    assert.equal(await p2.evaluate(() => document.body.dataset.job), 'idle');
    assert.equal(await p2.evaluate(() => document.body.dataset.outcome ?? null), null);
    assert.match(await p2.textContent('#message'), /not started/);
    assert.match(await p2.textContent('#settings-problems'), new RegExp(`${int.key}=${int.max + 1}`));
    assert.deepEqual(e2, []);
  } finally {
    await b.close();
  }
});

test('the JS API takes every setting of the table, with its range, and refuses values outside it', { timeout: 180_000 }, async () => {
  const b = await browser();
  try {
    const { page, errors } = await readyPage(b);
    const results = await page.evaluate(() => {
      const nk = window.wasmBindings;
      const t = nk.settings_table();
      const call = (options) => {
        try {
          nk.preflight(3000, false, options, 128 * 1024 * 1024, true);
          return null;
        } catch (e) {
          return `${e.name}: ${e.message}`;
        }
      };
      return t.map((s) => {
        let good, bad;
        if (s.kind === 'switch') { good = !s.default; bad = 'maybe'; }
        else if (s.kind === 'choice') { good = s.choices[s.choices.length - 1].value; bad = 'bogus'; }
        else { good = s.max; bad = s.max * 2 + 1; }
        return { key: s.key, kind: s.kind, min: s.min, max: s.max, good: call({ [s.key]: good }), bad: call({ [s.key]: bad }) };
      });
    });
    for (const r of results) {
      assert.equal(r.good, null, `${r.key}: an in-range value was refused: ${r.good}`);
      assert.match(r.bad ?? '', new RegExp(`^RangeError: ${r.key} must be `), `${r.key}: ${r.bad}`);
      if (r.kind === "int" || r.kind === "float") assert.ok(r.bad.includes(` to ${r.max}`), `${r.key}: ${r.bad}`);
    }
    assert.deepEqual(errors, []);
  } finally {
    await b.close();
  }
});
