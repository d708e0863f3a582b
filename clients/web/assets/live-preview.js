// The live preview's pictures (WebSocket message type "preview", API.md) and
// the parts that draw them, shared by the Station page's live view
// (liveview.js) and the guided calibration (calib-guide.js):
//   createCameraPicture   one camera's picture, swapped whole per frame
//   drawHistogram         a 64-bin grey-level histogram on a <canvas>
//   exposureVerdict       over- / under-exposed, in words
//   createFocusGrid       the focus heat map drawn over a picture
//   drawCorners           the calibration board's corners (SVG) over a picture
//
// app.js hands every preview message to onPreviewMessage; the ones without a
// calibration overlay are the live view's and are emitted as 'preview'
// (the guided calibration's go to jobs.onPreview).

import { h, show } from './dom.js';
import { emit } from './store.js';

export const CLIPPED_WARN_PCT = 1; // more than this share at 255: over-exposed
const DARK_BINS = 8; // grey 0..31
const DARK_WARN_SHARE = 0.5; // more than this share that dark: under-exposed

// The latest live-view frame and when it arrived (ms, this computer's clock).
export const livePreview = { frame: null, at: 0, arrivals: [] };

export function onPreviewMessage(m) {
  if (!m || typeof m !== 'object' || !m.left || !m.right) return;
  if (m.overlay && typeof m.overlay === 'object') return; // a job's frames (guided calibration)
  const now = Date.now();
  livePreview.frame = m;
  livePreview.at = now;
  livePreview.arrivals.push(now);
  if (livePreview.arrivals.length > 9) livePreview.arrivals.shift();
  emit('preview', m);
}

// Frames per second over the last few arrivals (0 when unknown).
export function arrivalRate() {
  const a = livePreview.arrivals;
  if (a.length < 2) return 0;
  const span = a[a.length - 1] - a[0];
  return span > 0 ? ((a.length - 1) * 1000) / span : 0;
}

// now − stamp in ms when the frame's stamp is on this computer's clock (the
// station's and the console's on one machine, or synchronised); null when
// it cannot be (negative or above a minute: another clock, or monotonic).
export function latencyMs(m, receivedAt = Date.now(), field = 'stamp_ns') {
  const stamp = Number(m?.[field]);
  if (!(stamp > 0)) return null;
  const ms = receivedAt - stamp / 1e6;
  return ms > -1000 && ms < 60000 ? Math.max(0, ms) : null;
}

// --- a camera's picture ---

const SVG = 'http://www.w3.org/2000/svg';

// One camera's picture: <figure> with a frame (the <img>, whatever is drawn
// over it) and a caption. load(url, width, height) decodes the new picture
// off the page and resolves to a function that swaps the <img> element whole
// (so a frame is never shown half-loaded, and both cameras' can be swapped
// at once); a picture that does not decode keeps the last good one.
export function createCameraPicture({ testid, label, className = '' }) {
  let img = h('img', { class: 'cam-img', testid, alt: `${label}: live picture` });
  const frame = h('div', { class: 'cam-frame' }, img);
  const caption = h('figcaption', { class: 'cam-caption' }, label);
  const el = h('figure', { class: `cam ${className}`.trim() }, frame, caption);
  let shown = '';
  const keep = () => {};
  async function load(url, width, height) {
    if (!url || url === shown) return keep;
    const next = h('img', { class: 'cam-img', testid, alt: img.alt, src: url });
    try {
      await next.decode();
    } catch {
      return keep;
    }
    return () => {
      if (width > 0 && height > 0) frame.style.aspectRatio = `${width} / ${height}`;
      img.replaceWith(next);
      img = next;
      shown = url;
    };
  }
  return {
    el,
    frame,
    caption,
    load,
    get img() {
      return img;
    },
  };
}

// Decodes both pictures of a preview message `m` ({left: {image}, right:
// {image}, width, height}) and shows them at once.
export async function showPair(pics, m) {
  const w = Number(m.width) || 0;
  const ht = Number(m.height) || 0;
  const swaps = await Promise.all(['left', 'right'].map((side) => pics[side].load(m[side]?.image, w, ht)));
  for (const swap of swaps) swap();
}

