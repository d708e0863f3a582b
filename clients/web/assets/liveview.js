// The Station page's "Live view": both cameras side by side as the daemon's
// preview streams them (API.md, message type "preview"), a focus heat map
// over each picture, each picture's histogram with its clipped share, the
// exposure and gain the frames were taken with; `side` (the exposure / gain
// form, for operators) sits beside the pictures.
//
// The preview runs on the station while someone asks for it: an operator
// starts it here (preview start, fps 4, width 640, for 60 s) and this page
// renews it every 20 s while the panel and the browser tab are visible, and
// stops it when the page is left. Any job stops it on the station; the panel
// says so and offers to start it again once the station is idle. Observers
// watch a preview someone else started.
//
// data-testid: preview (the panel; data-frame = the last frame shown,
// data-state = off | starting | live | paused | stopped | gone), preview-left,
// preview-right (the <img>s), histogram-left, histogram-right (<canvas>),
// exposure-warning-left / -right, preview-note, preview-start, preview-stop,
// preview-focus (heat map toggle, aria-pressed), focus-legend,
// preview-exposure (data-exposure-us), preview-gain (data-gain-db),
// preview-latency (data-latency-ms when the stamps allow it), preview-rate.

import { h, show } from './dom.js';
import { fmtNumber } from './format.js';
import {
  livePreview, arrivalRate, latencyMs, createCameraPicture, showPair, drawHistogram, exposureVerdict,
  createFocusGrid, focusLegend,
} from './live-preview.js';

export const PREVIEW_ARGS = { action: 'start', fps: 4, width: 640, seconds: 60 };
const RENEW_MS = 20000; // well inside PREVIEW_ARGS.seconds
const STALE_MS = 5000; // no frame for this long: "Preview stopped"
const RETRY_STALLED_MS = 10000; // wanted but no frames: ask again at most this often

const JOB_WORDS = {
  scan: 'a scan',
  resume: 'a resumed scan',
  capture: 'a capture',
  calibrate: 'the camera calibration',
  'calibrate-turntable': 'the turntable calibration',
  turntable: 'a turntable move',
  camera: 'a camera change',
};

function imageSide(name, label) {
  const pic = createCameraPicture({ testid: `preview-${name}`, label: `${label} camera` });
  const focus = createFocusGrid();
  pic.frame.append(focus.el);
  const hist = h('canvas', {
    class: 'histogram', testid: `histogram-${name}`, width: '256', height: '72',
    role: 'img', 'aria-label': `${label} camera: histogram of grey levels`,
  });
  const stats = h('p', { class: 'hist-stats' });
  const warning = h('p', { class: 'expo-warning', testid: `exposure-warning-${name}`, role: 'status', hidden: true });
  const el = h('div', { class: 'live-side' }, pic.el, hist, stats, warning);
  return { name, label, pic, focus, hist, stats, warning, el };
}

