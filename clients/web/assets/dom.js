// Small DOM helpers for the craftscan console. Everything the console shows
// is built with these (never with HTML strings), so text from the station is
// always inserted as text, and nothing needs an inline style or handler (the
// server's Content-Security-Policy forbids both).

// h('button', {class: 'btn', testid: 'scan-start', onclick: fn}, 'Start')
//   class    → className          testid  → data-testid
//   dataset  → data-* attributes   text    → textContent
//   on<evt>  → addEventListener   value / checked / disabled / hidden → properties
//   other    → setAttribute (true → "", false / null / undefined → left out)
// Children: nodes, strings, numbers, arrays of those; null / false are skipped.
export function h(tag, props, ...children) {
  const el = document.createElement(tag);
  if (props) {
    for (const [key, value] of Object.entries(props)) {
      if (value === undefined || value === null || value === false) continue;
      if (key === 'class') el.className = value;
      else if (key === 'testid') el.dataset.testid = value;
      else if (key === 'dataset') Object.assign(el.dataset, value);
      else if (key === 'text') el.textContent = String(value);
      else if (key.startsWith('on') && typeof value === 'function') {
        el.addEventListener(key.slice(2), value);
      } else if (key === 'value' || key === 'checked' || key === 'disabled' || key === 'hidden') {
        el[key] = value;
      } else if (key === 'style') {
        throw new Error('h(): no inline styles (CSP); use a class or element.style');
      } else el.setAttribute(key, value === true ? '' : String(value));
    }
  }
  append(el, children);
  return el;
}

// Appends nodes / strings / (nested) arrays of them; null and false are skipped.
export function append(el, ...children) {
  for (const child of children.flat(Infinity)) {
    if (child === null || child === undefined || child === false) continue;
    el.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return el;
}

// Removes every child of `el` and appends `children`.
export function replace(el, ...children) {
  el.replaceChildren();
  return append(el, children);
}

// Shows or hides `el` with the hidden attribute.
export function show(el, visible) {
  el.hidden = !visible;
  return el;
}

// A label + control pair: <div class="field"><label for=id>text</label>control hint</div>
let nextId = 1;
export function field(labelText, control, hint) {
  if (!control.id) control.id = `f${nextId++}`;
  const parts = [h('label', { for: control.id }, labelText), control];
  if (hint) {
    const hintEl = typeof hint === 'string' ? h('p', { class: 'hint' }, hint) : hint;
    if (!hintEl.id) hintEl.id = `${control.id}-hint`;
    control.setAttribute('aria-describedby', hintEl.id);
    parts.push(hintEl);
  }
  return h('div', { class: 'field' }, parts);
}
