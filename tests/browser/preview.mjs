// The Station page's live view in headless Chromium against the real
// craftscand on the sim (console_station: the daemon plus craftscan-web's
// server):
//   - an operator starts the live view: frames arrive (data-frame moves on),
//     both pictures change from frame to frame, the histograms are drawn,
//     the focus heat map covers each picture when turned on;
//   - an observer on another browser watches the same frames without the
//     start button or the camera form;
//   - a longer exposure set in the form reaches the daemon, the preview goes
//     on and a later frame reports it (and the over-exposure warning shows);
//   - the page fits a tablet's width;
//   - Stop: after 5 s without a frame the panel says "Preview stopped";
//   - started again and the page left: the station's preview job ends.
// Screenshots in the artifacts folder (preview/).
//
//   node preview.mjs --station-harness PATH --assets DIR
import { runBrowserTest, check } from './lib.mjs';
import {
  consolePage, harnessArgs, pageFetch, sel, signIn, startStation, textOf, waitUntil,
} from './station.mjs';

const harness = harnessArgs('preview.mjs');

// The live view as the page shows it.
async function liveState(page) {
  return page.evaluate((s) => {
    const panel = document.querySelector(s.panel);
    const img = (id) => document.querySelector(`[data-testid="${id}"]`)?.getAttribute('src') ?? '';
    return {
      frame: panel?.dataset.frame ?? '',
      job: panel?.dataset.job ?? '',
      state: panel?.dataset.state ?? '',
      left: img('preview-left'),
      right: img('preview-right'),
      exposure: document.querySelector('[data-testid="preview-exposure"]')?.dataset.exposureUs ?? '',
      latency: document.querySelector('[data-testid="preview-latency"]')?.dataset.latencyMs ?? '',
      ready: document.querySelector('[data-testid="preview-latency"]')?.dataset.readyMs ?? '',
    };
  }, { panel: sel('preview') });
}

// Waits for `count` distinct frames (job and frame number) shown; returns them.
async function collectFrames(page, count, timeoutMs) {
  const frames = [];
  await waitUntil(`${count} live frames`, async () => {
    const s = await liveState(page);
    const key = `${s.job}/${s.frame}`;
    if (s.frame !== '' && (!frames.length || frames[frames.length - 1].key !== key)) frames.push({ key, ...s });
    return frames.length >= count;
  }, timeoutMs);
  return frames;
}

// Pixels of a <canvas> that differ from its background colour.
async function canvasDrawn(page, id) {
  return page.$eval(sel(id), (c) => {
    const g = c.getContext('2d');
    const d = g.getImageData(0, 0, c.width, c.height).data;
    const bg = [d[0], d[1], d[2]];
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (Math.abs(d[i] - bg[0]) + Math.abs(d[i + 1] - bg[1]) + Math.abs(d[i + 2] - bg[2]) > 60) n++;
    }
    return { drawn: n, total: c.width * c.height };
  });
}

