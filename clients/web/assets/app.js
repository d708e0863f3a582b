/*
 * craftscan console (craftscan-web front-end; issue 17). Plain ES modules, no
 * build step, nothing from the network but this server: the station may be
 * offline. Served under the server's CSP (default-src 'self'; no inline
 * scripts, handlers or style attributes): every element is built with
 * dom.js's h(), styles come from style.css classes or element.style.
 *
 * Modules:  app.js (this: sign-in flow, shell, routing, commands, live link)
 *           api.js (HTTP API) · live.js (WebSocket) · jobs.js (job tracking)
 *           store.js (state, events) · dom.js · format.js
 *           page-login.js · page-scan.js · page-sessions.js · page-calibrate.js
 *           page-station.js · progress.js · report.js (session result,
 *           measurements, downloads) · viewer.js (3D view, loads
 *           /assets/viewer.bundle.js on first use) · calib-guide.js
 *           (guided calibration) · liveview.js (the Station page's live view)
 *           · live-preview.js (preview frames: pictures, histograms, focus
 *           map, board corners)
 *
 * Routes: #/scan (default) · #/sessions · #/sessions/<id> (one opened) ·
 *         #/calibrate (admin) · #/station
 *
 * Stable hooks for the browser tests (data-testid):
 *   Sign-in
 *     login-station        station id input (prefilled from GET /api/stations' first entry
 *                          when available, else the last one used)
 *     login-token          token input (password)
 *     login-submit         the sign-in button
 *     login-error          the error message (hidden when there is none)
 *   Shell (once signed in)
 *     station-id           the station's id in the top bar
 *     station-state        the station's state; text and data-state are one of
 *                          idle | busy | error | starting | stopping | gone | connecting
 *                          ("gone": status.online is false or the WebSocket is down;
 *                          "idle" while the daemon's only job is the live preview)
 *     role                 the signed-in role (observer | operator | admin); data-role too
 *     signout              the sign-out button
 *     banner-gone          "Station not reachable" banner: in the page only while the
 *                          station is offline (status.online false) or the WebSocket is
 *                          disconnected (absent otherwise); data-reason is "station" or
 *                          "connection"
 *     nav-scan, nav-sessions, nav-calibrate (admins only), nav-station   navigation links
 *     status-line          the last command's outcome, text "<verb> — <code_name>: <message>"
 *                          or "<verb> — station not answering" (HTTP 504); data-code =
 *                          code_name (or "timeout" / "http_<status>"), data-kind = ok | error
 *                          (hidden until the first command)
 *   Scan page (#/scan)
 *     scan-object, scan-views, scan-step     form inputs (operator and admin only: absent
 *                                            for observers, like every control below
 *                                            that starts something)
 *     scan-start, scan-cancel                buttons
 *     scan-error                             form validation message
 *     progress-stage       the current stage, in words; data-stage = the raw stage name
 *                          ("capture", "match", … and finally "done" | "failed" |
 *                          "cancelled" | "interrupted")
 *     progress-bar         <progress> of the current stage (current/total)
 *     progress-message     the stage's message
 *     thumbs               the view thumbnails: one <figure data-view="<index>"> per view,
 *                          with the left camera's picture (an <img> in a button) once
 *                          captured and, once matched, the view's disparity:
 *       thumb-disparity    its false-colour picture (<img>; data-valid = the valid fraction
 *                          0..1; blue far, red near, black where no match)
 *       thumb-disparity-caption  "disparity, 87 % valid"
 *                          Both stay for the current scan when the page is left and opened
 *                          again (not across a browser reload: the console keeps no history)
 *     viewer               the 3D viewer's container (the element given to
 *                          CraftscanViewer.create); data-state = loading | ready | error,
 *                          data-mode = cloud | mesh | both, data-points, data-triangles
 *     viewer-cloud, viewer-mesh, viewer-both, viewer-reset   viewer buttons
 *     scan-result          where the finished scan's session is shown (empty otherwise)
 *     measurements         the measurements from report.json
 *     measurement-dims     the box's L × W × H (when measured)
 *     measurement-extents  the oriented bounding box's size
 *     report-link          link to report.html
 *     downloads            the output download links (<a data-file="<name>">)
 *   Sessions page (#/sessions)
 *     sessions-table       table; each row <tr data-session="<id>" data-state="<state>">
 *     session-open         "Open" link in a row (→ #/sessions/<id>)
 *     session-resume       "Resume" button in a row of an interrupted or failed session
 *                          (operator and admin only); also in the opened session's heading
 *     session-delete       admins: "Delete" (first click asks "Move to trash?", data-confirm; the
 *                          second within 5 s moves the session to the station's trash)
 *     sessions-refresh     refresh button
 *     sessions-job         line following a running scan / resume
 *     session-detail       the opened session (viewer, measurements, downloads as above)
 *   Calibrate page (#/calibrate, admins only)
 *     calibrate-start, calibrate-turntable-start, calibrate-cancel   buttons
 *     calibrate-stage, calibrate-bar, calibrate-message               progress (as progress-*)
 *     calibrate-result     the final verdict; data-state = done | failed | cancelled
 *                          | interrupted, with the job's result fields when the daemon gives them
 *     calibration-id       the calibration in use
 *     calib-guide          guided calibration panel, fed by the calibrate job's preview
 *                          frames (overlay.kind "calibration"; hidden until the first);
 *                          data-state = the overlay's state (searching | moving | holding |
 *                          captured | rejected | solving), data-running = true | false
 *       calib-state        the state in words
 *       calib-advice       what to do next, in large type
 *       calib-rejected     why the last view was not used (hidden when it was)
 *       calib-counts       "n of m views"; data-accepted, data-needed
 *       calib-hold         hold-still progress (<progress> inside; data-hold-s)
 *       calib-corners      both cameras' live pictures (calib-left, calib-right <img>) with
 *                          the board's corners over them (<svg data-corners="<count>"
 *                          class="corner-layer tone-ok|tone-moving|tone-bad">); only while
 *                          the job runs
 *       calib-coverage     the coverage grid (one <span class="cov cov-0..4"> per cell)
 *       calib-diversity    X, Y, Size, Skew bars (rows data-axis = x | y | size | skew)
 *       calib-angles       turntable (mode "turntable"): the angles measured, li data-angle,
 *                          data-found; data-found on the box = how many found
 *       calib-extra        any other scalar field of the overlay
 *   Station page (#/station)
 *     preview              the live view (a card); data-frame = the last frame shown,
 *                          data-state = off | starting | live | paused (a job stopped it) |
 *                          stopped (no frame for 5 s) | gone, data-job = its job
 *       preview-left, preview-right         the cameras' <img>s (swapped whole per frame)
 *       histogram-left, histogram-right     <canvas> histograms (clipped share in red)
 *       exposure-warning-left / -right      "Over-exposed: …" / "Under-exposed: …" (hidden when fine;
 *                                           data-kind = over | under)
 *       preview-note       why there is no live picture (hidden while live)
 *       preview-start, preview-stop         operators and admins only
 *       preview-focus      the focus heat map toggle (aria-pressed); focus-legend
 *       preview-exposure, preview-gain      the last frame's settings, in words;
 *                                           data-exposure-us / data-gain-db the numbers
 *       preview-rate, preview-latency       frames/s, and latency (data-latency-ms only when
 *                                           the frame's stamp is on this computer's clock:
 *                                           exposure to screen; data-ready-ms: from the frame
 *                                           in the daemon's hands to screen)
 *     station-summary, station-summary-state, station-last-error, devices (table, rows
 *     data-device / data-state), stations, camera-exposure, camera-gain, camera-apply
 *     (beside the live view), turntable-angle, turntable-move, turntable-home, device-job
 */