export function createLiveView(ctx, { side = null } = {}) {
  const { store, jobs } = ctx;
  const operator = ctx.can('operator');

  const stateEl = h('span', { class: 'live-state' });
  const rateEl = h('span', { class: 'live-meta', testid: 'preview-rate' });
  const latencyEl = h('span', { class: 'live-meta', testid: 'preview-latency' });
  const startBtn = h('button', { type: 'button', class: 'btn btn-primary btn-small', testid: 'preview-start' }, 'Start live view');
  const stopBtn = h('button', { type: 'button', class: 'btn btn-secondary btn-small', testid: 'preview-stop' }, 'Stop');
  const focusBtn = h('button', {
    type: 'button', class: 'btn btn-secondary btn-small btn-toggle', testid: 'preview-focus',
    'aria-pressed': store.previewFocus ? 'true' : 'false',
  }, 'Focus map');
  const note = h('p', { class: 'note live-note', testid: 'preview-note', role: 'status', 'aria-live': 'polite', hidden: true });
  const left = imageSide('left', 'Left');
  const right = imageSide('right', 'Right');
  const legend = focusLegend();
  const exposureEl = h('dd', { testid: 'preview-exposure' }, '—');
  const gainEl = h('dd', { testid: 'preview-gain' }, '—');
  const sizeEl = h('dd', null, '—');
  const readout = h('dl', { class: 'kv live-readout', 'aria-label': 'Settings of the last frame' },
    h('dt', null, 'Exposure'), exposureEl,
    h('dt', null, 'Gain'), gainEl,
    h('dt', null, 'Picture'), sizeEl);
  const cams = h('div', { class: 'live-cams' }, left.el, right.el);

  const el = h('section', { class: 'card live-view', testid: 'preview', 'aria-labelledby': 'live-view-title', dataset: { frame: '', state: 'off' } },
    h('div', { class: 'live-head' },
      h('h2', { id: 'live-view-title' }, 'Live view'),
      stateEl,
      h('span', { class: 'live-metas' }, rateEl, latencyEl),
      h('span', { class: 'live-tools' }, focusBtn, operator ? startBtn : null, operator ? stopBtn : null)),
    note,
    h('div', { class: 'live-layout' },
      h('div', { class: 'live-main' }, cams, legend),
      h('div', { class: 'live-aside' }, readout, side)));

  let want = false; // this page keeps the preview running (an operator pressed Start)
  let renewing = false;
  let lastAsk = 0; // when the preview was last asked to start / renewed
  let lastStart = 0; // when it was last started (Start, or asked again as it had stopped)
  let askProblem = ''; // the daemon's refusal of the last start, if any
  let lastEnd = null; // the last preview job's end: {id, state, message}
  let stoppedHere = false; // Stop was pressed on this page
  let pausedBy = null; // the job the preview last gave way to: {verb, id}
  let pending = null; // the newest frame not drawn yet
  let drawing = false;
  let panelVisible = true;
  let disposed = false;

  // --- frames ---

  function onFrame(m) {
    pending = m;
    if (!drawing) drawFrames();
    render();
  }

  async function drawFrames() {
    drawing = true;
    while (pending && !disposed) {
      const m = pending;
      pending = null;
      await showPair({ left: left.pic, right: right.pic }, m);
      if (disposed) break;
      for (const s of [left, right]) drawSide(s, m[s.name], m);
      exposureEl.textContent = typeof m.exposure_us === 'number' ? `${fmtNumber(m.exposure_us, 0)} µs` : '—';
      exposureEl.dataset.exposureUs = String(m.exposure_us ?? '');
      gainEl.textContent = typeof m.gain_db === 'number' ? `${fmtNumber(m.gain_db, 1)} dB` : '—';
      gainEl.dataset.gainDb = String(m.gain_db ?? '');
      sizeEl.textContent = m.full_width && m.full_width !== m.width
        ? `${m.width} × ${m.height} (of ${m.full_width} × ${m.full_height})`
        : `${m.width} × ${m.height}`;
      el.dataset.frame = String(m.frame ?? '');
      el.dataset.job = String(m.job_id ?? '');
      const shown = Date.now(); // on screen now
      const lat = latencyMs(m, shown); // exposure to display
      const fromReady = latencyMs(m, shown, 'ready_ns'); // the frame in the daemon's hands to display
      latencyEl.textContent = lat === null ? 'latency —'
        : `latency ${fmtNumber(lat, 0)} ms${fromReady === null ? '' : ` (camera ${fmtNumber(Math.max(0, lat - fromReady), 0)} ms)`}`;
      latencyEl.title = lat === null
        ? 'The frames are stamped with the station’s own clock, which this computer cannot compare with.'
        : 'Time from the exposure to this frame on screen (meaningful when the station and this computer share a clock).';
      if (lat === null) delete latencyEl.dataset.latencyMs;
      else latencyEl.dataset.latencyMs = String(Math.round(lat));
      if (fromReady === null) delete latencyEl.dataset.readyMs;
      else latencyEl.dataset.readyMs = String(Math.round(fromReady));
    }
    drawing = false;
  }

  function drawSide(s, image, m) {
    if (!image) return;
    const clipped = Number(image.clipped_pct) || 0;
    const black = Number(image.black_pct) || 0;
    drawHistogram(s.hist, image.histogram, { clippedPct: clipped });
    s.stats.replaceChildren(
      h('span', { class: clipped > 1 ? 'clip-high' : '' }, `clipped ${fmtNumber(clipped, 1)} %`),
      ' · ',
      h('span', null, `black ${fmtNumber(black, 1)} %`));
    const verdict = exposureVerdict(image);
    s.warning.textContent = verdict.text;
    s.warning.dataset.kind = verdict.kind;
    show(s.warning, !!verdict.text);
    s.pic.frame.dataset.exposure = verdict.kind || 'ok';
    s.focus.update(image.focus, Number(m.grid_rows), Number(m.grid_cols));
  }

  // --- asking the station ---

  async function ask(notifyOutcome) {
    if (renewing) return;
    renewing = true;
    lastAsk = Date.now();
    try {
      const reply = notifyOutcome
        ? await ctx.command('preview', PREVIEW_ARGS)
        : await ctx.api.command('preview', PREVIEW_ARGS);
      if (reply?.code === 0) {
        askProblem = '';
        if (reply.result?.id) jobs.trackJob('preview', reply.result);
      } else if (reply) {
        askProblem = reply.message || reply.code_name || 'refused';
        // Busy with a job, or not allowed: stop asking until started again.
        if (reply.code_name === 'busy' || reply.code_name === 'forbidden') want = false;
      } else if (notifyOutcome) {
        askProblem = 'The station did not answer.';
      }
    } catch (e) {
      askProblem = e.message || 'The station did not answer.';
    } finally {
      renewing = false;
      render();
    }
  }

  function start() {
    want = true;
    askProblem = '';
    lastEnd = null;
    stoppedHere = false;
    pausedBy = null;
    lastStart = Date.now();
    ask(true);
    render();
  }

  async function stop() {
    want = false;
    stoppedHere = true;
    render();
    await ctx.command('preview', { action: 'stop' });
    render();
  }

  startBtn.addEventListener('click', start);
  stopBtn.addEventListener('click', stop);
  focusBtn.addEventListener('click', () => {
    store.previewFocus = !store.previewFocus;
    focusBtn.setAttribute('aria-pressed', store.previewFocus ? 'true' : 'false');
    render();
  });

  const pageVisible = () => document.visibilityState !== 'hidden';

  // Renews while wanted and seen; asks again when the frames stopped.
  function keepAlive() {
    if (!want || renewing || !pageVisible() || !panelVisible) return;
    const now = Date.now();
    const stalled = now - Math.max(livePreview.at, lastAsk) > STALE_MS && now - lastAsk > RETRY_STALLED_MS;
    if (stalled) lastStart = now;
    if (now - lastAsk >= RENEW_MS || stalled) ask(false);
  }

  function onVisible() {
    if (pageVisible() && panelVisible && want && Date.now() - lastAsk > 2000) {
      if (Date.now() - livePreview.at > STALE_MS) lastStart = Date.now(); // it may have run out meanwhile
      ask(false);
    }
    render();
  }
  document.addEventListener('visibilitychange', onVisible);
  let observer = null;
  if (typeof IntersectionObserver === 'function') {
    observer = new IntersectionObserver((entries) => {
      const visible = entries.some((e) => e.isIntersecting);
      if (visible === panelVisible) return;
      panelVisible = visible;
      if (visible) onVisible();
    });
    observer.observe(el);
  }
  // Leaving the console (tab closed, reloaded): stop what this page runs.
  const onPageHide = () => {
    if (want) ctx.api.command('preview', { action: 'stop' }, { keepalive: true }).catch(() => {});
  };
  window.addEventListener('pagehide', onPageHide);

  // --- what the panel says ---

  function render() {
    if (disposed) return;
    const s = store.status;
    const now = Date.now();
    const reachable = store.live === 'up' && s?.online !== false;
    const age = livePreview.at ? now - livePreview.at : Infinity;
    const fresh = age < STALE_MS;
    const job = jobs.stationBusy(s) ? s : null;
    if (job && want) want = false; // the job stopped it on the station
    if (job && !fresh) pausedBy = { verb: job.job_verb, id: job.job_id };
    let state;
    if (!reachable) state = 'gone';
    else if (fresh) state = 'live';
    else if (job) state = 'paused';
    else if (want && now - lastStart < STALE_MS + 1000 && !askProblem) state = 'starting';
    else if (livePreview.at || lastEnd || want) state = 'stopped';
    else state = 'off';
    el.dataset.state = state;
    el.classList.toggle('is-stale', state !== 'live');

    const words = { gone: 'Not reachable', live: 'Live', paused: 'Paused', starting: 'Starting…', stopped: 'Stopped', off: 'Off' };
    stateEl.textContent = words[state];
    stateEl.dataset.state = state;
    const rate = arrivalRate();
    rateEl.textContent = state === 'live' && rate > 0 ? `${fmtNumber(rate, 1)} frames/s` : '';
    show(latencyEl, state === 'live' && !!latencyEl.textContent);

    let text = '';
    let warn = false;
    const who = operator ? 'Start it again' : 'An operator can start it again';
    if (state === 'gone') {
      text = 'The station is not reachable. The live view returns when it is.';
    } else if (state === 'paused') {
      const what = JOB_WORDS[job.job_verb] ?? `a job (${job.job_verb || 'unknown'})`;
      const again = operator ? 'You can start it again' : 'It can be started again';
      text = livePreview.at
        ? `The live view stopped because the station is running ${what} (${job.job_id}): any job stops it. ${again} when the station is idle.`
        : `The station is running ${what} (${job.job_id}); the live view can start once the station is idle.`;
    } else if (state === 'starting') {
      text = 'Starting the cameras…';
    } else if (state === 'stopped') {
      warn = true;
      // Stable words (the note is read out when it changes): no counting seconds.
      const secs = Number.isFinite(age) ? `no picture for ${STALE_MS / 1000} s or more` : 'no picture yet';
      let why = '';
      if (stoppedHere) why = ' You stopped it.';
      else if (pausedBy) why = ` It gave way to ${JOB_WORDS[pausedBy.verb] ?? 'a job'} (${pausedBy.id}), which has ended.`;
      else if (askProblem) why = ` The station said: ${askProblem}.`;
      else if (lastEnd?.state === 'failed') why = ` It failed: ${lastEnd.message || 'no reason given'}.`;
      else if (lastEnd?.state === 'done') why = ' It ran out (nobody renewed it).';
      else if (lastEnd?.state === 'cancelled') why = ' It was stopped on the station.';
      text = `Preview stopped: ${secs}.${why} ${want ? 'Asking the station again…'
        : stoppedHere ? '' : `${who} when the station is idle.`}`.trim();
    } else if (state === 'off') {
      text = operator
        ? 'The live view is off. Start it to see both cameras, their focus and their exposure.'
        : 'The live view is off. It shows here when an operator starts it.';
    }
    if (note.textContent !== text) note.textContent = text;
    note.classList.toggle('warn', warn);
    show(note, !!text);

    if (operator) {
      const idle = reachable && !job;
      show(startBtn, !want);
      startBtn.disabled = !idle;
      startBtn.title = !reachable ? 'The station is not reachable'
        : job ? 'The station is busy with a job' : '';
      startBtn.textContent = state === 'live' ? 'Keep it running' : state === 'stopped' ? 'Start again' : 'Start live view';
      show(stopBtn, want || state === 'live');
      stopBtn.disabled = !reachable;
    }
    const focusOn = !!store.previewFocus;
    for (const side of [left, right]) side.focus.el.classList.toggle('on', focusOn);
    show(legend, focusOn);
  }

  const tick = setInterval(() => {
    keepAlive();
    render();
  }, 1000);

  const offs = [
    ctx.on('preview', onFrame),
    ctx.on('status', render),
    ctx.on('live', render),
    ctx.on('preview-job', (end) => {
      lastEnd = end;
      render();
    }),
  ];
  if (livePreview.frame && Date.now() - livePreview.at < STALE_MS) onFrame(livePreview.frame);
  render();

  return {
    el,
    // Stops the preview if this page runs it; resolves when the station answered.
    async dispose() {
      if (disposed) return;
      disposed = true;
      clearInterval(tick);
      for (const off of offs) off();
      observer?.disconnect();
      document.removeEventListener('visibilitychange', onVisible);
      window.removeEventListener('pagehide', onPageHide);
      if (want) {
        want = false;
        try {
          await ctx.api.command('preview', { action: 'stop' }, { keepalive: true });
        } catch {
          /* it runs out by itself */
        }
      }
    },
  };
}
