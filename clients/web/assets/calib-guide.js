// The guided-calibration panel (issue 17, item 4). The daemon's guided
// calibration is still to come; this panel is its place in the console. It is
// driven by the progress messages of a calibrate / calibrate-turntable job
// (and any progress whose stage starts with "calibrate") and shows only the
// parts whose fields are present — all of it stays hidden until one is.
//
// Fields read from the message itself or from a "guide" object inside it:
//   advice           string: what to do next ("tilt the top away")
//   corners          data URL, or {left, right} data URLs: the images with the
//                    corners found drawn on them
//   corners_left / corners_right / left / right / image   (the same, flat)
//   coverage         [[0..1, ...], ...] rows of cells, or {rows, cols, cells: [...]},
//                    numbers (fraction covered; counts are scaled to the
//                    largest) or booleans
//   diversity        {x, y, size, skew} each 0..1, or [x, y, size, skew]
//   views_accepted / accepted     int: poses kept so far
//   views_needed / needed / wanted int: poses wanted
//   rejected / refused            string: why the last pose was refused
//   verdict, rms_px, epipolar_px  the outcome when it is known
// Any other extra scalar field is listed as it is ("Other details").

import { h, replace, show } from './dom.js';
import { fmtValue, humanize } from './format.js';

const BASE_KEYS = new Set(['type', 'job_id', 'stage', 'current', 'total', 'message', 'guide']);
const IMAGE_KEYS = ['corners', 'corners_left', 'corners_right', 'left', 'right', 'image'];
const KNOWN_KEYS = new Set([
  ...IMAGE_KEYS, 'advice', 'coverage', 'diversity', 'views_accepted', 'accepted',
  'views_needed', 'needed', 'wanted', 'rejected', 'refused', 'verdict', 'rms_px', 'epipolar_px',
]);

// The guide fields of a progress message ({} when it has none).
export function guideFields(msg) {
  const out = {};
  const sources = [msg];
  if (msg && typeof msg.guide === 'object' && msg.guide) sources.push(msg.guide);
  for (const src of sources) {
    for (const [key, value] of Object.entries(src)) {
      if (src === msg && BASE_KEYS.has(key)) continue;
      if (value === undefined || value === null) continue;
      out[key] = value;
    }
  }
  return out;
}

function isImageUrl(v) {
  return typeof v === 'string' && (v.startsWith('data:image/') || v.startsWith('blob:') ||
    (v.startsWith('/') && !v.startsWith('//')));
}

function images(g) {
  const list = [];
  const add = (url, caption) => {
    if (isImageUrl(url)) list.push({ url, caption });
  };
  if (g.corners && typeof g.corners === 'object') {
    add(g.corners.left, 'Left camera');
    add(g.corners.right, 'Right camera');
  } else add(g.corners, 'Corners found');
  add(g.corners_left, 'Left camera');
  add(g.corners_right, 'Right camera');
  add(g.left, 'Left camera');
  add(g.right, 'Right camera');
  add(g.image, 'Camera');
  return list;
}

// Coverage as {rows, cols, cells: [0..1]} or null.
function coverageGrid(c) {
  let rows;
  let cols;
  let cells;
  if (Array.isArray(c) && c.length && Array.isArray(c[0])) {
    rows = c.length;
    cols = Math.max(...c.map((r) => (Array.isArray(r) ? r.length : 0)));
    cells = [];
    for (const r of c) for (let i = 0; i < cols; i++) cells.push(Array.isArray(r) ? r[i] : 0);
  } else if (c && typeof c === 'object' && Array.isArray(c.cells)) {
    cells = c.cells;
    cols = Number(c.cols) || Math.round(Math.sqrt(cells.length));
    rows = Number(c.rows) || Math.ceil(cells.length / cols);
  } else if (Array.isArray(c) && c.length) {
    cells = c;
    cols = Math.round(Math.sqrt(c.length));
    rows = Math.ceil(c.length / cols);
  } else return null;
  if (!(rows > 0 && cols > 0 && rows * cols <= 4096)) return null;
  let values = cells.map((v) => (typeof v === 'boolean' ? (v ? 1 : 0) : Number(v) || 0));
  const max = Math.max(...values);
  if (max > 1) values = values.map((v) => v / max);
  return { rows, cols, cells: values };
}

function diversityBars(d) {
  const names = [['x', 'X (left ↔ right)'], ['y', 'Y (top ↔ bottom)'], ['size', 'Size (near ↔ far)'], ['skew', 'Skew (tilt)']];
  const bars = [];
  names.forEach(([key, label], i) => {
    const v = Array.isArray(d) ? d[i] : d?.[key];
    if (typeof v === 'number' && Number.isFinite(v)) bars.push({ key, label, value: Math.min(1, Math.max(0, v)) });
  });
  return bars;
}