import { h, show } from './dom.js';
import { api, setUnauthorizedHandler, STATION_NOT_ANSWERING } from './api.js';
import { store, on, emit, can } from './store.js';
import { LiveSocket } from './live.js';
import * as jobs from './jobs.js';
import { fmtTime } from './format.js';
import { onPreviewMessage } from './live-preview.js';
import { mountLogin } from './page-login.js';
import { mountScan } from './page-scan.js';
import { mountSessions } from './page-sessions.js';
import { mountCalibrate } from './page-calibrate.js';
import { mountStation } from './page-station.js';

const PAGES = {
  scan: { title: 'Scan', mount: mountScan },
  sessions: { title: 'Sessions', mount: mountSessions },
  calibrate: { title: 'Calibrate', mount: mountCalibrate, role: 'admin' },
  station: { title: 'Station', mount: mountStation },
};

const app = document.getElementById('app');
let shell = null; // the signed-in page's parts
let current = null; // {name, page}
let live = null;

// --- the status line: every command's outcome ---

function notify(text, kind = 'info', { verb = '', code = '' } = {}) {
  if (!shell) return;
  const { statusLine, statusText, statusTime } = shell;
  statusText.textContent = verb ? `${verb} — ${text}` : text;
  statusTime.textContent = fmtTime(Date.now());
  statusLine.dataset.kind = kind;
  statusLine.dataset.code = code;
  statusLine.setAttribute('role', kind === 'error' ? 'alert' : 'status');
  show(statusLine, true);
}

