// The 3D view of a session: the viewer bundle (/assets/viewer.bundle.js,
// global CraftscanViewer, see API.md) loaded on first use, a cloud and/or a
// mesh PLY loaded into it, and the Cloud / Mesh / Both / Reset view buttons.

import { h, replace } from './dom.js';
import { fmtNumber } from './format.js';

const BUNDLE_URL = '/assets/viewer.bundle.js';
let bundle = null;

export function loadViewerBundle() {
  if (globalThis.CraftscanViewer) return Promise.resolve(globalThis.CraftscanViewer);
  if (!bundle) {
    bundle = new Promise((resolve, reject) => {
      const script = document.createElement('script');
      script.src = BUNDLE_URL;
      script.async = true;
      script.addEventListener('load', () => {
        if (globalThis.CraftscanViewer) resolve(globalThis.CraftscanViewer);
        else reject(new Error('the viewer bundle did not define CraftscanViewer'));
      });
      script.addEventListener('error', () => reject(new Error('the 3D viewer could not be loaded')));
      document.head.append(script);
    }).catch((e) => {
      bundle = null; // try again next time
      throw e;
    });
  }
  return bundle;
}

// {el, dispose()} — `cloudUrl` and/or `meshUrl` (null when the session has none).
// The element with data-testid="viewer" is the viewer's own container; its
// data-state is "loading", then "ready" or "error".
export function createViewerPanel({ cloudUrl, meshUrl, label = '3D model' }) {
  const canvasBox = h('div', {
    class: 'viewer-canvas',
    testid: 'viewer',
    role: 'img',
    'aria-label': `${label}: drag to turn, scroll or pinch to zoom`,
    dataset: { state: 'loading' },
  });
  const note = h('p', { class: 'viewer-note', role: 'status', 'aria-live': 'polite' }, 'Loading the 3D view…');
  const buttons = {};
  const modeButton = (mode, text) => {
    buttons[mode] = h('button', {
      type: 'button',
      class: 'btn btn-small btn-toggle',
      testid: `viewer-${mode}`,
      'aria-pressed': 'false',
      disabled: true,
      onclick: () => setMode(mode),
    }, text);
    return buttons[mode];
  };
  const reset = h('button', {
    type: 'button', class: 'btn btn-small', testid: 'viewer-reset', disabled: true,
    onclick: () => viewer?.resetView(),
  }, 'Reset view');
  const toolbar = h('div', { class: 'viewer-toolbar', role: 'group', 'aria-label': 'What to show' },
    modeButton('cloud', 'Cloud'), modeButton('mesh', 'Mesh'), modeButton('both', 'Both'), reset);
  const el = h('div', { class: 'viewer-frame' }, canvasBox, toolbar, note);

  let viewer = null;
  let disposed = false;
  const has = { cloud: false, mesh: false };

  function setMode(mode) {
    if (!viewer) return;
    viewer.setMode(mode);
    for (const [m, b] of Object.entries(buttons)) b.setAttribute('aria-pressed', String(m === mode));
    canvasBox.dataset.mode = mode;
  }

  function fail(text) {
    canvasBox.dataset.state = 'error';
    note.textContent = text;
    note.classList.add('error-text');
  }

  const load = async () => {
    if (!cloudUrl && !meshUrl) {
      fail('This session has no 3D model.');
      return;
    }
    let CV;
    try {
      CV = await loadViewerBundle();
    } catch (e) {
      fail(`${e.message}. The report and downloads below still work.`);
      return;
    }
    if (disposed) return;
    try {
      // ui: false — the console draws its own labelled buttons below the view.
      viewer = CV.create(canvasBox, { background: '#1d2125', ui: false });
    } catch (e) {
      fail(`The 3D view could not start (${e.message}). This browser may not support WebGL.`);
      return;
    }
    let points = 0;
    let triangles = 0;
    const problems = [];
    if (cloudUrl) {
      note.textContent = 'Loading the point cloud…';
      try {
        const r = await viewer.loadPly(cloudUrl);
        points = r?.points ?? 0;
        has.cloud = true;
      } catch (e) {
        problems.push(`the point cloud could not be loaded (${e.message})`);
      }
      if (disposed) return;
    }
    if (meshUrl) {
      note.textContent = 'Loading the mesh…';
      try {
        const r = await viewer.loadPly(meshUrl);
        triangles = r?.triangles ?? 0;
        has.mesh = true;
      } catch (e) {
        problems.push(`the mesh could not be loaded (${e.message})`);
      }
      if (disposed) return;
    }
    if (!has.cloud && !has.mesh) {
      fail(`The model could not be shown: ${problems.join('; ')}.`);
      return;
    }
    buttons.cloud.disabled = !has.cloud;
    buttons.mesh.disabled = !has.mesh;
    buttons.both.disabled = !(has.cloud && has.mesh);
    reset.disabled = false;
    setMode(has.mesh ? 'mesh' : 'cloud');
    const parts = [];
    if (has.cloud) parts.push(`${fmtNumber(points)} points`);
    if (has.mesh) parts.push(`${fmtNumber(triangles)} triangles`);
    replace(note, `${parts.join(' · ')}. Drag to turn, scroll to zoom.`,
      problems.length ? ` Note: ${problems.join('; ')}.` : '');
    canvasBox.dataset.state = 'ready';
    canvasBox.dataset.points = String(points);
    canvasBox.dataset.triangles = String(triangles);
  };
  load().catch((e) => {
    if (!disposed) fail(`The 3D view failed: ${e && e.message ? e.message : e}`);
  });

  return {
    el,
    dispose() {
      disposed = true;
      if (viewer) {
        try {
          viewer.dispose();
        } catch {
          /* already gone */
        }
        viewer = null;
      }
    },
  };
}
