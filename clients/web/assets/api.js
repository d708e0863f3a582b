// The console server's HTTP API (clients/web/API.md). Every call is
// same-origin with the session cookie; every POST carries the headers the
// server requires (X-Craftscan-Request: 1, Content-Type: application/json).
// Failures throw ApiError with the server's own message ({"error": ...}).

export class ApiError extends Error {
  constructor(status, message, body) {
    super(message);
    this.name = 'ApiError';
    this.status = status; // HTTP status; 0 when the server could not be reached
    this.body = body;
  }
}

export const STATION_NOT_ANSWERING = 'station not answering';

let onUnauthorized = null;
// Called (once per failing request) when a request needing the session gets
// 401: the session expired or was signed out elsewhere.
export function setUnauthorizedHandler(fn) {
  onUnauthorized = fn;
}

const TIMEOUT_MS = 45000;

// keepalive: the request outlives the page (sent while it is left).
async function request(method, path, body, { auth = true, keepalive = false } = {}) {
  const headers = { Accept: 'application/json' };
  const init = { method, credentials: 'same-origin', cache: 'no-store', headers };
  if (keepalive) init.keepalive = true;
  if (method !== 'GET') {
    headers['X-Craftscan-Request'] = '1';
    headers['Content-Type'] = 'application/json';
    init.body = JSON.stringify(body ?? {});
  }
  const abort = new AbortController();
  const timer = setTimeout(() => abort.abort(), TIMEOUT_MS);
  init.signal = abort.signal;
  let res;
  let text = '';
  try {
    res = await fetch(path, init);
    text = await res.text();
  } catch (e) {
    throw new ApiError(0, abort.signal.aborted
      ? 'The console server did not answer in time.'
      : 'Cannot reach the console server. Check the network connection.');
  } finally {
    clearTimeout(timer);
  }
  let data = null;
  if (text) {
    try {
      data = JSON.parse(text);
    } catch {
      data = null;
    }
  }
  if (!res.ok) {
    let message;
    if (res.status === 504) message = STATION_NOT_ANSWERING;
    else if (data && typeof data.error === 'string' && data.error) message = data.error;
    else message = `${res.status} ${res.statusText || 'error'}`.trim();
    if (res.status === 401 && auth && onUnauthorized) onUnauthorized(message);
    throw new ApiError(res.status, message, data);
  }
  return data;
}

// /api/sessions/<id>/files/<name>; name may have "/" (previews/a.png).
export function fileUrl(session, name) {
  const parts = String(name).split('/').map(encodeURIComponent).join('/');
  return `/api/sessions/${encodeURIComponent(session)}/files/${parts}`;
}

export const api = {
  me: () => request('GET', '/api/me', undefined, { auth: false }),
  login: (station, token) => request('POST', '/api/login', { station, token }, { auth: false }),
  logout: () => request('POST', '/api/logout', {}, { auth: false }),
  stations: () => request('GET', '/api/stations', undefined, { auth: false }),
  status: () => request('GET', '/api/status'),
  sessions: () => request('GET', '/api/sessions'),
  session: (id) => request('GET', `/api/sessions/${encodeURIComponent(id)}`),
  // The daemon's Reply as it is: {code, code_name, message, result}.
  // options: {keepalive} (see request).
  command: (verb, args = {}, options = {}) => request('POST', '/api/command', { verb, args }, options),
  fileJson: (session, name) => request('GET', fileUrl(session, name)),
  fileUrl,
};