// Sends a command to the station (POST /api/command) and shows its outcome.
// Returns the daemon's reply ({code, code_name, message, result}) or null.
async function command(verb, args = {}) {
  jobs.expectJob(verb);
  try {
    const reply = await api.command(verb, args);
    if (!reply || typeof reply !== 'object') {
      notify('the server sent no reply', 'error', { verb, code: 'no_reply' });
      return null;
    }
    const ok = reply.code === 0;
    const codeName = reply.code_name ?? (ok ? 'ok' : `code ${reply.code}`);
    notify(`${codeName}: ${reply.message ?? ''}`, ok ? 'ok' : 'error', { verb, code: codeName });
    return reply;
  } catch (e) {
    if (e.status === 504 || e.message === STATION_NOT_ANSWERING) {
      notify(STATION_NOT_ANSWERING, 'error', { verb, code: 'timeout' });
    } else if (e.status !== 401) {
      notify(e.message, 'error', { verb, code: e.body?.code ?? `http_${e.status}` });
    }
    return null;
  } finally {
    // The caller files the reply's job (jobs.trackJob) before any other
    // message is handled; from here on, unknown jobs are not ours.
    jobs.expectJob('');
  }
}

const ctx = { store, on, emit, api, jobs, can, command, notify };

// --- the station's state: top bar and banner ---

function stationState() {
  const s = store.status;
  if (store.live === 'down' || (s && s.online === false)) return 'gone';
  // The live preview is a job on the daemon, but gives way to any other:
  // for the people here the station is idle.
  if (s && s.state === 'busy' && s.job_verb === 'preview') return 'idle';
  if (s && s.state) return s.state;
  return 'connecting';
}

function renderState() {
  if (!shell) return;
  const state = stationState();
  shell.stateEl.textContent = state;
  shell.stateEl.dataset.state = state;
  const s = store.status;
  shell.stateEl.title = s?.last_error ? `Last problem: ${s.last_error}`
    : s?.state === 'busy' && s.job_verb === 'preview' ? 'Idle; the live view is running' : '';
  if (s?.station) shell.stationEl.textContent = s.station;
  document.body.classList.toggle('is-gone', state === 'gone');
  renderBanner();
}

function renderBanner() {
  if (!shell) return;
  const { banner, bannerDetail, bannerCountdown, bannerScan, bannerRetry } = shell;
  const connectionDown = store.live === 'down';
  const stationGone = store.status?.online === false;
  if (!connectionDown && !stationGone) {
    banner.remove(); // absent, not just hidden, while the station is reachable
    return;
  }
  const station = store.me?.station ?? 'The station';
  if (connectionDown) {
    const wait = Math.max(0, Math.ceil((store.liveRetryAt - Date.now()) / 1000));
    bannerDetail.textContent = 'The console has lost its live connection to the server and keeps trying.';
    bannerCountdown.textContent = wait > 0 ? `Next try in ${wait} s.` : 'Trying now…';
  } else {
    bannerCountdown.textContent = '';
    bannerDetail.textContent = `${station} has not been heard from for a few seconds. Check that it is ` +
      'switched on and connected. This page updates by itself when it is back.';
  }
  show(bannerScan, jobs.tracks.scan.running);
  show(bannerRetry, connectionDown);
  banner.dataset.reason = connectionDown ? 'connection' : 'station';
  if (!banner.isConnected) shell.nav.scan.parentElement.after(banner);
}

