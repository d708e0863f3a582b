// A finished session, shown the same way on the Scan and Sessions pages: the
// 3D view, the measurements from report.json, the report and the downloads.

import { h, replace } from './dom.js';
import { fmtBytes, fmtDate, fmtValue, humanize } from './format.js';
import { api, fileUrl } from './api.js';
import { createViewerPanel } from './viewer.js';

const isScalar = (v) => typeof v === 'number' || typeof v === 'string' || typeof v === 'boolean';
const isVec = (v) => Array.isArray(v) && v.length > 0 && v.length <= 4 && v.every((x) => typeof x === 'number');

// <dl> of an object's scalar (and short numeric vector) fields.
function kvList(obj, skip = []) {
  const rows = [];
  for (const [key, value] of Object.entries(obj ?? {})) {
    if (skip.includes(key)) continue;
    if (!(isScalar(value) || isVec(value))) continue;
    if (value === '') continue;
    rows.push(h('dt', null, humanize(key)), h('dd', { dataset: { key } }, fmtValue(key, value)));
  }
  return rows.length ? h('dl', { class: 'kv' }, rows) : null;
}

function section(title, ...content) {
  const body = content.flat().filter(Boolean);
  if (!body.length) return null;
  return h('section', { class: 'report-section' }, h('h4', null, title), body);
}

const mmFormat = new Intl.NumberFormat(undefined, { minimumFractionDigits: 1, maximumFractionDigits: 1 });
function mm(v) {
  return mmFormat.format(v);
}

// The measurements of a report.json (ScanReportJson), generically: every
// scalar field it has, grouped, with the box's L × W × H first when measured.
export function renderMeasurements(report) {
  const root = h('div', { class: 'measurements', testid: 'measurements' });
  if (!report || typeof report !== 'object') {
    root.append(h('p', { class: 'muted' }, 'No measurements for this session.'));
    return root;
  }
  const m = report.measurement && typeof report.measurement === 'object' ? report.measurement : {};
  const box = m.box && typeof m.box === 'object' ? m.box : null;
  const obb = m.oriented_box && typeof m.oriented_box === 'object' ? m.oriented_box : null;
  const dims = box && box.status !== 'failed' && Array.isArray(box.dims_mm) && box.dims_mm.length === 3 &&
    box.dims_mm.every(Number.isFinite) ? box.dims_mm : null;

  const headline = [];
  if (dims) {
    headline.push(h('div', { class: 'headline-size', testid: 'measurement-dims' },
      h('span', { class: 'headline-label' }, 'Box size  L × W × H'),
      h('span', { class: 'headline-value' }, `${dims.map(mm).join(' × ')} mm`)));
  }
  if (obb && Array.isArray(obb.extents_mm) && obb.extents_mm.length === 3 && obb.extents_mm.every(Number.isFinite)) {
    headline.push(h('div', { class: dims ? 'headline-size secondary' : 'headline-size', testid: 'measurement-extents' },
      h('span', { class: 'headline-label' }, 'Overall size (oriented bounding box)'),
      h('span', { class: 'headline-value' }, `${obb.extents_mm.map(mm).join(' × ')} mm`)));
  }
  if (headline.length) root.append(h('div', { class: 'headline' }, headline));
  else root.append(h('p', { class: 'muted' }, 'No size was measured for this object.'));

  const notes = [];
  if (report.ok === false) notes.push(`The reconstruction reported a problem: ${report.message || 'no details'}`);
  if (box && box.status === 'failed') notes.push(`Box faces not measured: ${box.message || 'no details'}`);
  if (typeof report.box_measurement_error === 'string' && report.box_measurement_error) {
    notes.push(`Box faces not measured: ${report.box_measurement_error}`);
  }
  for (const n of notes) root.append(h('p', { class: 'note warn' }, n));

  const handled = new Set(['ok', 'message', 'measurement', 'box_measurement_error', 'views', 'quality',
    'loop_closure', 'mesh', 'fused_points', 'fusion', 'free_space_check', 'times', 'frame',
    'turntable_from_view0', 'closing_registration']);

  const summary = {};
  if (typeof report.fused_points === 'number') summary.points_in_the_cloud = report.fused_points;
  if (report.mesh && typeof report.mesh === 'object') {
    if (typeof report.mesh.vertices === 'number') summary.mesh_vertices = report.mesh.vertices;
    if (typeof report.mesh.faces === 'number') summary.mesh_triangles = report.mesh.faces;
  }
  if (Array.isArray(report.views)) summary.views = report.views.length;
  if (typeof report.frame === 'string') summary.frame = report.frame === 'turntable' ? 'turntable axis' : report.frame;
  if (obb && typeof obb.points === 'number') summary.points_measured = obb.points;

  const viewErrors = Array.isArray(report.views)
    ? report.views.filter((v) => v && typeof v.error === 'string' && v.error)
      .map((v) => h('li', null, `View ${v.index}: ${v.error}`))
    : [];

  const others = [];
  const otherSections = [];
  for (const [key, value] of Object.entries(report)) {
    if (handled.has(key)) continue;
    if (isScalar(value) || isVec(value)) others.push([key, value]);
    else if (value && typeof value === 'object' && !Array.isArray(value)) {
      const list = kvList(value);
      if (list) otherSections.push(section(humanize(key), list));
    }
  }

  const groups = [
    section('Model', kvList(summary)),
    section('Surface quality', kvList(report.quality)),
    box ? section('Box measurement quality', kvList(box.quality), kvList(box, ['status', 'message', 'dims_mm'])) : null,
    section('Turntable loop', kvList(report.loop_closure, ['message', 'model'])),
    section('Fusion', kvList(report.fusion)),
    section('Free-space check', kvList(report.free_space_check)),
    viewErrors.length ? section('Views with problems', h('ul', null, viewErrors)) : null,
    ...otherSections,
    others.length ? section('Other', kvList(Object.fromEntries(others))) : null,
  ].filter(Boolean);
  for (const g of groups) root.append(g);

  const times = kvList(report.times);
  if (times) root.append(h('details', { class: 'report-section' }, h('summary', null, 'Processing times'), times));
  return root;
}

