// Small helpers shared by the page's modules (web/app.js, web/result.js, web/settings.js).

export const $ = (id) => document.getElementById(id);

export const fmt = new Intl.NumberFormat('en-US');

/** A number to 5 significant digits, without trailing zeros. */
export const num = (x) => Number(x.toPrecision(5)).toString();

/** Seconds for display: "3.25 s", "42.1 s". */
export const secs = (s) => (s < 10 ? s.toFixed(2) : s.toFixed(1)) + ' s';

/** Replaces a list's items with one <li> per text. */
export function setItems(ul, texts) {
  ul.replaceChildren(...texts.map((t) => Object.assign(document.createElement('li'), { textContent: t })));
}