// --- histogram ---

// Draws a 64-bin histogram (counts of 4 grey levels each) on `canvas`,
// sized to its box: bars scaled to the tallest bin below the top one, the
// top bin (the clipped pixels) in red reaching as high as its share, the two
// lowest bins in dark blue; the clipped share written in red when above
// CLIPPED_WARN_PCT. Returns the number of bars drawn.
export function drawHistogram(canvas, histogram, { clippedPct = 0 } = {}) {
  const dpr = window.devicePixelRatio || 1;
  const cssW = Math.max(64, Math.round(canvas.clientWidth || 256));
  const cssH = Math.max(32, Math.round(canvas.clientHeight || 72));
  if (canvas.width !== Math.round(cssW * dpr) || canvas.height !== Math.round(cssH * dpr)) {
    canvas.width = Math.round(cssW * dpr);
    canvas.height = Math.round(cssH * dpr);
  }
  const g = canvas.getContext('2d');
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.fillStyle = '#1d2125';
  g.fillRect(0, 0, cssW, cssH);
  // Quarter lines: where grey levels 64, 128, 192 fall.
  g.fillStyle = 'rgb(255 255 255 / 12%)';
  for (let q = 1; q < 4; q++) g.fillRect(Math.round((q * cssW) / 4), 0, 1, cssH);
  const bins = Array.isArray(histogram) ? histogram.map((v) => Math.max(0, Number(v) || 0)) : [];
  if (!bins.length) return 0;
  const total = bins.reduce((a, b) => a + b, 0) || 1;
  const last = bins.length - 1;
  const scale = Math.max(1, ...bins.slice(0, last));
  const barW = cssW / bins.length;
  const top = 4;
  let drawn = 0;
  bins.forEach((v, i) => {
    let frac = Math.min(1, v / scale);
    if (i === last) {
      // The clipped share: 10 % of the image reaches full height.
      const share = Math.max(v / total, clippedPct / 100);
      frac = share > 0 ? Math.max(0.04, Math.min(1, share * 10)) : 0;
    }
    if (frac <= 0) return;
    const barH = Math.max(1, frac * (cssH - top));
    g.fillStyle = i === last ? '#e5483f' : i < 2 ? '#6f8fd8' : '#d9dde1';
    g.fillRect(i * barW + 0.5, cssH - barH, Math.max(1, barW - 1), barH);
    drawn++;
  });
  if (clippedPct > CLIPPED_WARN_PCT) {
    g.fillStyle = '#ff6b61';
    g.font = `600 ${Math.round(Math.min(14, cssH / 4))}px system-ui, sans-serif`;
    g.textAlign = 'right';
    g.textBaseline = 'top';
    g.fillText(`${clippedPct.toFixed(1)} % clipped`, cssW - barW - 4, 3);
  }
  return drawn;
}

// {kind: 'over' | 'under' | '', text}: over-exposed when more than
// CLIPPED_WARN_PCT of the pixels are at 255, under-exposed when most of the
// histogram sits in its lowest bins.
export function exposureVerdict(image) {
  const clipped = Number(image?.clipped_pct) || 0;
  if (clipped > CLIPPED_WARN_PCT) return { kind: 'over', text: 'Over-exposed: lower the exposure' };
  const bins = Array.isArray(image?.histogram) ? image.histogram.map((v) => Number(v) || 0) : [];
  const total = bins.reduce((a, b) => a + b, 0);
  const dark = bins.slice(0, DARK_BINS).reduce((a, b) => a + b, 0);
  const black = Number(image?.black_pct) || 0;
  if (total > 0 && (dark / total > DARK_WARN_SHARE || black > 50)) {
    return { kind: 'under', text: 'Under-exposed: raise the exposure or the gain' };
  }
  return { kind: '', text: '' };
}

// --- focus heat map ---