runBrowserTest('preview', async (t) => {
  const station = await startStation(harness);
  const { info } = station;
  t.log('station', info.station, 'at', info.url);
  try {
    // The operator starts the live view.
    const page = await consolePage(t.browser, info.url);
    await page.goto(info.url, { waitUntil: 'load' });
    await signIn(page, info, info.operator);
    await page.waitForFunction((s) => document.querySelector(s)?.dataset.state === 'idle',
                               { timeout: 15000 }, sel('station-state'));
    await page.click(sel('nav-station'));
    await page.waitForSelector(sel('preview-start'), { visible: true });
    check((await page.$eval(sel('preview'), (e) => e.dataset.state)) === 'off',
          'the live view is not "off" before it is started');
    await page.click(sel('preview-start'));
    const frames = await collectFrames(page, 3, 30000);
    t.log('frames', frames.map((f) => f.key).join(', '));
    // Figures, not checks, over a dozen frames (the daemon and the browser
    // share this machine's clock): exposure to screen, and from the frame in
    // the daemon's hands to screen (without the simulated camera's rendering).
    const timed = await collectFrames(page, 12, 60000);
    for (const [key, what] of [['latency', 'exposure to screen'], ['ready', 'frame in the daemon to screen']]) {
      const v = timed.map((f) => f[key]).filter((x) => x !== '').map(Number).sort((a, b) => a - b);
      if (v.length) t.log(`preview latency, ${what}: median ${v[v.length >> 1]} ms, max ${v[v.length - 1]} ms over ${v.length} frames`);
    }
    check(frames.every((f) => f.left.startsWith('data:image/jpeg') && f.right.startsWith('data:image/jpeg')),
          'the pictures are not JPEG data URLs');
    for (const side of ['left', 'right']) {
      const distinct = new Set(frames.map((f) => f[side])).size;
      check(distinct === frames.length, `the ${side} picture did not change between frames (${distinct} of ${frames.length} distinct)`);
    }
    check((await liveState(page)).state === 'live', 'the live view does not say it is live');
    // The station stays "idle" for the people here while only the preview runs.
    check((await page.$eval(sel('station-state'), (e) => e.dataset.state)) === 'idle',
          'the station shows busy while only the live preview runs');

    for (const side of ['left', 'right']) {
      const h = await canvasDrawn(page, `histogram-${side}`);
      t.log(`histogram-${side}: ${h.drawn} of ${h.total} pixels drawn`);
      check(h.drawn > h.total * 0.02, `histogram-${side} is empty (${h.drawn} of ${h.total} pixels)`);
    }

    // The focus heat map: a grid over each picture, a legend.
    await page.click(sel('preview-focus'));
    await page.waitForSelector(sel('focus-legend'), { visible: true });
    const grids = await page.$$eval('.live-view .focus-grid.on', (gs) => gs.map((g) => {
      const box = g.getBoundingClientRect();
      const cells = [...g.children];
      return { cells: cells.length, width: box.width, best: cells.filter((c) => c.textContent === '100').length };
    }));
    check(grids.length === 2 && grids.every((g) => g.cells === 16 && g.width > 100 && g.best >= 1),
          `focus grids: ${JSON.stringify(grids)}`);
    await collectFrames(page, 1, 5000);
    await t.screenshot(page, '01-live-view');
    await t.screenshot(page, '01-live-view-panel', sel('preview'));

    // An observer watches the same frames, with nothing to start or set.
    const context = await t.browser.createBrowserContext();
    const observer = await consolePage(context, info.url);
    await observer.goto(`${info.url}`, { waitUntil: 'load' });
    await signIn(observer, info, info.observer);
    await observer.click(sel('nav-station'));
    const watched = await collectFrames(observer, 2, 15000);
    t.log('observer sees', watched.map((f) => f.key).join(', '));
    for (const id of ['preview-start', 'preview-stop', 'camera-exposure', 'camera-apply']) {
      check(!(await observer.$(sel(id))), `an observer sees ${id}`);
    }
    await t.screenshot(observer, '02-observer-watching');
    check(observer.errors.length === 0, `observer page errors: ${observer.errors.join(' | ')}`);
    await context.close();

    // A longer exposure: applied by the daemon, the preview goes on with it.
    const before = await liveState(page);
    const exposure = Math.max(40000, Number(before.exposure || 0) * 4);
    t.log(`exposure ${before.exposure} → ${exposure} µs`);
    await page.$eval(sel('camera-exposure'), (e) => { e.value = ''; });
    await page.type(sel('camera-exposure'), String(exposure));
    await page.click(sel('camera-apply'));
    await page.waitForFunction((s) => /camera —/.test(document.querySelector(s)?.textContent || ''),
                               { timeout: 15000 }, sel('status-line')).catch(async (e) => {
      const form = await page.$eval('.camera-form', (f) => f.textContent).catch(() => '');
      throw new Error(`no reply to camera: status line "${await textOf(page, 'status-line')}", form "${form}" (${e.message})`);
    });
    const applied = await page.$eval(sel('status-line'), (e) => [e.dataset.code, e.textContent.trim()]);
    check(applied[0] === 'ok', `camera refused: ${applied[1]}`);
    const later = await waitUntil(`a frame taken at ${exposure} µs`, async () => {
      const s = await liveState(page);
      return Number(s.exposure) === exposure ? s : null;
    }, 20000);
    t.log(`frame ${later.job}/${later.frame} at ${await textOf(page, 'preview-exposure')}, gain ${await textOf(page, 'preview-gain')}`);
    check((await textOf(page, 'preview-exposure')).replace(/\D/g, '') === String(exposure),
          `the exposure shown is "${await textOf(page, 'preview-exposure')}"`);
    await collectFrames(page, 2, 10000); // it goes on
    const warnings = await page.$$eval('[data-testid^="exposure-warning-"]', (ws) =>
      ws.filter((w) => !w.hidden).map((w) => w.textContent));
    t.log('warnings', JSON.stringify(warnings));
    check(warnings.some((w) => /over-exposed/i.test(w)), `no over-exposure warning at ${exposure} µs`);
    await t.screenshot(page, '03-longer-exposure', sel('preview'));

    // A tablet (portrait): the page fits its width.
    await page.setViewport({ width: 820, height: 1180, deviceScaleFactor: 1 });
    await collectFrames(page, 1, 5000);
    const overflow = await page.evaluate(() => document.documentElement.scrollWidth - window.innerWidth);
    check(overflow <= 0, `on a tablet the page is ${overflow} px wider than the screen`);
    await t.screenshot(page, '04-tablet');
    await page.setViewport({ width: 1280, height: 900, deviceScaleFactor: 1 });

    // Stop: no frame for 5 s → "Preview stopped".
    await page.click(sel('preview-stop'));
    await page.waitForFunction((s) => document.querySelector(s)?.dataset.state === 'stopped',
                               { timeout: 12000 }, sel('preview'));
    const stopped = await textOf(page, 'preview-note');
    check(/preview stopped/i.test(stopped), `after Stop the note says "${stopped}"`);
    check(await page.$eval(sel('preview-start'), (e) => !e.hidden && !e.disabled), 'no button to start it again');
    await t.screenshot(page, '05-stopped', sel('preview'));

    // Started again, then the page left: the station's preview ends.
    await page.click(sel('preview-start'));
    await collectFrames(page, 1, 15000);
    await page.click(sel('nav-scan'));
    await waitUntil('the preview to end on the station', async () => {
      const r = await pageFetch(page, '/api/status', {});
      return r.status === 200 && !(r.body.state === 'busy' && r.body.job_verb === 'preview');
    }, 10000);

    check(page.refused.length === 0, `requests outside the console: ${page.refused.join(', ')}`);
    check(page.errors.length === 0, `page errors: ${page.errors.join(' | ')}`);
  } finally {
    await station.stop();
  }
}, { timeoutMs: 150000 });
