// The sign-in page: station id and token → POST /api/login.

import { h, field, show } from './dom.js';
import { api, STATION_NOT_ANSWERING } from './api.js';

const LAST_STATION_KEY = 'craftscan.station';

function loginErrorText(e) {
  if (e.status === 504 || e.message === STATION_NOT_ANSWERING) {
    return 'The station is not answering. Check that it is switched on and connected, then try again.';
  }
  if (e.status === 401) return `The station refused this token: ${e.message}`;
  return e.message || 'Sign-in failed.';
}

// Mounts the sign-in form in `root`; calls onSignedIn(me) after a good sign-in.
export function mountLogin(root, { onSignedIn, message = '' }) {
  const station = h('input', {
    type: 'text', name: 'station', testid: 'login-station', required: true,
    autocomplete: 'username', autocapitalize: 'none', spellcheck: 'false', list: 'station-list',
  });
  const stationList = h('datalist', { id: 'station-list' });
  const token = h('input', {
    type: 'password', name: 'token', testid: 'login-token', required: true,
    autocomplete: 'current-password',
  });
  const submit = h('button', { type: 'submit', class: 'btn btn-primary btn-wide', testid: 'login-submit' }, 'Sign in');
  const error = h('p', { class: 'login-error', testid: 'login-error', role: 'alert', hidden: true });
  const info = h('p', { class: 'login-info', role: 'status', hidden: !message }, message);

  const form = h('form', { class: 'login-form', novalidate: true, 'aria-labelledby': 'login-title' },
    h('h1', { id: 'login-title' }, 'Sign in to the scanning station'),
    info,
    field('Station', station, 'The name of the scanning station, e.g. station1.'),
    stationList,
    field('Access token', token, 'The token you were given for this station.'),
    error,
    submit);

  const stored = (() => {
    try {
      return localStorage.getItem(LAST_STATION_KEY) || '';
    } catch {
      return '';
    }
  })();
  if (stored) station.value = stored;

  function showError(text) {
    error.textContent = text;
    show(error, !!text);
  }

  form.addEventListener('submit', async (event) => {
    event.preventDefault();
    const stationId = station.value.trim();
    const tokenValue = token.value;
    if (!stationId) {
      showError('Enter the station name.');
      station.focus();
      return;
    }
    if (!tokenValue) {
      showError('Enter your access token.');
      token.focus();
      return;
    }
    showError('');
    show(info, false);
    submit.disabled = true;
    submit.textContent = 'Signing in…';
    form.setAttribute('aria-busy', 'true');
    try {
      const me = await api.login(stationId, tokenValue);
      try {
        localStorage.setItem(LAST_STATION_KEY, stationId);
      } catch {
        /* private mode */
      }
      token.value = '';
      onSignedIn({ station: stationId, ...me });
    } catch (e) {
      showError(loginErrorText(e));
      token.select();
      token.focus();
    } finally {
      submit.disabled = false;
      submit.textContent = 'Sign in';
      form.removeAttribute('aria-busy');
    }
  });

  root.replaceChildren(h('main', { class: 'login-page', id: 'main' },
    h('div', { class: 'login-card card' },
      h('p', { class: 'brand brand-dark' }, 'craftscan'),
      form,
      h('p', { class: 'muted small' }, 'The console works without an internet connection.'))));

  // The stations this console serves: the first one is the default.
  api.stations().then((data) => {
    const list = Array.isArray(data?.stations) ? data.stations : [];
    stationList.replaceChildren(...list.map((s) =>
      h('option', { value: s.id }, `${s.id} — ${s.online === false ? 'not reachable' : s.state || ''}`)));
    const ids = list.map((s) => s.id);
    if (ids.length && (!station.value || !ids.includes(station.value))) station.value = ids[0];
  }).catch(() => {
    /* not available before sign-in: type the station's name */
  });

  (station.value ? token : station).focus();
}
