// The live connection: GET /api/ws (WebSocket). Reconnects with exponential
// backoff (0.5 s doubling to 15 s, with jitter) and treats a connection that
// has been silent for 10 s as dead (the server sends a status at least every
// 2 s), so a half-open connection is noticed too.

const MIN_DELAY_MS = 500;
const MAX_DELAY_MS = 15000;
const SILENCE_PING_MS = 5000;
const SILENCE_DEAD_MS = 10000;

export class LiveSocket {
  // onMessage(object) for each JSON message; onState('connecting'|'up'|'down', retryAtMs).
  constructor({ onMessage, onState, url }) {
    this.onMessage = onMessage;
    this.onState = onState;
    this.url = url ?? LiveSocket.defaultUrl();
    this.ws = null;
    this.attempts = 0;
    this.stopped = true;
    this.retryTimer = 0;
    this.watchTimer = 0;
    this.lastHeard = 0;
    this.lastPing = 0;
  }

  static defaultUrl() {
    const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
    return `${scheme}//${location.host}/api/ws`;
  }

  start() {
    if (!this.stopped) return;
    this.stopped = false;
    this.connect();
    this.watchTimer = setInterval(() => this.watch(), 1000);
  }

  stop() {
    this.stopped = true;
    clearTimeout(this.retryTimer);
    clearInterval(this.watchTimer);
    if (this.ws) {
      const ws = this.ws;
      this.ws = null;
      ws.close(1000, 'signed out');
    }
  }

  // Reconnects at once (e.g. the user pressed "Try now").
  retryNow() {
    if (this.stopped || (this.ws && this.ws.readyState <= WebSocket.OPEN)) return;
    clearTimeout(this.retryTimer);
    this.connect();
  }

  connect() {
    if (this.stopped) return;
    this.onState(this.attempts === 0 ? 'connecting' : 'down', 0);
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (e) {
      this.scheduleRetry();
      return;
    }
    this.ws = ws;
    ws.addEventListener('open', () => {
      if (this.ws !== ws) return;
      this.attempts = 0;
      this.lastHeard = Date.now();
      this.onState('up', 0);
    });
    ws.addEventListener('message', (event) => {
      if (this.ws !== ws) return;
      this.lastHeard = Date.now();
      if (typeof event.data !== 'string') return;
      let msg;
      try {
        msg = JSON.parse(event.data);
      } catch {
        return;
      }
      if (msg && typeof msg === 'object') this.onMessage(msg);
    });
    ws.addEventListener('close', () => {
      if (this.ws !== ws) return;
      this.ws = null;
      this.scheduleRetry();
    });
    // An error is always followed by close.
  }

  scheduleRetry() {
    if (this.stopped) return;
    const base = Math.min(MAX_DELAY_MS, MIN_DELAY_MS * 2 ** this.attempts);
    const delay = Math.round(base * (0.8 + Math.random() * 0.4));
    this.attempts++;
    const at = Date.now() + delay;
    this.onState('down', at);
    clearTimeout(this.retryTimer);
    this.retryTimer = setTimeout(() => this.connect(), delay);
  }

  watch() {
    const ws = this.ws;
    if (!ws || ws.readyState !== WebSocket.OPEN) return;
    const silent = Date.now() - this.lastHeard;
    if (silent > SILENCE_DEAD_MS) {
      this.ws = null;
      ws.close(4000, 'silent');
      this.scheduleRetry();
    } else if (silent > SILENCE_PING_MS && Date.now() - this.lastPing > SILENCE_PING_MS) {
      this.lastPing = Date.now();
      try {
        ws.send(JSON.stringify({ type: 'ping' }));
      } catch {
        /* close follows */
      }
    }
  }
}