function applyStatus(msg) {
  const { type, ...status } = msg;
  store.status = status;
  jobs.onStatus(status);
  renderState();
  emit('status', status);
}

function onLiveMessage(msg) {
  switch (msg.type) {
    case 'status':
      applyStatus(msg);
      break;
    case 'progress':
      jobs.onProgress(msg);
      break;
    case 'capture':
      jobs.onCapture(msg);
      break;
    case 'disparity':
      jobs.onDisparity(msg);
      break;
    case 'cloud':
      jobs.onCloud(msg);
      break;
    case 'preview':
      jobs.onPreview(msg); // the guided calibration's overlays
      onPreviewMessage(msg); // the live view's frames
      break;
    default:
      break; // pong and anything newer
  }
}

let bannerTimer = 0;
function onLiveState(state, retryAt) {
  const was = store.live;
  store.live = state;
  store.liveRetryAt = retryAt || 0;
  clearInterval(bannerTimer);
  if (state === 'down') {
    bannerTimer = setInterval(renderBanner, 1000);
    if (was === 'up') {
      // Was it the sign-in that ended? Then go back to the sign-in page.
      api.me().catch((e) => {
        if (e.status === 401) signedOut('Your session has ended. Please sign in again.');
      });
    }
  }
  if (state === 'up' && was !== 'up') {
    api.status().then((s) => s && applyStatus(s)).catch(() => {});
  }
  renderState();
  emit('live', state);
}

// --- routing ---

function parseHash() {
  const m = /^#\/([a-z-]+)(?:\/(.*))?$/.exec(location.hash);
  if (!m) return { name: '', param: '' };
  let param = '';
  try {
    param = m[2] ? decodeURIComponent(m[2]) : '';
  } catch {
    param = '';
  }
  return { name: m[1], param };
}

function route() {
  if (!shell) return;
  let { name, param } = parseHash();
  const page = PAGES[name];
  if (!page || (page.role && !can(page.role))) {
    history.replaceState(null, '', '#/scan');
    ({ name, param } = { name: 'scan', param: '' });
  }
  if (current && current.name === name && current.page.update) {
    current.page.update(param);
    return;
  }
  const first = !current;
  current?.page.unmount();
  const main = shell.main;
  main.replaceChildren();
  main.dataset.page = name;
  current = { name, page: PAGES[name].mount(main, ctx, param) };
  for (const [key, link] of Object.entries(shell.nav)) {
    if (key === name) link.setAttribute('aria-current', 'page');
    else link.removeAttribute('aria-current');
  }
  document.title = `${PAGES[name].title} — craftscan ${store.me?.station ?? ''}`.trim();
  if (!first) main.querySelector('h1')?.focus({ preventScroll: false });
}

window.addEventListener('hashchange', route);

// --- sign-in, the shell, sign-out ---