const MAIN_FILES = ['report.html', 'fused.ply', 'mesh.ply', 'mesh.obj', 'report.json'];
const FILE_WORDS = {
  'report.html': 'Report (web page)',
  'fused.ply': 'Point cloud (PLY)',
  'mesh.ply': 'Mesh (PLY)',
  'mesh.obj': 'Mesh (OBJ)',
  'report.json': 'Measurements (JSON)',
};

// The download links of a session's outputs ({name: {size, fnv1a64}}).
export function renderDownloads(id, outputs) {
  const names = Object.keys(outputs ?? {});
  const main = MAIN_FILES.filter((n) => names.includes(n));
  const rest = names.filter((n) => !MAIN_FILES.includes(n)).sort();
  const item = (name) => {
    const size = outputs[name]?.size;
    return h('li', null,
      h('a', { href: fileUrl(id, name), download: name.split('/').pop(), dataset: { file: name } },
        FILE_WORDS[name] ?? name),
      FILE_WORDS[name] ? h('span', { class: 'muted' }, ` ${name}`) : null,
      typeof size === 'number' ? h('span', { class: 'muted' }, ` · ${fmtBytes(size)}`) : null);
  };
  const el = h('div', { class: 'downloads', testid: 'downloads' }, h('h4', null, 'Downloads'));
  if (!names.length) {
    el.append(h('p', { class: 'muted' }, 'This session has no outputs yet.'));
    return el;
  }
  el.append(h('ul', { class: 'file-list' }, main.map(item)));
  if (rest.length) {
    el.append(h('details', null, h('summary', null, `Other files (${rest.length})`),
      h('ul', { class: 'file-list' }, rest.map(item))));
  }
  return el;
}

