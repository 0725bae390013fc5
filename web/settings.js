// The reconstruction settings on the page: the form, the options it gives the wasm module, and
// share links. Nothing here names a setting: every field, default, range, choice, label and help
// text comes from the wasm module's settings_table() (src/settings.rs, the one definition the CLI
// uses too), one entry per setting in display order:
//
//   { key, flag, label, help, kind: 'int' | 'float' | 'choice' | 'switch', min, max, choices,
//     presets, default, canBeOff, nkrrOnly, advanced }
//
// A setting's control has the id of its key in kebab case (removeSmall → remove-small) and the
// key as its name. int/float settings with presets are a <select> of them, others a number input;
// choices a <select>; switches a checkbox. Settings that can be off (canBeOff) are off when 0 or
// empty, and are passed to the wasm module as 0 then. nkrrOnly settings are disabled unless the
// method is nkrr; advanced ones sit in a collapsed "Advanced settings" section.

/** The id of a setting's control: its key in kebab case (removeSmall → remove-small). */
export const settingId = (key) => key.replace(/[A-Z]/g, (c) => `-${c.toLowerCase()}`);

/** A table entry with its optional parts filled in. */
function normalise(s) {
  return {
    ...s,
    min: s.min ?? null,
    max: s.max ?? null,
    choices: s.choices ?? [],
    presets: s.presets ?? [],
    default: s.default ?? null,
    canBeOff: !!s.canBeOff,
    nkrrOnly: !!s.nkrrOnly,
    advanced: !!s.advanced,
  };
}

function element(tag, props = {}) {
  return Object.assign(document.createElement(tag), props);
}

export class Settings {
  /**
   * Builds the form inside `container`.
   * @param {object[]} table  the wasm module's settings_table()
   * @param {HTMLElement} container
   * @param {(key: string, text: string) => any} parseText  the wasm module's parse_setting: the
   *   value of a setting's text, or a throw naming the setting and its range
   */
  constructor(table, container, parseText) {
    this.table = Array.from(table, normalise);
    this.parseText = parseText;
    this.byKey = new Map(this.table.map((s) => [s.key, s]));
    this.container = container;
    /** What the share link's settings had wrong (each was not used). */
    this.problems = [];
    /** True when WebGPU runs on a software adapter: #nkrr-note then says why the network is the default. */
    this.softwareAdapter = false;
    this._build();
    container.addEventListener('change', (e) => { if (e.target.name === 'method') this.sync(); });
    this.sync();
  }

  /** The control of setting `key`. */
  control(key) {
    return document.getElementById(settingId(key));
  }

  /** True unless there is a method setting and it is not nkrr. */
  get nkrr() {
    return !this.byKey.has('method') || this.control('method').value === 'nkrr';
  }

  _build() {
    const c = this.container;
    c.classList.add('settings-fields');
    this.problemList = element('ul', { id: 'settings-problems', className: 'warnings', hidden: true });
    this.problemList.setAttribute('role', 'alert');
    this.advanced = element('details', { id: 'advanced-settings', className: 'advanced' });
    const advancedFields = element('div', { className: 'settings-fields' });
    this.advanced.append(element('summary', { textContent: 'Advanced settings' }), advancedFields);
    c.replaceChildren(this.problemList);
    for (const s of this.table) {
      const section = s.advanced ? advancedFields : c;
      let parent = section;
      if (s.nkrrOnly) {
        // Consecutive nkrr-only fields share a fieldset, disabled unless the method is nkrr.
        parent = section.lastElementChild;
        if (!parent?.matches('fieldset.nkrr-only')) {
          parent = element('fieldset', { className: 'nkrr-only' });
          section.append(parent);
        }
      }
      parent.append(this._field(s));
    }
    if (advancedFields.childElementCount) c.append(this.advanced);
    // Prose elsewhere on the page that quotes a default: <span data-setting-default="m">.
    for (const el of document.querySelectorAll('[data-setting-default]')) {
      const s = this.byKey.get(el.dataset.settingDefault);
      if (s) el.textContent = s.default === null ? 'off' : String(s.default);
    }
  }

  _field(s) {
    const label = element('label', { className: 'field', title: s.flag ? `${s.help} (${s.flag})` : s.help });
    label.dataset.setting = s.key;
    let control;
    if (s.kind === 'switch') {
      control = element('input', { type: 'checkbox', defaultChecked: !!s.default });
    } else if (s.kind === 'choice') {
      control = element('select');
      const def = s.default ?? '';
      for (const ch of s.choices) control.append(new Option(ch.label, ch.value, ch.value === def, ch.value === def));
    } else if (s.presets.length) {
      control = element('select');
      const def = s.default ?? 0;
      if (s.canBeOff && !s.presets.some((p) => Number(p.value) === 0)) control.append(new Option('Off', '0'));
      for (const p of s.presets) control.append(new Option(p.label, String(p.value)));
      if (!this._option(control, def)) control.append(new Option(this._presetLabel(s, def), String(def)));
      const o = this._option(control, def);
      o.defaultSelected = o.selected = true;
    } else {
      control = element('input', { type: 'number', step: s.kind === 'int' ? '1' : 'any' });
      // Off (0) is allowed even where the smallest value when on is above 0.
      if (s.min !== null) control.min = String(s.canBeOff ? Math.min(0, s.min) : s.min);
      if (s.max !== null) control.max = String(s.max);
      if (s.canBeOff) control.placeholder = 'off';
      control.defaultValue = s.default === null ? '' : String(s.default);
    }
    control.id = settingId(s.key);
    control.name = s.key;
    label.append(element('span', { textContent: s.label }), control, element('small', { textContent: s.help }));
    return label;
  }

