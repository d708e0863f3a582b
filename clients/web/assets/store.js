// Shared state of the console and a tiny event bus between its parts.
//
// Events: 'status' (store.status changed), 'live' (WebSocket state),
// 'job' (a job track changed; data: the track), 'job-final' (a job ended),
// 'thumb' (a view's thumbnail or disparity picture arrived; data: view
// index), 'cloud',
// 'preview' (a live-view frame; data: the message), 'preview-job' (a preview
// job ended; data: {id, state, message}), 'guide' (a guided-calibration
// overlay arrived; data: the calibrate track).

const listeners = new Map();

export function on(event, fn) {
  let set = listeners.get(event);
  if (!set) listeners.set(event, (set = new Set()));
  set.add(fn);
  return () => set.delete(fn);
}

export function emit(event, data) {
  const set = listeners.get(event);
  if (!set) return;
  for (const fn of [...set]) {
    try {
      fn(data);
    } catch (e) {
      console.error(`craftscan: ${event} listener failed`, e);
    }
  }
}

export const store = {
  me: null, // {station, role, client} once signed in
  stations: [], // [{id, state, online}] when known
  status: null, // the latest status (GET /api/status or a WebSocket status message)
  live: 'connecting', // the WebSocket: 'connecting' | 'up' | 'down'
  liveRetryAt: 0, // when 'down': the time of the next attempt (ms since epoch)
  scanForm: null, // the scan form's values, kept across page changes
  previewFocus: false, // the live view's focus heat map is on
};

export const ROLE_RANK = { observer: 0, operator: 1, admin: 2 };

// Whether the signed-in role is at least `role`.
export function can(role) {
  const mine = store.me ? ROLE_RANK[store.me.role] : undefined;
  return mine !== undefined && mine >= ROLE_RANK[role];
}
