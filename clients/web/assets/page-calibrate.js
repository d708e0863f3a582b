// The Calibrate page (admins): stereo calibration and turntable-axis
// calibration, their progress, the guidance panel (calib-guide.js: the
// calibrate job's live pictures with its feedback) and the final verdict.

import { h, replace, show } from './dom.js';
import { fmtTime, fmtValue, humanize, stageLabel } from './format.js';
import { createProgress } from './progress.js';
import { createGuide } from './calib-guide.js';

const VERB_WORDS = {
  calibrate: 'Camera calibration',
  'calibrate-turntable': 'Turntable calibration',
};

export function mountCalibrate(root, ctx) {
  const { jobs, store } = ctx;
  const admin = ctx.can('admin');
  const cleanups = [];

  root.append(h('h1', { class: 'page-title', tabindex: '-1' }, 'Calibrate'));
  if (!admin) {
    root.append(h('section', { class: 'card' },
      h('p', null, 'Calibration is done by an administrator of the station.'),
      h('p', { class: 'muted' }, 'Sign in with an administrator token to calibrate.')));
    return { unmount() {} };
  }

  const calibId = h('strong', { testid: 'calibration-id' });
  const startStereo = h('button', { type: 'button', class: 'btn btn-primary btn-wide', testid: 'calibrate-start' }, 'Calibrate the cameras');
  const startTable = h('button', { type: 'button', class: 'btn btn-primary btn-wide', testid: 'calibrate-turntable-start' }, 'Calibrate the turntable');
  const cancelBtn = h('button', { type: 'button', class: 'btn btn-danger', testid: 'calibrate-cancel' }, 'Cancel calibration');
  const progress = createProgress({ stage: 'calibrate-stage', bar: 'calibrate-bar', message: 'calibrate-message', title: 'Calibration progress' });
  const guide = createGuide();
  const jobTitle = h('h2', { id: 'calib-progress-title' }, 'Progress');
  const result = h('div', { class: 'calibrate-result', testid: 'calibrate-result', role: 'status', 'aria-live': 'polite' });

  let cards = null;
  root.append(
    h('p', { class: 'current-calibration' }, 'Calibration in use: ', calibId),
    cards = h('div', { class: 'calib-cards' },
      h('section', { class: 'card', 'aria-labelledby': 'calib-stereo-title' },
        h('h2', { id: 'calib-stereo-title' }, 'Cameras'),
        h('p', null, 'Measures the two cameras and how they sit to each other. Needed after the cameras were moved, refocused or changed.'),
        h('p', { class: 'muted' }, 'Have the calibration board ready and follow the instructions shown below while it runs.'),
        startStereo),
      h('section', { class: 'card', 'aria-labelledby': 'calib-table-title' },
        h('h2', { id: 'calib-table-title' }, 'Turntable'),
        h('p', null, 'Finds the turntable’s axis as the cameras see it. Needed after the cameras or the turntable were moved, and after a camera calibration.'),
        h('p', { class: 'muted' }, 'Place the calibration board flat on the turntable.'),
        startTable)),
    h('section', { class: 'card', 'aria-labelledby': 'calib-progress-title' },
      // The verdict (once there is one) above what the guidance achieved.
      jobTitle, result, guide.el, progress.el, h('div', { class: 'button-row' }, cancelBtn)));

  async function start(verb, button) {
    button.disabled = true;
    const reply = await ctx.command(verb);
    if (reply && reply.result && typeof reply.result === 'object' && reply.result.id) {
      jobs.trackJob(reply.result.verb || verb, reply.result);
    }
    update();
  }
  startStereo.addEventListener('click', () => start('calibrate', startStereo));
  startTable.addEventListener('click', () => start('calibrate-turntable', startTable));
  cancelBtn.addEventListener('click', async () => {
    cancelBtn.disabled = true;
    await ctx.command('cancel');
    update();
  });

  function renderResult(t) {
    if (!t.final) {
      replace(result);
      show(result, false);
      return;
    }
    const ok = t.final.state === 'done';
    const what = VERB_WORDS[t.verb] ?? 'Calibration';
    const verdict = ok ? `${what} finished` : t.final.state === 'cancelled' ? `${what} cancelled` : `${what} did not succeed`;
    const fields = [];
    if (t.result && typeof t.result === 'object') {
      for (const [k, v] of Object.entries(t.result)) {
        if (typeof v === 'number' || typeof v === 'string' || typeof v === 'boolean') {
          fields.push(h('dt', null, humanize(k)), h('dd', { dataset: { key: k } }, fmtValue(k, v)));
        }
      }
    }
    result.className = `calibrate-result final-${t.final.state}`;
    result.dataset.state = t.final.state;
    replace(result,
      h('p', { class: 'verdict' }, verdict, t.endedAt ? h('span', { class: 'muted' }, ` at ${fmtTime(t.endedAt)}`) : null),
      t.final.message ? h('p', { class: 'verdict-message' }, t.final.message) : null,
      fields.length ? h('dl', { class: 'kv' }, fields) : null);
    show(result, true);
  }

  function update() {
    const t = jobs.tracks.calibrate;
    const s = store.status;
    const busy = jobs.stationBusy(s) || Object.values(jobs.tracks).some((x) => x.running);
    startStereo.disabled = busy;
    startTable.disabled = busy;
    cancelBtn.disabled = !(t.running);
    show(cancelBtn, t.running);
    show(cards, !t.running); // while it runs, the guidance comes first
    jobTitle.textContent = t.verb ? (VERB_WORDS[t.verb] ?? stageLabel(t.verb)) : 'Progress';
    calibId.textContent = s?.calibration_id || 'none yet';
    progress.update(t.id || t.running || t.final ? t : null);
    guide.update(t);
    renderResult(t);
  }

  cleanups.push(ctx.on('job', update), ctx.on('status', update),
    ctx.on('guide', (t) => guide.update(t))); // every calibration frame: the guide only
  update();
  return {
    unmount() {
      for (const off of cleanups) off();
    },
  };
}