export function createGuide() {
  const advice = h('p', { class: 'guide-advice', testid: 'calib-advice', role: 'status', 'aria-live': 'polite' });
  const rejected = h('p', { class: 'guide-rejected', testid: 'calib-rejected' });
  const counts = h('p', { class: 'guide-counts', testid: 'calib-counts' });
  const corners = h('div', { class: 'guide-images', testid: 'calib-corners' });
  const coverageGridEl = h('div', { class: 'coverage-grid', role: 'img' });
  const coverage = h('div', { class: 'guide-coverage', testid: 'calib-coverage' },
    h('h4', null, 'Coverage of the image'), coverageGridEl);
  const diversityList = h('div', { class: 'diversity-list' });
  const diversity = h('div', { class: 'guide-diversity', testid: 'calib-diversity' },
    h('h4', null, 'Variety of board poses'), diversityList);
  const extraList = h('dl', { class: 'kv' });
  const extra = h('details', { class: 'guide-extra', testid: 'calib-extra' },
    h('summary', null, 'Other details'), extraList);
  const el = h('section', { class: 'guide', testid: 'calib-guide', 'aria-label': 'Calibration guidance' },
    advice, rejected, counts,
    h('div', { class: 'guide-grid' }, corners, h('div', { class: 'guide-side' }, coverage, diversity)),
    extra);

  let last;
  function update(g = {}) {
    if (g === last) return; // unchanged (tracks replace the object on change)
    last = g;
    let any = false;

    const adviceText = typeof g.advice === 'string' ? g.advice : '';
    advice.textContent = adviceText;
    show(advice, !!adviceText);
    any = any || !!adviceText;

    const why = typeof g.rejected === 'string' ? g.rejected : typeof g.refused === 'string' ? g.refused : '';
    rejected.textContent = why ? `Pose not used: ${why}` : '';
    show(rejected, !!why);
    any = any || !!why;

    const accepted = g.views_accepted ?? g.accepted;
    const needed = g.views_needed ?? g.needed ?? g.wanted;
    const parts = [];
    if (typeof accepted === 'number') parts.push(typeof needed === 'number' ? `${accepted} of ${needed} poses kept` : `${accepted} poses kept`);
    if (typeof g.verdict === 'string' && g.verdict) parts.push(`Verdict: ${g.verdict}`);
    if (typeof g.rms_px === 'number') parts.push(`RMS ${fmtValue('rms_px', g.rms_px)}`);
    if (typeof g.epipolar_px === 'number') parts.push(`epipolar error ${fmtValue('epipolar_px', g.epipolar_px)}`);
    counts.textContent = parts.join(' · ');
    show(counts, parts.length > 0);
    any = any || parts.length > 0;

    const imgs = images(g);
    replace(corners, imgs.map(({ url, caption }) => h('figure', null,
      h('img', { src: url, alt: `${caption}: calibration board with the corners found`, decoding: 'async' }),
      h('figcaption', null, caption))));
    show(corners, imgs.length > 0);
    any = any || imgs.length > 0;

    const grid = g.coverage !== undefined ? coverageGrid(g.coverage) : null;
    if (grid) {
      coverageGridEl.style.gridTemplateColumns = `repeat(${grid.cols}, 1fr)`;
      const covered = grid.cells.filter((v) => v > 0).length;
      coverageGridEl.setAttribute('aria-label',
        `${covered} of ${grid.cells.length} image areas covered by the board`);
      replace(coverageGridEl, grid.cells.map((v) =>
        h('span', { class: `cov cov-${Math.min(4, Math.ceil(v * 4))}` })));
    }
    show(coverage, !!grid);
    any = any || !!grid;

    const bars = g.diversity !== undefined ? diversityBars(g.diversity) : [];
    replace(diversityList, bars.map((b) => {
      const id = `div-${b.key}`;
      return h('div', { class: 'diversity-row', dataset: { axis: b.key } },
        h('label', { for: id }, b.label),
        h('progress', { id, max: '1', value: String(b.value) }),
        h('span', { class: 'diversity-value' }, `${Math.round(b.value * 100)}%`));
    }));
    show(diversity, bars.length > 0);
    any = any || bars.length > 0;

    const extras = Object.entries(g).filter(([k, v]) => !KNOWN_KEYS.has(k) &&
      (typeof v === 'number' || typeof v === 'string' || typeof v === 'boolean'));
    replace(extraList, extras.map(([k, v]) => [h('dt', null, humanize(k)), h('dd', null, fmtValue(k, v))]));
    show(extra, extras.length > 0);
    any = any || extras.length > 0;

    show(el, any);
  }

  update({});
  return { el, update };
}
