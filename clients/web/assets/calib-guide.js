// The guided-calibration panel (issue 17, item 4). While the calibrate job
// runs, the daemon streams preview frames (API.md, message type "preview")
// whose `overlay` is its feedback; jobs.onPreview files the latest on the
// calibrate track (t.guide, with the frame in t.guideFrame) and this panel
// shows it:
//   {kind: "calibration",
//    state: "searching" | "moving" | "holding" | "captured" | "rejected" | "solving",
//    board: {left: [[x, y], ...], right: [...]} | null   (corners, in the JPEG's pixels),
//    hold_s, hold_needed_s,                                (holding still, seconds)
//    coverage: {cols, rows, cells: [0 | 1, ...]}           (row-major, left image),
//    diversity: {x, y, size, skew}                         (each 0..1; 1 = enough),
//    views_accepted, views_needed, rejected: "" | why, advice: "…"}
// or, for the turntable axis (calibrate-turntable, guided), mode: "turntable"
// with no coverage or diversity but the angle being measured and the steps:
//   {kind: "calibration", mode: "turntable", state (… | "missed"), board,
//    hold_s, hold_needed_s (the board lying still before it turns),
//    angle_deg: null (placing) | degrees, steps: [{angle_deg, found}, ...],
//    views_accepted (angles measured), views_needed (angles), rejected, advice}
// shown as the angles measured (✓) and missed (✗).
// Both cameras' live pictures with the corners drawn over them (green when
// holding or captured, amber while the board moves, red when the view was
// refused), the advice in large type, the views kept, the hold-still
// progress, the coverage grid and the four variety bars (as ROS's
// camera_calibration shows X, Y, Size, Skew). When the job is over the
// pictures, advice and hold go; what the views covered stays beside the
// verdict (page-calibrate.js). Hidden until the first overlay.

import { h, replace, show } from './dom.js';
import { fmtNumber, fmtValue, humanize } from './format.js';
import { createCameraPicture, createCornerLayer, drawCorners, showPair } from './live-preview.js';

const KNOWN_KEYS = new Set([
  'kind', 'state', 'board', 'hold_s', 'hold_needed_s', 'coverage', 'diversity',
  'views_accepted', 'views_needed', 'rejected', 'advice', 'mode', 'angle_deg', 'steps',
]);

const STATE_WORDS = {
  searching: 'Looking for the board',
  moving: 'Board found: hold it still',
  holding: 'Hold still…',
  captured: 'View captured',
  rejected: 'View not used',
  solving: 'Computing the calibration',
  missed: 'Angle not measured',
};
const TURNTABLE_WORDS = {
  moving: 'Board moving: let it lie still',
  holding: 'Board lying still…',
  captured: 'Measured',
};

// The corners' colour for a state: ok (green), moving (amber), bad (red).
export function cornerTone(state) {
  if (state === 'holding' || state === 'captured') return 'ok';
  if (state === 'rejected') return 'bad';
  return 'moving';
}

// Coverage as {rows, cols, cells: [0..1]} or null: {cols, rows, cells},
// rows of cells ([[...], ...]) or a flat square list; booleans or numbers
// (counts are scaled to the largest).
export function coverageGrid(c) {
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
  let values = Array.from({ length: rows * cols }, (_, i) => {
    const v = cells[i];
    return typeof v === 'boolean' ? (v ? 1 : 0) : Number(v) || 0;
  });
  const max = Math.max(...values);
  if (max > 1) values = values.map((v) => v / max);
  return { rows, cols, cells: values };
}

const AXES = [['x', 'X', 'left ↔ right'], ['y', 'Y', 'top ↔ bottom'], ['size', 'Size', 'near ↔ far'], ['skew', 'Skew', 'tilt']];

function diversityBars(d) {
  const bars = [];
  AXES.forEach(([key, label, hint], i) => {
    const v = Array.isArray(d) ? d[i] : d?.[key];
    if (typeof v === 'number' && Number.isFinite(v)) bars.push({ key, label, hint, value: Math.min(1, Math.max(0, v)) });
  });
  return bars;
}

