// The Station page: the live view of both cameras (liveview.js) with the
// camera exposure and gain beside it, the station's state and devices, and
// the turntable (home / move) for operators.

import { h, field, replace, show } from './dom.js';
import { fmtNumber, fmtTime } from './format.js';
import { createLiveView } from './liveview.js';
import { livePreview } from './live-preview.js';

export function mountStation(root, ctx) {
  const { store, jobs } = ctx;
  const operator = ctx.can('operator');
  const cleanups = [];

  const summary = h('dl', { class: 'kv kv-wide', testid: 'station-summary' });
  const devicesBody = h('tbody');
  const devices = h('table', { class: 'table', testid: 'devices' },
    h('caption', { class: 'visually-hidden' }, 'Devices of the station'),
    h('thead', null, h('tr', null,
      h('th', { scope: 'col' }, 'Device'),
      h('th', { scope: 'col' }, 'Kind'),
      h('th', { scope: 'col' }, 'State'),
      h('th', { scope: 'col' }, 'Message'))),
    devicesBody);
  const stationsList = h('ul', { class: 'stations-list', testid: 'stations' });
  const deviceJob = h('p', { class: 'job-line', testid: 'device-job', role: 'status', 'aria-live': 'polite', hidden: true });

  const cameraSlot = h('div', { class: 'live-camera-form' });
  const liveView = createLiveView(ctx, { side: cameraSlot });

  root.append(
    h('h1', { class: 'page-title', tabindex: '-1' }, 'Station'),
    liveView.el,
    h('div', { class: 'station-layout' },
      h('div', null,
        h('section', { class: 'card', 'aria-labelledby': 'station-summary-title' },
          h('h2', { id: 'station-summary-title' }, 'State'), summary),
        h('section', { class: 'card', 'aria-labelledby': 'station-devices-title' },
          h('h2', { id: 'station-devices-title' }, 'Devices'),
          h('div', { class: 'table-scroll' }, devices))),
      h('div', { class: 'station-controls' })));
  const controls = root.querySelector('.station-controls');

  // --- operator controls (absent for observers) ---
  if (operator) {
    const exposure = h('input', { type: 'number', name: 'exposure_us', testid: 'camera-exposure', min: '1', step: '1', inputmode: 'numeric', required: true });
    const gain = h('input', { type: 'number', name: 'gain_db', testid: 'camera-gain', min: '0', step: '0.1', inputmode: 'decimal', required: true });
    const applyCamera = h('button', { type: 'submit', class: 'btn btn-primary', testid: 'camera-apply' }, 'Apply to both cameras');
    const cameraError = h('p', { class: 'form-error', role: 'alert', hidden: true });
    const cameraForm = h('form', { class: 'camera-form', novalidate: true, 'aria-label': 'Camera exposure and gain' },
      h('div', { class: 'field-row' },
        field('Exposure (µs)', exposure, 'Longer is brighter; e.g. 10000 = 1/100 s.'),
        field('Gain (dB)', gain, 'Higher is brighter but noisier.')),
      cameraError, applyCamera);
    cameraForm.addEventListener('submit', async (event) => {
      event.preventDefault();
      const e = Number(exposure.value);
      const g = Number(gain.value);
      let problem = '';
      if (exposure.value === '' || !(e > 0)) problem = 'Enter an exposure time above 0 µs.';
      else if (gain.value === '' || !Number.isFinite(g) || g < 0) problem = 'Enter a gain of 0 dB or more.';
      cameraError.textContent = problem;
      show(cameraError, !!problem);
      if (problem) return;
      applyCamera.disabled = true;
      const reply = await ctx.command('camera', { exposure_us: e, gain_db: g });
      if (reply?.code === 0 && reply.result?.id) jobs.trackJob('camera', reply.result);
      applyCamera.disabled = false;
    });

    const angle = h('input', { type: 'number', name: 'angle_deg', testid: 'turntable-angle', step: 'any', inputmode: 'decimal', value: '0' });
    const home = h('button', { type: 'button', class: 'btn btn-secondary', testid: 'turntable-home' }, 'Home');
    const move = h('button', { type: 'submit', class: 'btn btn-primary', testid: 'turntable-move' }, 'Move');
    const tableError = h('p', { class: 'form-error', role: 'alert', hidden: true });
    const tableForm = h('form', { class: 'turntable-form', novalidate: true, 'aria-label': 'Turntable' },
      field('Angle (degrees)', angle, 'The turntable turns to this angle.'),
      tableError,
      h('div', { class: 'button-row' }, move, home));
    const turntable = async (args, button) => {
      button.disabled = true;
      const reply = await ctx.command('turntable', args);
      if (reply?.code === 0 && reply.result?.id) jobs.trackJob('turntable', reply.result);
      button.disabled = false;
    };
    tableForm.addEventListener('submit', (event) => {
      event.preventDefault();
      const a = Number(angle.value);
      const bad = angle.value === '' || !Number.isFinite(a);
      tableError.textContent = bad ? 'Enter an angle in degrees.' : '';
      show(tableError, bad);
      if (!bad) turntable({ action: 'move', angle_deg: a }, move);
    });
    home.addEventListener('click', () => turntable({ action: 'home' }, home));

    // The form starts from the settings the live frames were taken with
    // (the status does not carry them), unless someone is typing.
    const prefill = (m) => {
      for (const [input, value] of [[exposure, m?.exposure_us], [gain, m?.gain_db]]) {
        if (typeof value === 'number' && input.value === '' && document.activeElement !== input) {
          input.value = String(Math.round(value * 10) / 10);
        }
      }
    };
    cleanups.push(ctx.on('preview', prefill));
    prefill(livePreview.frame);

    cameraSlot.append(
      h('h3', { id: 'station-camera-title' }, 'Exposure and gain'),
      h('p', { class: 'muted small' }, 'Applied to both cameras; the live view goes on with the new settings.'),
      cameraForm);
    controls.append(
      h('section', { class: 'card', 'aria-labelledby': 'station-table-title' },
        h('h2', { id: 'station-table-title' }, 'Turntable'), tableForm),
      deviceJob);
  }
  controls.append(h('section', { class: 'card', 'aria-labelledby': 'station-list-title' },
    h('h2', { id: 'station-list-title' }, 'Stations'), stationsList));

  function renderStatus() {
    const s = store.status;
    const reachable = s && s.online !== false && store.live === 'up';
    const rows = [];
    const add = (label, value, testid) => rows.push(h('dt', null, label), h('dd', { testid }, value));
    add('Station', s?.station || store.me?.station || '—');
    const previewOnly = s?.state === 'busy' && s.job_verb === 'preview'; // gives way to any job
    add('State', !s ? 'unknown' : !reachable ? 'not reachable' : previewOnly ? 'idle (live view running)' : s.state || 'unknown',
      'station-summary-state');
    if (s?.job_id) {
      const pct = typeof s.progress === 'number' ? ` · ${fmtNumber(s.progress * 100, 0)}%` : '';
      const verb = s.job_verb === 'preview' ? 'live view' : s.job_verb || 'job';
      add('Job', `${verb} ${s.job_id} — ${s.job_state || ''}${s.job_state === 'running' ? pct : ''}`);
    }
    add('Calibration', s?.calibration_id || 'none');
    if (s?.last_error) add('Last problem', s.last_error, 'station-last-error');
    if (typeof s?.stamp_ns === 'number' && s.stamp_ns > 0) add('Last heard', fmtTime(s.stamp_ns / 1e6));
    replace(summary, rows);

    const list = Array.isArray(s?.devices) ? s.devices : [];
    replace(devicesBody, list.map((d) => h('tr', { dataset: { device: d.name ?? '', state: d.state ?? '' } },
      h('td', null, d.name || '—'),
      h('td', null, d.kind || '—'),
      h('td', null, h('span', { class: `badge dev-${d.state}` }, d.state || 'unknown')),
      h('td', null, d.message || ''))));
    if (!list.length) devicesBody.append(h('tr', null, h('td', { colspan: '4', class: 'empty' }, 'No devices reported yet.')));
  }

  function renderStations() {
    const list = store.stations ?? [];
    const stateOf = (st) => {
      // The signed-in station's own status is newer, and knows the job.
      const s = st.id === store.me?.station ? store.status : null;
      if (s && s.online !== false) return jobs.stationBusy(s) || s.state !== 'busy' ? s.state : 'idle';
      return st.state;
    };
    replace(stationsList, list.map((st) => h('li', { dataset: { station: st.id } },
      h('strong', null, st.id), ' ',
      h('span', { class: `badge state-${st.online === false ? 'gone' : stateOf(st)}` }, st.online === false ? 'not reachable' : stateOf(st) || 'unknown'),
      st.id === store.me?.station ? h('span', { class: 'muted' }, ' (signed in)') : null)));
    if (!list.length) stationsList.append(h('li', { class: 'muted' }, store.me?.station ?? ''));
  }

  function renderDeviceJob() {
    const t = jobs.tracks.device;
    if (!operator || (!t.running && !t.final)) {
      show(deviceJob, false);
      return;
    }
    const what = t.verb === 'camera' ? 'Camera settings' : t.verb === 'turntable' ? 'Turntable' : 'Job';
    deviceJob.textContent = t.running
      ? `${what}: ${t.latest?.message || 'working…'}`
      : `${what}: ${t.final.state}${t.final.message ? ` — ${t.final.message}` : ''}`;
    deviceJob.dataset.state = t.running ? 'running' : t.final.state;
    show(deviceJob, true);
  }

  ctx.api.stations().then((data) => {
    if (Array.isArray(data?.stations)) store.stations = data.stations;
    renderStations();
  }).catch(() => renderStations());

  cleanups.push(ctx.on('status', () => {
    renderStatus();
    renderStations();
  }), ctx.on('live', renderStatus), ctx.on('job', (t) => {
    if (t?.kind === 'device') renderDeviceJob();
  }));
  renderStatus();
  renderStations();
  renderDeviceJob();
  return {
    unmount() {
      for (const off of cleanups) off();
      return liveView.dispose(); // stops the preview this page runs
    },
  };
}