// Colour of a cell whose sharpness is `ratio` of the best cell's (0..1):
// red (blurred) through amber to green (as sharp as the best).
export function focusColour(ratio, alpha = 0.42) {
  const r = Math.min(1, Math.max(0, ratio));
  const hue = Math.round(120 * r * r); // most cells sit near the top: spread them
  return `hsl(${hue} 85% 45% / ${alpha})`;
}

// A grid laid over a picture; update(focus, rows, cols) colours each cell
// relative to the picture's sharpest and writes its share of it (%).
export function createFocusGrid() {
  const el = h('div', { class: 'focus-grid', 'aria-hidden': 'true' });
  let cells = [];
  let shape = '';
  function update(focus, rows, cols) {
    const values = Array.isArray(focus) ? focus.map((v) => Math.max(0, Number(v) || 0)) : [];
    if (!(rows > 0 && cols > 0) || values.length < rows * cols) {
      show(el, false);
      return;
    }
    if (shape !== `${rows}x${cols}`) {
      shape = `${rows}x${cols}`;
      el.style.gridTemplateColumns = `repeat(${cols}, 1fr)`;
      el.style.gridTemplateRows = `repeat(${rows}, 1fr)`;
      cells = Array.from({ length: rows * cols }, () => h('span', { class: 'focus-cell' }));
      el.replaceChildren(...cells);
    }
    const best = Math.max(...values.slice(0, rows * cols)) || 1;
    cells.forEach((cell, i) => {
      const ratio = values[i] / best;
      cell.style.backgroundColor = focusColour(ratio);
      cell.textContent = `${Math.round(ratio * 100)}`;
      cell.classList.toggle('best', values[i] === best);
    });
  }
  return { el, update };
}

// The legend beside the heat map.
export function focusLegend() {
  return h('div', { class: 'focus-legend', testid: 'focus-legend' },
    h('span', null, 'Focus, % of the sharpest area:'),
    h('span', { class: 'focus-legend-end' }, 'blurred'),
    h('span', { class: 'focus-legend-bar', 'aria-hidden': 'true' }),
    h('span', { class: 'focus-legend-end' }, 'sharper'));
}

// --- calibration board corners ---

export function createCornerLayer() {
  const svg = document.createElementNS(SVG, 'svg');
  svg.setAttribute('class', 'corner-layer');
  svg.setAttribute('aria-hidden', 'true');
  svg.setAttribute('preserveAspectRatio', 'none');
  return svg;
}

// Draws `points` ([[x, y], ...] in the picture's pixels, width × height)
// into `svg`: the board's corners in order joined by a line (as OpenCV's
// drawChessboardCorners does) and a dot at each; `tone` a class: ok | moving | bad.
export function drawCorners(svg, points, width, height, tone) {
  svg.replaceChildren();
  if (width > 0 && height > 0) svg.setAttribute('viewBox', `0 0 ${width} ${height}`);
  svg.setAttribute('class', `corner-layer tone-${tone}`);
  const pts = Array.isArray(points)
    ? points.filter((p) => Array.isArray(p) && Number.isFinite(+p[0]) && Number.isFinite(+p[1]))
    : [];
  svg.dataset.corners = String(pts.length);
  if (!pts.length) return 0;
  const line = document.createElementNS(SVG, 'polyline');
  line.setAttribute('points', pts.map((p) => `${+p[0]},${+p[1]}`).join(' '));
  line.setAttribute('class', 'corner-path');
  line.setAttribute('vector-effect', 'non-scaling-stroke');
  svg.append(line);
  const r = Math.max(2, Math.min(width || 640, height || 480) / 120);
  for (const p of pts) {
    const c = document.createElementNS(SVG, 'circle');
    c.setAttribute('cx', String(+p[0]));
    c.setAttribute('cy', String(+p[1]));
    c.setAttribute('r', String(r));
    c.setAttribute('class', 'corner-dot');
    c.setAttribute('vector-effect', 'non-scaling-stroke');
    svg.append(c);
  }
  return pts.length;
}