export function createGuide() {
  const stateEl = h('p', { class: 'guide-state', testid: 'calib-state' });
  const counts = h('p', { class: 'guide-counts', testid: 'calib-counts' });
  const countsBar = h('progress', { class: 'guide-counts-bar', max: '1', value: '0', 'aria-label': 'Views kept' });
  const advice = h('p', { class: 'guide-advice', testid: 'calib-advice', role: 'status', 'aria-live': 'polite' });
  const rejected = h('p', { class: 'guide-rejected', testid: 'calib-rejected', role: 'alert' });
  const holdBar = h('progress', { max: '1', value: '0', 'aria-label': 'Holding still' });
  const holdText = h('span', { class: 'guide-hold-text' });
  const hold = h('div', { class: 'guide-hold', testid: 'calib-hold' }, holdText, holdBar);

  const pics = {
    left: createCameraPicture({ testid: 'calib-left', label: 'Left camera' }),
    right: createCameraPicture({ testid: 'calib-right', label: 'Right camera' }),
  };
  const layers = { left: createCornerLayer(), right: createCornerLayer() };
  for (const side of ['left', 'right']) pics[side].frame.append(layers[side]);
  const corners = h('div', { class: 'guide-images', testid: 'calib-corners' }, pics.left.el, pics.right.el);

  const coverageGridEl = h('div', { class: 'coverage-grid', role: 'img' });
  const coverageNote = h('p', { class: 'hint' });
  const coverage = h('div', { class: 'guide-coverage', testid: 'calib-coverage' },
    h('h4', null, 'Coverage of the left image'), coverageGridEl, coverageNote);
  const diversityList = h('div', { class: 'diversity-list' });
  const diversity = h('div', { class: 'guide-diversity', testid: 'calib-diversity' },
    h('h4', null, 'Variety of board poses'), diversityList,
    h('p', { class: 'hint' }, 'Each bar fills as the board is shown in enough places, distances and tilts.'));
  const anglesList = h('ul', { class: 'guide-angles' });
  const angles = h('div', { class: 'guide-angles-box', testid: 'calib-angles' },
    h('h4', null, 'Turntable angles measured'), anglesList);
  const extraList = h('dl', { class: 'kv' });
  const extra = h('details', { class: 'guide-extra', testid: 'calib-extra' },
    h('summary', null, 'Other details'), extraList);
  const endedNote = h('p', { class: 'muted' }, 'The guided calibration has ended. What its views covered:');
  const el = h('section', { class: 'guide', testid: 'calib-guide', 'aria-label': 'Calibration guidance' },
    h('div', { class: 'guide-head' }, stateEl, h('div', { class: 'guide-count-box' }, counts, countsBar)),
    endedNote, advice, rejected, hold,
    h('div', { class: 'guide-grid' }, corners, h('div', { class: 'guide-side' }, coverage, diversity, angles)),
    extra);

  let lastGuide;
  let lastRunning;
  let lastFrame;
  let pending = null; // the newest {g, m} whose pictures are not shown yet
  let drawing = false;

  // Shows frames one at a time, always the newest next: a picture is
  // decoded before it replaces the last, and the corners follow it.
  async function drawPictures() {
    drawing = true;
    while (pending) {
      const { g, m } = pending;
      pending = null;
      const w = Number(m.width) || 0;
      const ht = Number(m.height) || 0;
      await showPair(pics, m);
      const board = g.board && typeof g.board === 'object' ? g.board : null;
      for (const side of ['left', 'right']) {
        const n = drawCorners(layers[side], board?.[side], w, ht, cornerTone(g.state));
        // Turning, the axis is measured in the left image only.
        const unused = !n && side === 'right' && g.mode === 'turntable' && g.angle_deg != null;
        pics[side].caption.textContent = `${side === 'left' ? 'Left' : 'Right'} camera · ${
          n ? `${n} corners` : unused ? 'not used while turning' : 'board not found'}`;
      }
      corners.dataset.state = g.state ?? '';
      corners.dataset.frame = String(m.frame ?? '');
    }
    drawing = false;
  }

  // t: the calibrate track (jobs.js) or null.
  function update(t) {
    const g = t?.guide ?? null;
    const running = !!t?.running;
    if (g === lastGuide && running === lastRunning) return;
    lastGuide = g;
    lastRunning = running;
    if (!g || typeof g !== 'object') {
      show(el, false);
      return;
    }
    const state = typeof g.state === 'string' ? g.state : '';
    el.dataset.state = state;
    el.dataset.running = String(running);
    show(el, true);
    show(endedNote, !running);

    const words = (g.mode === 'turntable' && TURNTABLE_WORDS[state]) || STATE_WORDS[state];
    stateEl.textContent = running ? words ?? humanize(state || 'waiting') : 'Guided calibration';
    stateEl.dataset.state = running ? state : '';

    const accepted = Number(g.views_accepted);
    const needed = Number(g.views_needed);
    const haveCounts = Number.isFinite(accepted) && g.views_accepted !== undefined;
    const turntable = g.mode === 'turntable';
    const unit = turntable ? 'angles' : 'views';
    counts.textContent = haveCounts
      ? (Number.isFinite(needed) && needed > 0 ? `${accepted} of ${needed} ${unit}` : `${accepted} ${unit}`)
      : '';
    counts.dataset.accepted = haveCounts ? String(accepted) : '';
    counts.dataset.needed = Number.isFinite(needed) ? String(needed) : '';
    show(counts, haveCounts);
    if (haveCounts && needed > 0) {
      countsBar.max = needed;
      countsBar.value = Math.min(accepted, needed);
    }
    show(countsBar, haveCounts && needed > 0);

    let adviceText = typeof g.advice === 'string' ? g.advice : '';
    if (!adviceText && state === 'solving') adviceText = 'Computing the calibration…';
    advice.textContent = adviceText;
    show(advice, running && !!adviceText);

    const why = typeof g.rejected === 'string' ? g.rejected : '';
    rejected.textContent = why ? `Last view not used: ${why}` : '';
    show(rejected, running && !!why);

    const holdS = Number(g.hold_s) || 0;
    const holdNeeded = Number(g.hold_needed_s) || 0;
    const holding = running && holdNeeded > 0 && ['moving', 'holding', 'captured'].includes(state);
    if (holding) {
      const done = state === 'captured' ? holdNeeded : Math.min(holdS, holdNeeded);
      holdBar.max = holdNeeded;
      holdBar.value = done;
      holdText.textContent = state === 'captured' ? (turntable ? 'Measured ✓' : 'Captured ✓')
        : `${turntable ? 'Lying still' : 'Hold still'}: ${fmtNumber(done, 1)} of ${fmtNumber(holdNeeded, 1)} s`;
      hold.dataset.holdS = String(done);
      hold.dataset.state = state;
    }
    show(hold, holding);

    const m = t.guideFrame;
    const pictures = running && m && m.left && m.right;
    if (pictures && m !== lastFrame) {
      lastFrame = m;
      pending = { g, m };
      if (!drawing) drawPictures();
    }
    show(corners, !!pictures);

    const grid = g.coverage !== undefined ? coverageGrid(g.coverage) : null;
    if (grid) {
      coverageGridEl.style.gridTemplateColumns = `repeat(${grid.cols}, 1fr)`;
      const w = Number(m?.width) || 4;
      const ht = Number(m?.height) || 3;
      coverageGridEl.style.aspectRatio = `${w} / ${ht}`;
      const covered = grid.cells.filter((v) => v > 0).length;
      const words = `${covered} of ${grid.cells.length} areas of the image covered by the board`;
      coverageGridEl.setAttribute('aria-label', words);
      coverageNote.textContent = covered < grid.cells.length && running
        ? `${words}: show it in the empty ones.` : `${words}.`;
      coverage.dataset.covered = String(covered);
      coverage.dataset.cells = String(grid.cells.length);
      replace(coverageGridEl, grid.cells.map((v) =>
        h('span', { class: `cov cov-${Math.min(4, Math.ceil(v * 4))}` })));
    }
    show(coverage, !!grid);

    const bars = g.diversity !== undefined ? diversityBars(g.diversity) : [];
    replace(diversityList, bars.map((b) => {
      const id = `div-${b.key}`;
      return h('div', { class: `diversity-row${b.value >= 1 ? ' enough' : ''}`, dataset: { axis: b.key, value: String(b.value) } },
        h('label', { for: id }, h('strong', null, b.label), h('span', { class: 'muted' }, ` ${b.hint}`)),
        h('progress', { id, max: '1', value: String(b.value) }),
        h('span', { class: 'diversity-value' }, b.value >= 1 ? '✓' : `${Math.round(b.value * 100)}%`));
    }));
    show(diversity, bars.length > 0);

    const steps = Array.isArray(g.steps) ? g.steps.filter((x) => x && typeof x === 'object') : [];
    replace(anglesList, steps.map((x) => h('li', {
      class: x.found ? 'found' : 'missed',
      dataset: { angle: String(x.angle_deg), found: String(!!x.found) },
    }, `${fmtNumber(Number(x.angle_deg), 0)}° ${x.found ? '✓' : '✗'}`)));
    angles.dataset.found = String(steps.filter((x) => x.found).length);
    show(angles, turntable);

    const extras = Object.entries(g).filter(([k, v]) => !KNOWN_KEYS.has(k) &&
      (typeof v === 'number' || typeof v === 'string' || typeof v === 'boolean'));
    replace(extraList, extras.map(([k, v]) => [h('dt', null, humanize(k)), h('dd', null, fmtValue(k, v))]));
    show(extra, extras.length > 0);
  }

  update(null);
  return { el, update };
}