function buildShell() {
  const me = store.me;
  const stationEl = h('span', { class: 'topbar-station', testid: 'station-id' }, me.station ?? '');
  const stateEl = h('span', { class: 'state-pill', testid: 'station-state', dataset: { state: 'connecting' } }, 'connecting');
  const roleEl = h('span', { class: 'role', testid: 'role', dataset: { role: me.role ?? '' } }, me.role ?? '');
  const signoutBtn = h('button', { type: 'button', class: 'btn btn-small btn-light', testid: 'signout' }, 'Sign out');
  signoutBtn.addEventListener('click', signOut);

  const nav = {};
  const link = (key, text) => (nav[key] = h('a', { href: `#/${key}`, class: 'nav-link', testid: `nav-${key}` }, text));
  const navLinks = [link('scan', 'Scan'), link('sessions', 'Sessions')];
  if (can('admin')) navLinks.push(link('calibrate', 'Calibrate'));
  navLinks.push(link('station', 'Station'));

  const bannerDetail = h('span');
  const bannerCountdown = h('span', { class: 'banner-countdown', 'aria-hidden': 'true' });
  const bannerScan = h('span', { hidden: true },
    'If a scan was running, its views are kept: resume it from the Sessions page once the station is back.');
  const bannerRetry = h('button', { type: 'button', class: 'btn btn-small btn-light', hidden: true }, 'Try now');
  bannerRetry.addEventListener('click', () => live?.retryNow());
  const banner = h('div', { class: 'banner-gone', testid: 'banner-gone', role: 'alert' },
    h('div', { class: 'banner-text' },
      h('strong', { class: 'banner-title' }, 'Station not reachable'), bannerDetail, bannerCountdown, bannerScan),
    bannerRetry);
  const main = h('main', { id: 'main', class: 'main' });
  const statusText = h('span', { class: 'status-text' });
  const statusTime = h('span', { class: 'status-time' });
  const statusClose = h('button', { type: 'button', class: 'status-close', 'aria-label': 'Dismiss' }, '×');
  const statusLine = h('div', { class: 'status-line', testid: 'status-line', role: 'status', hidden: true },
    statusTime, statusText, statusClose);
  statusClose.addEventListener('click', () => show(statusLine, false));

  app.replaceChildren(
    h('a', { class: 'skip-link', href: '#main' }, 'Skip to content'),
    h('header', { class: 'topbar' },
      h('div', { class: 'topbar-left' },
        h('span', { class: 'brand' }, 'craftscan'),
        h('span', { class: 'topbar-item' }, h('span', { class: 'topbar-label' }, 'Station'), stationEl),
        h('span', { class: 'topbar-item' }, h('span', { class: 'topbar-label' }, 'State'), stateEl)),
      h('div', { class: 'topbar-right' },
        h('span', { class: 'topbar-item' }, h('span', { class: 'topbar-label' }, 'Signed in as'), roleEl),
        signoutBtn)),
    h('nav', { class: 'nav', 'aria-label': 'Pages' }, navLinks),
    statusLine,
    main);
  // The skip link must not change the route.
  app.querySelector('.skip-link').addEventListener('click', (e) => {
    e.preventDefault();
    main.querySelector('h1')?.focus();
  });
  shell = { stationEl, stateEl, roleEl, nav, banner, bannerDetail, bannerCountdown, bannerScan, bannerRetry, main, statusLine, statusText, statusTime };
}

function enter(me) {
  store.me = { station: me.station, role: me.role, client: me.client };
  if (Array.isArray(me.stations)) store.stations = me.stations.map((id) => (typeof id === 'string' ? { id } : id));
  buildShell();
  renderState();
  live = new LiveSocket({ onMessage: onLiveMessage, onState: onLiveState });
  live.start();
  api.status().then((s) => s && applyStatus(s)).catch(() => {});
  route();
}

function showLogin(message = '') {
  shell = null;
  document.title = 'Sign in — craftscan';
  document.body.classList.remove('is-gone');
  mountLogin(app, { onSignedIn: enter, message });
}

function signedOut(message) {
  if (!store.me) return;
  live?.stop();
  live = null;
  clearInterval(bannerTimer);
  current?.page.unmount();
  current = null;
  store.me = null;
  store.status = null;
  store.live = 'connecting';
  store.scanForm = null;
  jobs.resetJobs();
  showLogin(message);
}

async function signOut() {
  // The page ends what it runs for this console (the live preview) while
  // the session still holds.
  const leaving = current;
  current = null;
  try {
    await Promise.race([leaving?.page.unmount(), new Promise((r) => setTimeout(r, 3000))]);
  } catch {
    /* signing out anyway */
  }
  try {
    await api.logout();
  } catch {
    /* signed out here anyway */
  }
  signedOut('You have signed out.');
}

async function boot() {
  setUnauthorizedHandler(() => signedOut('Your session has ended. Please sign in again.'));
  let me;
  try {
    me = await api.me();
  } catch (e) {
    showLogin(e.status === 401 ? '' : e.message);
    return;
  }
  enter(me);
}

boot();
