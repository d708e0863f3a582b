// The Scan page: start / cancel a scan, its progress per stage, the view
// thumbnails as they arrive with each view's disparity under its picture
// (once matched), and the finished model with its measurements.

import { h, append, field, replace, show } from './dom.js';
import { fmtNumber } from './format.js';
import { createProgress } from './progress.js';
import { createSessionPanel } from './report.js';

const DEFAULT_VIEWS = 6;

function evenStep(views) {
  return Math.round((360 / views) * 1000) / 1000;
}

export function mountScan(root, ctx) {
  const { store, jobs } = ctx;
  const operator = ctx.can('operator');
  const form0 = store.scanForm ?? { object: '', views: DEFAULT_VIEWS, step: evenStep(DEFAULT_VIEWS), stepAuto: true };
  store.scanForm = form0;
  const cleanups = [];

  // --- the form (operators and admins only; absent for observers) ---
  let startBtn = null;
  let cancelBtn = null;
  let formCard = null;
  if (operator) {
    const objectIn = h('input', {
      type: 'text', name: 'object', testid: 'scan-object', required: true, maxlength: '100',
      autocomplete: 'off', value: form0.object, placeholder: 'e.g. clay jug 1987.42',
    });
    const viewsIn = h('input', {
      type: 'number', name: 'views', testid: 'scan-views', required: true, min: '2', max: '360', step: '1',
      inputmode: 'numeric', value: String(form0.views),
    });
    const stepIn = h('input', {
      type: 'number', name: 'step_deg', testid: 'scan-step', required: true, min: '0.1', max: '360', step: 'any',
      inputmode: 'decimal', value: String(form0.step),
    });
    const stepHint = h('p', { class: 'hint' });
    const evenBtn = h('button', { type: 'button', class: 'btn-link', testid: 'scan-step-even' }, 'Use even spacing');
    const formError = h('p', { class: 'form-error', role: 'alert', testid: 'scan-error', hidden: true });
    startBtn = h('button', { type: 'submit', class: 'btn btn-primary btn-grow', testid: 'scan-start' }, 'Start scan');
    cancelBtn = h('button', { type: 'button', class: 'btn btn-danger btn-grow', testid: 'scan-cancel' }, 'Cancel');

    const updateHint = () => {
      const views = Number(viewsIn.value);
      const step = Number(stepIn.value);
      if (Number.isInteger(views) && views >= 2 && step > 0) {
        const turn = (views - 1) * step;
        const spacing = form0.stepAuto ? 'evenly around one full turn' : `covering ${fmtNumber(turn + step, 1)}° of the turntable`;
        stepHint.textContent = `${views} views, ${fmtNumber(step)}° apart — ${spacing}.`;
      } else stepHint.textContent = 'Between 2 and 360 views.';
      show(evenBtn, !form0.stepAuto);
    };
    viewsIn.addEventListener('input', () => {
      const views = Number(viewsIn.value);
      form0.views = viewsIn.value;
      if (form0.stepAuto && Number.isInteger(views) && views >= 2 && views <= 360) {
        stepIn.value = String(evenStep(views));
        form0.step = stepIn.value;
      }
      updateHint();
    });
    stepIn.addEventListener('input', () => {
      form0.stepAuto = false;
      form0.step = stepIn.value;
      updateHint();
    });
    objectIn.addEventListener('input', () => {
      form0.object = objectIn.value;
    });
    evenBtn.addEventListener('click', () => {
      form0.stepAuto = true;
      const views = Number(viewsIn.value);
      if (Number.isInteger(views) && views >= 2) stepIn.value = String(evenStep(views));
      form0.step = stepIn.value;
      updateHint();
    });

    const form = h('form', { class: 'scan-form', novalidate: true, 'aria-label': 'New scan' },
      field('Object name', objectIn, 'Used in the session name and the report.'),
      h('div', { class: 'field-row' },
        field('Views', viewsIn),
        field('Degrees apart', stepIn)),
      stepHint, evenBtn, formError,
      h('div', { class: 'button-row' }, startBtn, cancelBtn));
    updateHint();

    form.addEventListener('submit', async (event) => {
      event.preventDefault();
      const object = objectIn.value.trim();
      const views = Number(viewsIn.value);
      const step = Number(stepIn.value);
      let problem = '';
      let bad = null;
      if (!object) [problem, bad] = ['Enter a name for the object.', objectIn];
      else if (!Number.isInteger(views) || views < 2 || views > 360) [problem, bad] = ['The number of views must be a whole number from 2 to 360.', viewsIn];
      else if (!(step > 0) || step > 360) [problem, bad] = ['The degrees between views must be more than 0 and at most 360.', stepIn];
      formError.textContent = problem;
      show(formError, !!problem);
      if (bad) {
        bad.setAttribute('aria-invalid', 'true');
        bad.focus();
        return;
      }
      for (const el of [objectIn, viewsIn, stepIn]) el.removeAttribute('aria-invalid');
      startBtn.disabled = true;
      const reply = await ctx.command('scan', { object, views, step_deg: step });
      if (reply && reply.result && typeof reply.result === 'object' && reply.result.id) {
        // ok: the new job; busy: the job that is running (follow it).
        jobs.trackJob(reply.result.verb || 'scan', reply.result);
      }
      updateButtons();
    });
    cancelBtn.addEventListener('click', async () => {
      cancelBtn.disabled = true;
      await ctx.command('cancel');
      updateButtons();
    });
    formCard = h('section', { class: 'card', 'aria-labelledby': 'scan-form-title' },
      h('h2', { id: 'scan-form-title' }, 'New scan'),
      h('p', { class: 'muted small' }, 'Place the object in the middle of the turntable, then start.'),
      form);
  }

  // --- progress, thumbnails, result ---
  const progress = createProgress({ stage: 'progress-stage', bar: 'progress-bar', message: 'progress-message', title: 'Scan progress' });
  const progressCard = h('section', { class: 'card', 'aria-labelledby': 'scan-progress-title' },
    h('h2', { id: 'scan-progress-title' }, 'Progress'), progress.el,
    h('p', { class: 'muted small' }, 'When a scan is finished, its 3D model and measurements appear at the top of this page.'));

  const thumbs = h('div', { class: 'thumbs', testid: 'thumbs', role: 'list', 'aria-label': 'Views captured' });
  const thumbsNote = h('p', { class: 'muted' }, 'The views appear here as the cameras take them, each with its disparity (blue far, red near) once matched.');
  const dialogImgs = h('div', { class: 'dialog-images' });
  const dialogTitle = h('h3', null, '');
  const dialog = h('dialog', { class: 'view-dialog', 'aria-label': 'View' },
    dialogTitle, dialogImgs,
    h('form', { method: 'dialog' }, h('button', { class: 'btn', type: 'submit' }, 'Close')));
  const thumbsCard = h('section', { class: 'card', 'aria-labelledby': 'scan-thumbs-title' },
    h('h2', { id: 'scan-thumbs-title' }, 'Views'), thumbsNote, thumbs, dialog);

  const resultSlot = h('div', { class: 'result-slot', testid: 'scan-result' });
  let panel = null;
  let panelSession = '';

  const observerNote = operator ? null
    : h('p', { class: 'note' }, 'You are signed in as an observer: you can follow scans but not start them.');

  // The finished scan's model spans the page above the form; progress and
  // views sit beside the form so both stay in sight while a scan runs.
  append(root,
    h('h1', { class: 'page-title', tabindex: '-1' }, 'Scan'),
    observerNote,
    resultSlot,
    h('div', { class: operator ? 'scan-layout' : 'scan-layout single' },
      formCard ? h('div', { class: 'scan-left' }, formCard) : null,
      h('div', { class: 'scan-right' }, progressCard, thumbsCard)));

  // "disparity, 87 % valid"
  function disparityWords(d) {
    return `disparity, ${Math.round(d.valid * 100)} % valid`;
  }

  // What the colours of a disparity picture mean, for its title and the dialog.
  function disparityLegend(d) {
    const range = d.scaleMin !== null && d.scaleMax !== null
      ? ` ${fmtNumber(d.scaleMin, 1)}–${fmtNumber(d.scaleMax, 1)} px` : '';
    return `Disparity${range}: blue far, red near; black where the cameras found no match`;
  }

  // View `index`: the left camera's picture (a button opening both cameras
  // and the disparity larger) and, once the view is matched, its disparity.
  function thumbFigure(index) {
    const t = jobs.tracks.scan;
    const v = t.thumbs.get(index);
    const d = t.disparities.get(index);
    const angle = v && v.angle !== null ? ` · ${fmtNumber(v.angle, 1)}°` : '';
    const points = t.viewPoints.get(index);
    const caption = `View ${index + 1}${angle}`;
    const picture = v ? v.left || v.right : '';
    const img = picture ? h('img', { src: picture, alt: `${caption}, left camera`, decoding: 'async', loading: 'lazy' }) : null;
    const button = h('button', { type: 'button', class: 'thumb-button', 'aria-label': `Show ${caption} larger` }, img);
    button.addEventListener('click', () => {
      dialogTitle.textContent = caption;
      replace(dialogImgs,
        v?.left ? h('figure', null, h('img', { src: v.left, alt: `${caption}, left camera` }), h('figcaption', null, 'Left camera')) : null,
        v?.right ? h('figure', null, h('img', { src: v.right, alt: `${caption}, right camera` }), h('figcaption', null, 'Right camera')) : null,
        d ? h('figure', null, h('img', { src: d.image, alt: `${caption}, disparity` }),
          h('figcaption', null, `${disparityLegend(d)} (${Math.round(d.valid * 100)} % matched)`)) : null);
      if (typeof dialog.showModal === 'function') dialog.showModal();
    });
    const disparity = d ? h('div', { class: 'thumb-disparity', title: disparityLegend(d) },
      h('img', { src: d.image, alt: `${caption}, disparity`, decoding: 'async', testid: 'thumb-disparity', dataset: { valid: String(d.valid) } }),
      h('span', { class: 'thumb-disparity-caption', testid: 'thumb-disparity-caption' }, disparityWords(d))) : null;
    return h('figure', { class: 'thumb', role: 'listitem', dataset: { view: String(index) } },
      img ? button : null, // a view captured before a resume has its disparity only
      disparity,
      h('figcaption', null, caption, points ? h('span', { class: 'muted' }, ` · ${fmtNumber(points)} pts`) : null));
  }

  function renderThumb(index) {
    const t = jobs.tracks.scan;
    const v = t.thumbs.get(index);
    if (!(v && (v.left || v.right)) && !t.disparities.has(index)) return;
    const fig = thumbFigure(index);
    const old = thumbs.querySelector(`[data-view="${index}"]`);
    if (old) old.replaceWith(fig);
    else {
      const after = [...thumbs.children].find((c) => Number(c.dataset.view) > index);
      thumbs.insertBefore(fig, after ?? null);
      if (!after) thumbs.scrollLeft = thumbs.scrollWidth;
    }
    show(thumbsNote, false);
  }

  function renderAllThumbs() {
    replace(thumbs);
    const t = jobs.tracks.scan;
    const views = new Set([...t.thumbs.keys(), ...t.disparities.keys()]);
    for (const index of [...views].sort((a, b) => a - b)) renderThumb(index);
    show(thumbsNote, views.size === 0);
  }

  function renderResult() {
    const t = jobs.tracks.scan;
    const want = t.final?.state === 'done' ? t.resultSession : '';
    if (want && want === panelSession) return;
    panel?.dispose();
    panel = null;
    panelSession = want;
    if (want) {
      panel = createSessionPanel(want, { title: `Finished: ${want}` });
      replace(resultSlot, panel.el);
      if (t.endedAt && Date.now() - t.endedAt < 5000) panel.el.scrollIntoView({ behavior: 'smooth', block: 'start' });
      return;
    }
    if (t.final && t.resolving) {
      replace(resultSlot, h('section', { class: 'card' }, h('p', { class: 'muted' }, 'Finding the session…')));
    } else if (t.final && t.final.state !== 'done') {
      const sid = t.resultSession || t.session;
      replace(resultSlot, h('section', { class: 'card' },
        h('h2', null, 'Model'),
        h('p', null, t.final.state === 'cancelled' ? 'The scan was cancelled.' : 'The scan did not finish.'),
        sid ? h('p', null, 'Its views are kept in session ', h('strong', null, sid), '. ',
          h('a', { href: `#/sessions/${encodeURIComponent(sid)}` }, 'Open it on the Sessions page'),
          ctx.can('operator') ? ' to resume it.' : '.') : null));
    } else if (t.final && t.resolveError) {
      replace(resultSlot, h('section', { class: 'card' }, h('p', { class: 'note warn' }, t.resolveError)));
    } else {
      replace(resultSlot);
    }
  }

  function updateButtons() {
    if (!operator) return;
    const t = jobs.tracks.scan;
    const s = store.status;
    const reachable = s && s.online !== false && store.live === 'up';
    const stationBusy = jobs.stationBusy(s); // not the live preview: a scan stops it
    const anyRunning = Object.values(jobs.tracks).some((x) => x.running);
    startBtn.disabled = !!(stationBusy || anyRunning);
    cancelBtn.disabled = !(t.running || stationBusy);
    startBtn.title = startBtn.disabled ? 'The station is busy with a job' : '';
    if (!reachable) startBtn.title = 'The station is not reachable';
  }

  function onJob(t) {
    if (t && t.kind !== 'scan') {
      updateButtons();
      return;
    }
    const track = jobs.tracks.scan;
    progress.update(track);
    if (track.thumbs.size === 0 && track.disparities.size === 0 && thumbs.children.length) renderAllThumbs();
    renderResult();
    updateButtons();
  }

  cleanups.push(
    ctx.on('job', onJob),
    ctx.on('thumb', (index) => renderThumb(index)),
    ctx.on('cloud', (m) => {
      if (typeof m?.view_index === 'number' && m.kind !== 'fused') renderThumb(m.view_index);
    }),
    ctx.on('status', updateButtons),
    ctx.on('live', updateButtons),
  );
  renderAllThumbs();
  onJob(null);

  return {
    unmount() {
      for (const off of cleanups) off();
      panel?.dispose();
      if (dialog.open) dialog.close();
    },
  };
}