// {el, dispose()}: session `id` with its viewer, measurements, report link
// and downloads. `extra(manifest)` may add elements under the heading (the
// Sessions page's resume button). Fetches GET /api/sessions/<id> itself.
export function createSessionPanel(id, { title, extra } = {}) {
  const head = h('div', { class: 'panel-head' }, h('h3', null, title ?? `Session ${id}`));
  const meta = h('div', { class: 'session-meta' });
  const viewerSlot = h('div', { class: 'viewer-slot' });
  const side = h('div', { class: 'result-side' }, h('p', { class: 'muted' }, 'Loading the session…'));
  const el = h('section', { class: 'card session-panel', dataset: { session: id }, 'aria-label': `Session ${id}` },
    head, meta, h('div', { class: 'result-grid' }, viewerSlot, side));
  let viewer = null;
  let disposed = false;

  const load = async () => {
    let info = null;
    let infoError = '';
    try {
      info = await api.session(id);
    } catch (e) {
      infoError = e.message;
    }
    if (disposed) return;
    const manifest = info && typeof info.manifest === 'object' && info.manifest ? info.manifest : null;
    const outputs = manifest && manifest.outputs && typeof manifest.outputs === 'object' ? manifest.outputs : null;
    // Without the manifest, try the usual files anyway.
    const has = (name) => (outputs ? name in outputs : true);

    const metaParts = [];
    if (manifest) {
      const objectName = manifest.object?.name ?? manifest.object_name ?? '';
      if (objectName) metaParts.push(h('span', null, h('strong', null, objectName)));
      if (manifest.state) metaParts.push(h('span', { class: `badge state-${manifest.state}` }, manifest.state));
      if (manifest.params?.views) metaParts.push(h('span', null, `${manifest.params.views} views`));
      if (manifest.created) metaParts.push(h('span', null, `created ${fmtDate(manifest.created)}`));
      if (info.intact === false) metaParts.push(h('span', { class: 'badge state-failed' }, 'damaged'));
    }
    replace(meta, metaParts);
    if (manifest?.error) meta.append(h('p', { class: 'note warn' }, manifest.error));
    if (Array.isArray(info?.problems) && info.problems.length) {
      meta.append(h('details', { class: 'note warn' }, h('summary', null, `Problems found (${info.problems.length})`),
        h('ul', null, info.problems.map((p) => h('li', null, String(p))))));
    }
    if (infoError) meta.append(h('p', { class: 'note warn' }, `Could not read the session: ${infoError}`));
    if (extra) {
      const more = extra(manifest);
      if (more) head.append(more);
    }

    const cloudUrl = has('fused.ply') ? fileUrl(id, 'fused.ply') : null;
    const meshUrl = has('mesh.ply') ? fileUrl(id, 'mesh.ply') : null;
    if (cloudUrl || meshUrl) {
      viewer = createViewerPanel({ cloudUrl, meshUrl, label: `3D model of session ${id}` });
      viewerSlot.append(viewer.el);
    } else {
      viewerSlot.append(h('div', { class: 'viewer-empty' },
        h('p', null, 'No 3D model yet.'),
        h('p', { class: 'muted' }, manifest?.state === 'done'
          ? 'This session was a capture only.'
          : 'The model is made when the scan finishes.')));
    }

    let report = null;
    let reportError = '';
    if (has('report.json')) {
      try {
        report = await api.fileJson(id, 'report.json');
      } catch (e) {
        reportError = e.status === 404 ? '' : e.message;
      }
    }
    if (disposed) return;
    const links = [];
    if (has('report.html')) {
      links.push(h('a', { class: 'btn btn-secondary', href: fileUrl(id, 'report.html'), target: '_blank',
        rel: 'noopener', testid: 'report-link' }, 'Open the full report'));
    }
    replace(side,
      h('h4', null, 'Measurements'),
      renderMeasurements(report),
      reportError ? h('p', { class: 'note warn' }, `The measurements could not be read: ${reportError}`) : null,
      links.length ? h('p', { class: 'report-links' }, links) : null,
      outputs ? renderDownloads(id, outputs) : null);
  };
  load().catch((e) => {
    if (!disposed) replace(side, h('p', { class: 'note warn' }, `The session could not be shown: ${e && e.message ? e.message : e}`));
  });

  return {
    el,
    dispose() {
      disposed = true;
      viewer?.dispose();
    },
  };
}