  /** The <option> of `select` whose value is the number `x`. */
  _option(select, x) {
    return [...select.options].find((o) => Number(o.value) === x);
  }

  /** A label for a value the presets do not list, in their style where they share one ("160³"). */
  _presetLabel(s, x) {
    const tails = s.presets.map((p) => (p.label.startsWith(String(p.value)) ? p.label.slice(String(p.value).length) : null));
    return tails.length && tails.every((t) => t !== null && t === tails[0]) ? `${x}${tails[0]}` : String(x);
  }

  /**
   * A setting's value in the form: a number, a string (a choice; '' = as in the file), a
   * boolean (a switch), null (off), or undefined (an empty number field: the default applies).
   */
  value(key) {
    const s = this.byKey.get(key);
    const c = this.control(key);
    if (s.kind === 'switch') return c.checked;
    if (s.kind === 'choice') return c.value;
    const t = c.value.trim();
    if (t === '') return s.canBeOff ? null : undefined;
    const x = Number(t);
    return s.canBeOff && x === 0 ? null : x;
  }

  /**
   * The options for the wasm module's reconstruct() and preflight(): every setting by its key;
   * off is 0; empty choices ('as in the file') and empty number fields are left out. nkrr-only
   * settings are left out unless the method is nkrr or `all` is given.
   */
  readOptions({ all = false } = {}) {
    const o = {};
    const nkrr = this.nkrr;
    for (const s of this.table) {
      if (s.nkrrOnly && !nkrr && !all) continue;
      const v = this.value(s.key);
      if (v === undefined || v === '') continue;
      o[s.key] = v === null ? 0 : v;
    }
    return o;
  }

  _isDefault(s, v) {
    if (v === undefined) return true;
    if (s.kind === 'switch') return v === !!s.default;
    if (s.kind === 'choice') return v === (s.default ?? '');
    return v === s.default;
  }

  /**
   * [key, value] pairs for a share link: every setting that differs from its default (nkrr-only
   * ones only when the method is nkrr), and those named in `always` (settings whose default on
   * the page depends on the machine). Switches are 1 or 0, off is 0.
   */
  shareParams({ always = [] } = {}) {
    const out = [];
    const nkrr = this.nkrr;
    for (const s of this.table) {
      if (s.nkrrOnly && !nkrr) continue;
      const v = this.value(s.key);
      if (v === undefined || (this._isDefault(s, v) && !always.includes(s.key))) continue;
      out.push([s.key, s.kind === 'switch' ? (v ? '1' : '0') : v === null ? '0' : String(v)]);
    }
    return out;
  }

  /** Checks a share link's text for setting `s`: { value } or { error }, by the wasm module's
   *  parse_setting (the settings table's one rule and wording, the CLI's too). */
  _parse(s, text) {
    try {
      return { value: this.parseText(s.key, text) };
    } catch (e) {
      return { error: e.message ?? String(e) };
    }
  }

  _set(s, v) {
    const c = this.control(s.key);
    if (s.kind === 'switch') c.checked = v;
    else if (s.kind === 'choice') c.value = v;
    else if (c instanceof HTMLSelectElement) {
      const x = v ?? 0;
      // A value the menu does not list (say resolution=160) is added, not dropped.
      if (!this._option(c, x)) c.append(new Option(this._presetLabel(s, x), String(x)));
      c.value = this._option(c, x).value;
    } else {
      c.value = v === null ? '' : String(v);
    }
  }

  /** Sets setting `key` from text (as in a share link); returns an error message or null. */
  setFromText(key, text) {
    const s = this.byKey.get(key);
    if (!s) return `${key} is not a setting`;
    const r = this._parse(s, text);
    if (r.error) return `${s.label} (${key}=${text}): ${r.error}; it was not used.`;
    this._set(s, r.value);
    if (s.advanced && !this._isDefault(s, this.value(key))) this.advanced.open = true;
    return null;
  }

  /**
   * Applies every setting a share link's query gives (by key). Values that do not fit their
   * setting are not used; they are listed above the form and returned.
   * @param {URLSearchParams} query
   */
  applyQuery(query) {
    this.problems = [];
    for (const s of this.table) {
      if (!query.has(s.key)) continue;
      const err = this.setFromText(s.key, query.get(s.key));
      if (err) this.problems.push(err);
    }
    const ul = this.problemList;
    ul.replaceChildren(...this.problems.map((p) => element('li', { textContent: `Link: ${p}` })));
    ul.hidden = this.problems.length === 0;
    this.sync();
    return this.problems;
  }

  /** Enables the nkrr-only fields when the method is nkrr; shows #nkrr-note on a software adapter
   *  from the start, so that why the network is the default is said before anyone picks NKRR. */
  sync() {
    const nkrr = this.nkrr;
    for (const fs of this.container.querySelectorAll('fieldset.nkrr-only')) fs.disabled = !nkrr;
    const note = document.getElementById('nkrr-note');
    if (note) note.hidden = !this.softwareAdapter;
  }
}
