// Shared by the console's browser tests (console.mjs, preview.mjs,
// calibrate.mjs): the console_station harness (craftscand on the sim plus
// craftscan-web's server) and the pages that talk to it.
import { spawn } from 'node:child_process';
import readline from 'node:readline';
import { check } from './lib.mjs';

/** The value after `name` on the command line. */
export function arg(name) {
  const i = process.argv.indexOf(name);
  return i > 0 ? process.argv[i + 1] : undefined;
}

/** --station-harness and --assets, or a usage error naming `script`. */
export function harnessArgs(script) {
  const harnessPath = arg('--station-harness');
  const assets = arg('--assets');
  check(harnessPath && assets, `usage: ${script} --station-harness PATH --assets DIR`);
  return { harnessPath, assets };
}

/**
 * Starts console_station; resolves {info, send(command) → its answer line,
 * stop()}. stop() closes its stdin and waits for it to end (it stops the
 * daemon); SIGTERM (which it also handles) if it has not ended in 10 s.
 * simExtra: more sim driver keys (", technician: 1, ..."); calibration: the
 * daemon config's calibration mapping ("{guided: true, ...}").
 */
export function startStation({ harnessPath, assets, simExtra = '', calibration = '' }) {
  return new Promise((resolve, reject) => {
    const args = ['--assets', assets];
    if (simExtra) args.push('--sim-extra', simExtra);
    if (calibration) args.push('--calibration', calibration);
    const child = spawn(harnessPath, args, { stdio: ['pipe', 'pipe', 'inherit'] });
    const lines = readline.createInterface({ input: child.stdout });
    const waiting = [];
    let info = null;
    const stop = () => new Promise((done) => {
      if (child.exitCode !== null || child.signalCode !== null) return done();
      const timer = setTimeout(() => child.kill('SIGTERM'), 10000);
      child.once('exit', () => { clearTimeout(timer); done(); });
      child.stdin.end();
    });
    const send = (command) => new Promise((done) => {
      waiting.push(done);
      child.stdin.write(command + '\n');
    });
    lines.on('line', (line) => {
      if (!info) {
        info = JSON.parse(line);
        resolve({ info, send, stop });
      } else if (waiting.length) {
        waiting.shift()(line);
      }
    });
    child.on('exit', (code) => { if (!info) reject(new Error(`console_station exited with ${code}`)); });
  });
}

/** A page that may load the console's own URLs only (others refused, listed in page.refused). */
export async function consolePage(browser, base, viewport = { width: 1280, height: 800 }) {
  const page = await browser.newPage();
  page.errors = [];
  page.refused = [];
  await page.setViewport({ ...viewport, deviceScaleFactor: 1 });
  await page.setRequestInterception(true);
  page.on('request', (request) => {
    const url = request.url();
    if (url.startsWith(base) || /^(data|blob|about):/.test(url)) {
      request.continue();
    } else {
      page.refused.push(url);
      request.abort('internetdisconnected');
    }
  });
  page.on('pageerror', (error) => page.errors.push(String(error && error.message ? error.message : error)));
  return page;
}

export const sel = (id) => `[data-testid="${id}"]`;

export async function signIn(page, info, token) {
  await page.waitForSelector(sel('login-token'), { visible: true });
  await page.$eval(sel('login-station'), (e, v) => { e.value = v; }, info.station);
  await page.type(sel('login-token'), token);
  await page.click(sel('login-submit'));
  await page.waitForSelector(sel('role'), { visible: true, timeout: 15000 });
}

export async function textOf(page, id) {
  return page.$eval(sel(id), (e) => e.textContent.trim()).catch(() => '');
}

/** fetch from inside the page (its cookie, its origin) → {status, body (JSON or null)}. */
export async function pageFetch(page, path, init) {
  return page.evaluate(async (p, i) => {
    const r = await fetch(p, i);
    let body = null;
    try { body = await r.json(); } catch { body = null; }
    return { status: r.status, body };
  }, path, init);
}

/** Polls `predicate` until it returns a truthy value (returned), or throws after timeoutMs. */
export async function waitUntil(what, predicate, timeoutMs) {
  const end = Date.now() + timeoutMs;
  for (;;) {
    const value = await predicate();
    if (value) return value;
    if (Date.now() > end) throw new Error(`timed out waiting for ${what}`);
    await new Promise((r) => setTimeout(r, 100));
  }
}
